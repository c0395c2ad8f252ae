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


def test_unit_restarts_on_what_a_restart_can_fix_only() -> None:
    """Issue 16: no restart loop on a configuration error (exit 2), a back-off for absent
    devices, descriptors above the connection cap, an explicit stop timeout."""
    from api.connections import ACCEPT_MARGIN
    from api.startup import RESERVED_FILES
    from config.settings import MAX_CONNECTIONS_LIMIT

    service = unit_directives()
    assert service["RestartPreventExitStatus"] == ["2"]
    assert int(service["RestartSec"][0].removesuffix("s")) >= 10
    assert int(service["LimitNOFILE"][0]) >= MAX_CONNECTIONS_LIMIT + ACCEPT_MARGIN + RESERVED_FILES
    assert service["TimeoutStopSec"] == ["30s"]


def test_unit_permits_locking_the_daemons_memory() -> None:
    """scheduler.lock_memory locks current and future pages: only safe without a limit."""
    assert unit_directives()["LimitMEMLOCK"] == ["infinity"]


def test_unit_documentation_link_exists_after_pip_install() -> None:
    """Issue 21: the link pointed at a README pip does not install; the daemon's /docs is
    always there while the service runs."""
    (link,) = [
        line.split("=", 1)[1]
        for line in UNIT.read_text().splitlines()
        if line.startswith("Documentation=")
    ]
    assert link == "http://127.0.0.1:8000/docs"
    lab = (REPO_ROOT / "config" / "lab.toml").read_text()
    assert "port = 8000" in lab  # the port the link names


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


DOCKERFILE = REPO_ROOT / "Dockerfile"


def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    text = DOCKERFILE.read_text().replace("\\\n", " ")
    lines = [line.strip() for line in text.splitlines()]
    return [
        (line.split(None, 1)[0].upper(), line.split(None, 1)[1])
        for line in lines
        if line and not line.startswith("#")
    ]


def test_dockerfile_copies_files_that_exist_and_runs_the_sim_config() -> None:
    """No docker engine here: check what a build would need (issue 10)."""
    instructions = dockerfile_instructions()
    ignored = (REPO_ROOT / ".dockerignore").read_text().split()
    copied_to: dict[str, str] = {}
    for name, arguments in instructions:
        if name != "COPY" or arguments.startswith("--from"):
            continue
        *sources, destination = arguments.split()
        for source in sources:
            assert (REPO_ROOT / source).exists(), source
            assert source.split("/")[0] not in ignored, f"{source} is not in the build context"
            copied_to[source] = destination
    # the default command runs the daemon on the simulated bench, with a config it copied
    assert ("ENTRYPOINT", '["thermocomp"]') in instructions
    (cmd,) = [arguments for name, arguments in instructions if name == "CMD"]
    assert cmd == '["serve", "--config", "/etc/thermocomp/sim.toml"]'
    assert copied_to["config/sim.toml"] == "/etc/thermocomp/"
    (healthcheck,) = [arguments for name, arguments in instructions if name == "HEALTHCHECK"]
    assert "http://127.0.0.1:8000/api/v1/health" in healthcheck
    assert ("USER", "thermocomp") in instructions and ("VOLUME", '["/data"]') in instructions
