"""``thermocomp model simulate`` and ``thermocomp model info``."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from daemon.commands import model_options
from daemon.model import ThermalModel, load_network, network_facts
from tests.helpers import run_cli, run_in_process


def run(command: str | list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """The model command alone, in-process (the real entry point is tested once below)."""
    argv = command.split() if isinstance(command, str) else command
    return run_in_process(model_options.register, argv, capsys)


def test_the_done_when_command_runs_through_the_real_entry_point() -> None:
    command = (
        "model simulate --network thesis-two-link --duration 3600 --dt 1 "
        "--heat 2=0.5 --heat 9=0.5 --json"
    )
    result = run_cli(command.split())
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert set(document) == {
        "network", "stepper", "dt_s", "t_s", "deformation_um", "nodes", "temperature_c"
    }  # fmt: skip
    assert document["network"] == "thesis-two-link"
    assert document["stepper"] == "exact"
    assert document["dt_s"] == 1.0
    assert document["t_s"] == [float(t) for t in range(3601)]
    assert document["nodes"] == [str(n) for n in range(1, 18)]
    assert len(document["temperature_c"]) == len(document["deformation_um"]) == 3601
    assert document["temperature_c"][0] == [22.0] * 17
    assert document["deformation_um"][0] == 0.0
    # The last row is the model's own state after an hour.
    model = ThermalModel(load_network("thesis-two-link"), "exact", 1.0, 22.0)
    model.set_heat({"2": 0.5, "9": 0.5})
    model.advance_to(3600.0)
    assert document["deformation_um"][-1] == pytest.approx(model.deformation_um_scalar(), 1e-12)
    np.testing.assert_allclose(document["temperature_c"][-1], model.temperatures_c, rtol=1e-12)


def test_simulate_output_interval_ambient_and_named_nodes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    status, out, err = run(
        "model simulate --network thesis-single-link --duration 95 --dt 2 --every 30 "
        "--heat shaft=1.5 --ambient 18.5 --json",
        capsys,
    )
    assert status == 0, err
    document = json.loads(out)
    assert document["t_s"] == [0.0, 30.0, 60.0, 90.0, 95.0]
    assert document["temperature_c"][0] == [18.5] * len(document["nodes"])
    shaft = document["nodes"].index("shaft")
    assert all(row[shaft] > 18.5 for row in document["temperature_c"][1:])
    assert all(b > a for a, b in itertools.pairwise(document["deformation_um"]))


def test_simulate_explicit_matches_exact_to_first_order(
    capsys: pytest.CaptureFixture[str],
) -> None:
    rows = {}
    for stepper in ("exact", "explicit"):
        status, out, err = run(
            f"model simulate --duration 600 --dt 0.5 --stepper {stepper} "
            "--heat 2=0.5 --heat 9=0.5 --every 600 --json",
            capsys,
        )
        assert status == 0, err
        rows[stepper] = json.loads(out)["deformation_um"][-1]
    assert rows["explicit"] == pytest.approx(rows["exact"], rel=1e-3)


def test_simulate_table_is_readable(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, _ = run(
        ["model", "simulate", "--duration", "10", "--dt", "5", "--heat", "2=0.5"], capsys
    )
    assert status == 0
    lines = out.splitlines()
    assert "deformation from node 2 to node 16" in lines[0]
    assert "deformation (um)" in lines[1] and "T2 (C)" in lines[1]
    assert len(lines) == 2 + 3  # header lines + t = 0, 5, 10


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--heat", "42=1"], "heat input '42' names no node of network 'thesis-two-link'"),
        (["--heat", "2:1"], "NODE=WATTS"),
        (["--heat", "2=hot"], "not a number of watts"),
        (["--network", "nonesuch"], "no network preset 'nonesuch'"),
        (["--dt", "0"], "positive"),
        (["--dt", "nan"], "must be finite"),
        (["--stepper", "explicit", "--dt", "5"], "exceeds the bound"),
        (["--stepper", "rk4"], "invalid choice"),
    ],
)
def test_simulate_bad_input_exits_2_with_a_message(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    status, out, err = run(
        ["model", "simulate", "--duration", "10", "--heat", "2=1", *argv], capsys
    )
    assert status == 2
    assert message in err
    assert "Traceback" not in err and out == ""


def test_simulate_without_any_heat_input_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 19: the presets carry no heat, so no --heat simulated 22 degC everywhere."""
    status, out, err = run("model simulate --duration 10", capsys)
    assert status == 2 and out == ""
    assert "no heat input" in err and "its heater nodes: 2, 9" in err
    # an explicit zero is a request, not an omission
    status, out, err = run("model simulate --duration 10 --heat 2=0 --json", capsys)
    assert status == 0, err
    assert np.abs(json.loads(out)["deformation_um"]).max() < 1e-9  # rounding only


