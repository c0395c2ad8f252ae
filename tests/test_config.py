"""Settings: loading, environment overrides, and the errors a user sees for bad files."""

from pathlib import Path

import pytest

from config import CONFIG_DIR, ConfigError, Settings, load_settings
from tests.helpers import run_cli, run_main


def test_bundled_files_load() -> None:
    sim = load_settings(CONFIG_DIR / "sim.toml", environ={})
    lab = load_settings(CONFIG_DIR / "lab.toml", environ={})
    assert sim.bench.enabled and sim.robot.driver == "sim"
    assert (sim.api.host, sim.api.port) == ("127.0.0.1", 8000)
    assert sim.storage.data_dir == Path("data")
    assert not lab.bench.enabled
    assert (lab.robot.driver, lab.robot.port, lab.robot.baudrate) == ("c500c", "/dev/ttyS0", 57600)
    assert (lab.robot.bytesize, lab.robot.parity, lab.robot.stopbits) == (8, "N", 1)
    assert (lab.camera.device, lab.ir.device) == (0, 1)


def test_each_bench_config_has_a_data_directory_of_its_own() -> None:
    """Issue 28: the two-link and the arm benches' runs never share a run history."""
    folders = [
        load_settings(CONFIG_DIR / name, environ={}).storage.data_dir
        for name in ("sim.toml", "arm-sim.toml", "arm-sim-played.toml")
    ]
    assert len(set(folders)) == len(folders), folders


def test_defaults_need_no_file() -> None:
    assert load_settings(None, environ={}) == Settings()


def test_environment_overrides_file(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[robot]\nbaudrate = 9600\nport = "/dev/ttyUSB0"\n')
    env = {"THERMOCOMP_ROBOT__BAUDRATE": "38400", "THERMOCOMP_API__CONTROL_TOKEN": "s3cret"}
    settings = load_settings(path, environ=env)
    assert settings.robot.baudrate == 38400
    assert settings.robot.port == "/dev/ttyUSB0"
    assert settings.api.control_token == "s3cret"


def test_out_of_range_field_names_file_path_and_reason(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text("[robot]\nbaudrate = 12345\n")
    with pytest.raises(ConfigError) as info:
        load_settings(path, environ={})
    assert str(info.value) == (
        f"{path}: robot.baudrate: must be one of 9600, 19200, 38400, 57600, 115200"
    )


def test_bad_environment_value_names_the_variable() -> None:
    with pytest.raises(
        ConfigError,
        match=r"THERMOCOMP_SCHEDULER__STEP_S \(environment\): "
        r"scheduler.step_s: Input should be greater than or equal to 0.01",
    ):
        load_settings(None, environ={"THERMOCOMP_SCHEDULER__STEP_S": "0.001"})


def test_unknown_key_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "typo.toml"
    path.write_text("[robot]\nbaudrat = 57600\n")
    with pytest.raises(ConfigError, match=r"typo.toml: robot.baudrat: unknown setting"):
        load_settings(path, environ={})


@pytest.mark.slow
def test_cli_exits_2_on_broken_toml(tmp_path: Path) -> None:
    """The real process (the exit status the shell sees); the other settings errors below
    call the same entry point in-process (tests.helpers.run_main)."""
    path = tmp_path / "broken.toml"
    path.write_text("[robot\nbaudrate = 57600\n")
    result = run_cli(["serve", "--config", str(path)])
    assert result.returncode == 2
    assert f"{path}: not valid TOML" in result.stderr
    assert "line 1" in result.stderr
    assert "Traceback" not in result.stderr


def test_cli_exits_2_on_out_of_range_field(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text("[robot]\nbaudrate = 12345\n[api]\nport = 70000\n")
    result = run_main(["serve", "--config", str(path)])
    assert result.returncode == 2
    assert f"{path}: robot.baudrate: must be one of 9600, 19200, 38400, 57600, 115200" in (
        result.stderr
    )
    assert f"{path}: api.port: Input should be less than or equal to 65535" in result.stderr
    assert "Traceback" not in result.stderr


def test_cli_exits_2_on_missing_file(tmp_path: Path) -> None:
    result = run_main(["serve", "--config", str(tmp_path / "nope.toml")])
    assert result.returncode == 2
    assert "nope.toml: no such file" in result.stderr


def test_cli_exits_2_on_out_of_range_port_option() -> None:
    result = run_main(["serve", "--config", "config/sim.toml", "--port", "99999"])
    assert result.returncode == 2
    assert "argument --port: must be a TCP port, 0 to 65535, got 99999" in result.stderr
    assert "Traceback" not in result.stderr
