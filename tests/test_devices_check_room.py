"""`thermocomp devices check` reads the room thermometer (issue 29: the room is an input of
every arm run) through the real CLI: a 1-Wire DS18B20 in a sysfs tree written here (the
kernel's w1_therm format, drivers/room.py), one that is missing (one failed line, every other
device still described, exit 1), and none configured on an arm (a note, not a failure)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers import REPO_ROOT, run_main
from tests.loopback import loopback_host

ARM = str(REPO_ROOT / "config" / "arm-sim.toml")
UR5E = str(REPO_ROOT / "config" / "ur5e-sim.toml")
SENSOR = "28-0316a2794aff"
#: What the kernel's w1_therm prints for 23.125 degC (Linux Documentation/w1/slaves/w1_therm.rst).
W1_SLAVE = "72 01 4b 46 7f ff 0e 10 57 : crc=57 YES\n72 01 4b 46 7f ff 0e 10 57 t=23125\n"


def w1_tree(tmp_path: Path) -> Path:
    folder = tmp_path / "w1" / SENSOR
    folder.mkdir(parents=True)
    (folder / "w1_slave").write_text(W1_SLAVE)
    return folder.parent


def environment(config: str, tmp_path: Path, **room: str) -> dict[str, str]:
    env = {f"THERMOCOMP_ROOM__{key.upper()}": value for key, value in room.items()}
    env["THERMOCOMP_STORAGE__DATA_DIR"] = str(tmp_path / "data")
    if config == UR5E:
        env["THERMOCOMP_ROBOT__HOST"] = loopback_host()
    return env


@pytest.mark.slow
@pytest.mark.parametrize("config", [ARM, UR5E], ids=["a465", "ur5e"])
def test_the_room_thermometer_is_read_and_a_missing_one_is_one_line(
    tmp_path: Path, config: str
) -> None:
    good = environment(config, tmp_path, driver="w1", w1_devices_dir=str(w1_tree(tmp_path)))
    result = run_main(["devices", "check", "--config", config, "--json"], env=good)
    assert result.returncode == 0, result.stdout + result.stderr
    data = json.loads(result.stdout)
    assert data["room"] == {"temperature_c": 23.125, "sensor": SENSOR}
    assert data["errors"] == {} and data["robot"]["link"] == "connected"

    missing = tmp_path / "no-w1-bus"
    bad = environment(config, tmp_path, driver="w1", w1_devices_dir=str(missing))
    result = run_main(["devices", "check", "--config", config], env=bad)
    assert result.returncode == 1
    lines = result.stdout.splitlines()
    # the room is the one failure, named as the room's; the robot is described all the same
    reason = (
        f"cannot list {missing}: No such file or directory (is the w1 bus driver loaded, e.g. "
        "w1-gpio or ds2490, and w1_therm?)"
    )
    assert [line for line in lines if "FAILED" in line] == [f"room: FAILED: {reason}"]
    assert any(line.startswith("robot: connected") for line in lines), result.stdout
    assert not any(line.startswith("room: no thermometer") for line in lines)
    errors = [line for line in result.stderr.splitlines() if "devices check" in line]
    assert errors == [f"thermocomp devices check: room: {reason}"]


@pytest.mark.slow
def test_an_arm_without_a_thermometer_is_told_so_and_the_two_link_is_not(tmp_path: Path) -> None:
    result = run_main(
        ["devices", "check", "--config", ARM], env=environment(ARM, tmp_path, driver="none")
    )
    assert result.returncode == 0, result.stdout + result.stderr
    notes = [line for line in result.stdout.splitlines() if line.startswith("room:")]
    assert notes == [
        "room: no thermometer (room.driver none): the model holds model.ambient_c, and a room "
        "that warms during a run is read as the robot heating "
        "(docs/how-to/identify-arm-model.md)"
    ]
    sim = str(REPO_ROOT / "config" / "sim.toml")  # the two-link bench: no room in its model
    result = run_main(["devices", "check", "--config", sim], env=environment(sim, tmp_path))
    assert result.returncode == 0, result.stdout + result.stderr
    assert not any(line.startswith("room") for line in result.stdout.splitlines())
