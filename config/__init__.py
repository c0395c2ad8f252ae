"""Settings schema and bundled configuration files (sim.toml, lab.toml, networks/)."""

from pathlib import Path

from config.settings import ConfigError, Settings, load_settings, redact_secrets

#: Folder of the bundled TOML files; network presets live in ``CONFIG_DIR / "networks"``.
CONFIG_DIR = Path(__file__).resolve().parent

__all__ = ["CONFIG_DIR", "ConfigError", "Settings", "load_settings", "redact_secrets"]
