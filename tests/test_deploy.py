"""The systemd unit: parsed by systemd itself, and carrying the hardening issue 10 requires."""

import configparser
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.helpers import REPO_ROOT

UNIT = REPO_ROOT / "deploy" / "thermocomp.service"


def unit_directives() -> dict[str, list[str]]:
    """Every `Key=value` of the [Service] section, repeated keys kept."""
    directives: dict[str, list[str]] = {}
    section = None
    for raw in UNIT.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            section = line
        elif section == "[Service]":
            key, _, value = line.partition("=")
            directives.setdefault(key, []).append(value)
    return directives


def test_unit_asks_for_notify_watchdog_and_hardening() -> None:
    service = unit_directives()
    expected = {
        "Type": ["notify"],
        "Restart": ["on-failure"],
        "ProtectSystem": ["strict"],
        "NoNewPrivileges": ["true"],
        "DevicePolicy": ["closed"],
        "StateDirectory": ["thermocomp"],
        "SupplementaryGroups": ["dialout video"],
    }
    for key, value in expected.items():
        assert service.get(key) == value, key
    assert service["WatchdogSec"][0].endswith("s")
    assert {"char-ttyS rw", "char-video4linux rw"} <= set(service["DeviceAllow"])
    assert service["ExecStart"][0].split()[1:3] == ["serve", "--config"]


def test_unit_is_valid_ini() -> None:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.read_string(UNIT.read_text())
    assert {"Unit", "Service", "Install"} <= set(parser.sections())


def test_systemd_analyze_verify_is_clean(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed on this machine")
    # verify also checks that ExecStart exists: point it at a binary every machine has.
    text = UNIT.read_text().replace("/opt/thermocomp/bin/thermocomp", shutil.which("true") or "")
    unit = tmp_path / "thermocomp.service"
    unit.write_text(text)
    result = subprocess.run(
        [analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60, check=False
    )
    complaints = [
        line for line in (result.stdout + result.stderr).splitlines() if str(unit) in line
    ]
    assert result.returncode == 0 and not complaints, complaints
