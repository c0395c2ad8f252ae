"""``thermocomp identify`` on an exported run (CSV) generated from a known truth."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from daemon.commands import identify as identify_cli
from daemon.model import ThermalModel, load_network
from daemon.model.identify import apply_parameters, parse_parameters
from tests.helpers import run_cli, run_in_process, run_main

REGIONS = {"node-2": ("2",), "node-9": ("9",), "node-16": ("16",)}
SCALE = 20.0  # deformation scale of the run (thesis 6.3)


def write_run(
    path: Path, seed: int, *, heat_scale: float = 1.3, compensated: bool = False, ir: bool = True
) -> None:
    """An exported run of the preset with convection x0.7 and heat x``heat_scale``, as the
    daemon records it: IR regions (offset 0.5 degC), residual = scale x (true - predicted)."""
    preset = load_network("thesis-two-link")
    specs = parse_parameters(["convection"], preset, REGIONS)
    truth_network = apply_parameters(preset, specs, np.log([0.7]), REGIONS).network
    truth, predicted = ThermalModel(truth_network, dt_s=30.0), ThermalModel(preset, dt_s=30.0)
    truth.set_heat({"2": 0.5 * heat_scale, "9": 0.5 * heat_scale})
    predicted.set_heat({"2": 0.5, "9": 0.5})
    rng = np.random.default_rng(seed)
    rows = []
    for step in range(120):
        t = 30.0 * step
        truth.advance_to(t)
        predicted.advance_to(t)
        prediction = predicted.deformation_um_scalar() if compensated else 0.0
        readings = {
            region: {"mean_c": float(truth.temperatures_c[preset.node_index(nodes[0])])
                     + 0.5 + rng.normal(0, 0.05), "max_c": 0.0}
            for region, nodes in REGIONS.items()
        }  # fmt: skip
        rows.append(
            {
                "run_id": "7",
                "step": step,
                "scheduled_s": t,
                "actual_s": t,
                "predicted_x_um": predicted.deformation_um_scalar(),
                "offset_x_mm": -SCALE * prediction / 1000.0,
                "residual_um": SCALE * (truth.deformation_um_scalar() - prediction)
                + rng.normal(0, 0.9),
                "ir_json": json.dumps(readings) if ir else "",
                "deformation_scale": SCALE,
            }
        )
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    return run_in_process(identify_cli.register, argv, capsys)


def test_identifies_an_exported_run_validates_and_writes_a_network(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    calibration, check, out = tmp_path / "off.csv", tmp_path / "comp.csv", tmp_path / "net.toml"
    write_run(calibration, seed=1)
    write_run(check, seed=2, compensated=True)
    status, stdout, stderr = run(
        ["identify", str(calibration), "--network", "thesis-two-link", "--out", str(out),
         "--validate", str(check), "--json"],
        capsys,
    )  # fmt: skip
    assert status == 0, stderr
    document = json.loads(stdout)
    values = {p["name"]: p for p in document["parameters"]}
    assert set(values) == {"convection", "heat:2", "heat:9", "alpha", "offset"}
    for name, truth in {"convection": 0.7, "heat:2": 1.3, "heat:9": 1.3, "alpha": 1.0}.items():
        assert values[name]["value"] == pytest.approx(truth, abs=4 * values[name]["standard_error"])
    assert document["validation"]["deformation_rms_um"] < 0.2  # 0.9 um / 20 of noise
    assert document["network_file"] == str(out)
    identified = load_network(out)
    assert identified.name == "thesis-two-link-identified"
    assert identified.heat_w[identified.node_index("2")] == pytest.approx(0.65, rel=0.02)


def test_text_output_flags_what_the_data_cannot_tell(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No IR regions recorded: heat and alpha only show as their product in the deformation."""
    calibration = tmp_path / "off.csv"
    write_run(calibration, seed=3, ir=False)
    status, stdout, _ = run(["identify", str(calibration), "--params", "heat", "alpha"], capsys)
    assert status == 0
    assert "deformation RMS" in stdout
    assert "warning: heat is not identifiable" in stdout
    assert "warning: alpha is not identifiable" in stdout
    assert stdout.count("NO: ") == 2


@pytest.mark.parametrize(
    ("argv", "status", "message"),
    [
        (["identify", "no-such-file.csv"], 1, "neither a file nor a run number"),
        (["identify", "{csv}", "--params", "viscosity"], 2, "unknown parameter"),
        (["identify", "{csv}", "--network", "no-such-network"], 2, "no network preset"),
        (["identify", "{csv}", "--heater-off", "-5"], 2, "must not be negative"),
    ],
)
def test_bad_input_gives_a_clear_message(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    status: int,
    message: str,
) -> None:
    calibration = tmp_path / "off.csv"
    write_run(calibration, seed=4)
    code, _, stderr = run([a.replace("{csv}", str(calibration)) for a in argv], capsys)
    assert code == status
    assert message in stderr
    assert "Traceback" not in stderr


def test_the_entry_point_lists_identify() -> None:
    result = run_cli(["identify", "--help"])
    assert result.returncode == 0
    assert "--validate" in result.stdout


@pytest.mark.slow
def test_a_recorded_run_from_the_database(tmp_path: Path) -> None:
    """End to end on the simulated bench: a real `thermocomp run` (compensation off) on a
    truth with heat x1.3 and convection x0.7, then `thermocomp identify RUN_ID` reading the
    database read-only, with the run's own heat input, network and IR regions."""
    config = tmp_path / "bench.toml"
    config.write_text(
        "[bench]\ntruth_network = 'thesis-two-link'\ntruth_heat_scale = 1.3\n"
        "truth_convection_scale = 0.7\nstand_drift_um = 0.0\n"
        f"[storage]\ndata_dir = '{tmp_path / 'data'}'\n"
    )
    recorded = run_main(
        ["run", "--config", str(config), "--compensation", "off", "--duration", "1200",
         "--step", "10", "--scale", "20"]
    )  # fmt: skip
    assert recorded.returncode == 0, recorded.stderr
    out = tmp_path / "identified.toml"
    result = run_main(["identify", "1", "--config", str(config), "--json", "--out", str(out)])
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert document["fit"]["temperature_samples"] == 3 * 120  # node-2, node-9, node-16
    values = {p["name"]: p["value"] for p in document["parameters"]}
    # the bench's truth IS the preset scaled (plus IR pixels and timing): close, not exact
    assert values["convection"] == pytest.approx(0.7, rel=0.1)
    assert values["heat:2"] == pytest.approx(1.3, rel=0.05)
    assert values["alpha"] == pytest.approx(1.0, rel=0.05)
    assert load_network(out).name == "thesis-two-link-identified"
    # the same run found by --data-dir, whatever storage.data_dir the settings name
    by_folder = run_main(
        ["identify", "1", "--config", "config/sim.toml", "--data-dir", str(tmp_path / "data"),
         "--json"]
    )  # fmt: skip
    assert by_folder.returncode == 0, by_folder.stderr
    again = {p["name"]: p["value"] for p in json.loads(by_folder.stdout)["parameters"]}
    assert again == values
