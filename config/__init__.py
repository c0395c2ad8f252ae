"""Settings schema and bundled configuration files (sim.toml, lab.toml, networks/).

The settings names are loaded on first use (PEP 562): ``config.cli`` (exit statuses, argument
types) must not pull in pydantic, so ``thermocomp --help`` stays fast.
"""

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from config.settings import ConfigError, Settings, load_settings, redact_secrets

#: Folder of the bundled TOML files; network presets live in ``CONFIG_DIR / "networks"``.
CONFIG_DIR = Path(__file__).resolve().parent

__all__ = ["CONFIG_DIR", "ConfigError", "Settings", "load_settings", "redact_secrets"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        # lazy: pydantic loads on first use of a setting (PEP 562), not for `thermocomp --help`
        from config import settings

        return getattr(settings, name)
    raise AttributeError(f"module 'config' has no attribute {name!r}")