def test_simulate_uses_the_networks_own_heat(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A network file whose nodes carry heat_w needs no --heat; --heat replaces it."""
    preset = Path("config/networks/thesis-two-link.toml").read_text()
    heated = preset.replace(
        "r_ambient_c_per_w = 248.000496\n", "r_ambient_c_per_w = 248.000496\nheat_w = 0.5\n", 1
    )
    assert heated != preset
    path = tmp_path / "heated.toml"
    path.write_text(heated)
    status, out, err = run(f"model simulate --network {path} --duration 60 --json", capsys)
    assert status == 0, err
    own = json.loads(out)["deformation_um"]
    status, out, err = run(
        f"model simulate --network {path} --duration 60 --heat 2=0.5 --json", capsys
    )
    assert status == 0, err
    assert own[-1] > 0 and json.loads(out)["deformation_um"] == own


def test_several_heat_inputs_after_one_heat_option(capsys: pytest.CaptureFixture[str]) -> None:
    """The documented form `--heat 2=0.5 9=0.5` equals `--heat 2=0.5 --heat 9=0.5`."""
    documents = []
    for heat in (["--heat", "2=0.5", "9=0.5"], ["--heat", "2=0.5", "--heat", "9=0.5"]):
        status, out, err = run(
            ["model", "simulate", "--duration", "60", "--every", "30", *heat, "--json"], capsys
        )
        assert status == 0, err
        documents.append(json.loads(out))
    assert documents[0] == documents[1]
    assert documents[0]["deformation_um"][-1] > 0


def test_explicit_sub_steps_on_request(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = run(
        "model simulate --duration 10 --dt 5 --stepper explicit --substeps --heat 2=1 --json",
        capsys,
    )
    assert status == 0, err
    assert json.loads(out)["deformation_um"][-1] > 0.0


def test_info_reports_the_network_facts(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = run(["model", "info", "thesis-two-link", "--json"], capsys)
    assert status == 0, err
    document = json.loads(out)
    facts = network_facts(load_network("thesis-two-link"))
    assert document["node_count"] == 17
    assert document["positivity_bound_s"] == pytest.approx(facts.positivity_bound_s)
    assert document["stability_limit_s"] == pytest.approx(facts.stability_limit_s)
    assert document["slowest_time_constant_s"] == pytest.approx(facts.slowest_time_constant_s)
    assert document["fastest_time_constant_s"] == pytest.approx(facts.fastest_time_constant_s)
    assert set(document["steady_deformation_um_per_w"]) == {"2", "9"}
    assert all(math.isfinite(v) for v in document["steady_deformation_um_per_w"].values())

    status, out, _ = run(["model", "info", "thesis-two-link"], capsys)
    assert status == 0
    assert "slowest" in out and "um/W" in out

    status, out, err = run(["model", "info", "nonesuch.toml"], capsys)
    assert status == 2 and "nonesuch.toml" in err and out == ""


def test_the_light_options_agree_with_the_model() -> None:
    """`thermocomp model --help` builds its parser without the model
    (daemon/commands/model_options.py repeats two of its facts): they must agree."""
    from daemon.commands.model_options import STEPPER_CHOICES, _presets
    from daemon.model.model import STEPPERS
    from daemon.model.presets import available_presets

    assert STEPPER_CHOICES == STEPPERS
    assert _presets() == available_presets()
