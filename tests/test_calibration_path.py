"""One path from a calibration run to a compensated run (issue 19): the identified network
file carries its heat, parameters, errors and IR offsets; a run with it uses its heat unless
the run overrides it; the observer starts from its offsets; heat keys are node names; saved
networks are listed by GET /networks and started by name from POST /runs."""

from __future__ import annotations

import json
import logging
import math
import tomllib
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.app import create_app
from config import Settings
from config.settings import IrRegion
from daemon.commands import identify as identify_cli
from daemon.model import load_network, network_facts
from daemon.model.identified_network import network_toml
from daemon.model.observer import OFFSET_SIGMA_C
from daemon.model.presets import saved_networks_dir
from daemon.run.setup import (
    RunParameterError,
    build_model,
    build_observer,
    offset_prior_sigma_c,
    resolve_heat,
)
from daemon.run.states import RunParameters
from daemon.service import Daemon
from daemon.storage.recorder import Recorder
from tests.helpers import run_in_process, run_main
from tests.test_api_runs import CONTROL_HEADERS, bench_settings, wait_state
from tests.test_api_server import serve
from tests.test_identify_cli import write_run

SAVED = "lab-links"


def identify(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    return run_in_process(identify_cli.register, ["identify", *argv], capsys)


@pytest.fixture
def data_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    """A data directory holding one identified network saved as SAVED, fitted to an exported
    run of a truth with heat x1.3, convection x0.7 and an IR offset of 0.5 degC."""
    calibration = tmp_path / "warmup.csv"
    write_run(calibration, seed=1)
    folder = tmp_path / "data"
    status, _, stderr = identify(
        [str(calibration), "--network", "thesis-two-link", "--data-dir", str(folder),
         "--save", SAVED],
        capsys,
    )  # fmt: skip
    assert status == 0, stderr
    return folder


def test_the_identified_file_carries_heat_errors_and_ir_offsets(
    tmp_path: Path, data_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    calibration = tmp_path / "warmup.csv"
    out = tmp_path / "copy.toml"
    status, stdout, _ = identify(
        [str(calibration), "--network", "thesis-two-link", "--out", str(out), "--json"], capsys
    )
    assert status == 0
    fitted = {p["name"]: p for p in json.loads(stdout)["parameters"]}
    network = load_network(SAVED, data_dir)
    assert network.own_heat_w() == pytest.approx({"2": 0.65, "9": 0.65}, rel=0.02)
    found = network.calibration
    assert found is not None
    assert found.base_network == "thesis-two-link" and found.source_runs == ("warmup.csv",)
    assert datetime.fromisoformat(found.identified_at).tzinfo is not None
    by_name = {p.name: p for p in found.parameters}
    assert set(by_name) == set(fitted) == {"convection", "heat:2", "heat:9", "alpha", "offset"}
    for name, parameter in by_name.items():
        assert parameter.value == pytest.approx(fitted[name]["value"], rel=1e-6)
        assert parameter.standard_error == pytest.approx(fitted[name]["standard_error"], rel=1e-6)
        assert parameter.identifiable is fitted[name]["identifiable"]
    # one common offset over the three regions: each region carries it and its error
    offset = by_name["offset"]
    assert set(found.ir_offsets_c) == {"node-2", "node-9", "node-16"}
    for region, value in found.ir_offsets_c.items():
        assert value == pytest.approx(0.5, abs=4 * (offset.standard_error or math.inf))
        assert found.ir_offset_sigma_c[region] == pytest.approx(offset.standard_error)
    # convection and expansion are in the node values: the identified network is the fit
    preset = load_network("thesis-two-link")
    ratio = preset.r_ambient_c_per_w / network.r_ambient_c_per_w
    assert ratio == pytest.approx([by_name["convection"].value] * 17, rel=1e-9)
    assert network.alpha_per_c == pytest.approx(preset.alpha_per_c * by_name["alpha"].value)
    # --out and --save write the same document but the date; and it reloads to itself
    saved_text = (saved_networks_dir(data_dir) / f"{SAVED}.toml").read_text()
    strip = [line for line in saved_text.splitlines() if not line.startswith("identified_at")]
    assert strip == [line for line in out.read_text().splitlines() if "identified_at" not in line]
    assert network_toml(network).splitlines()[5:] == saved_text.splitlines()[6:]


@pytest.mark.parametrize(
    ("name", "message"),
    [
        (SAVED, "exists; choose another name"),
        ("thesis-two-link", "a preset has that name"),
        ("../escape", "is not a network name"),
        ("x.toml", "is not a network name"),
    ],
)
def test_save_refuses_taken_preset_and_path_names(
    tmp_path: Path, data_dir: Path, capsys: pytest.CaptureFixture[str], name: str, message: str
) -> None:
    status, _, stderr = identify(
        [str(tmp_path / "warmup.csv"), "--data-dir", str(data_dir), "--save", name], capsys
    )
    assert status == 2 and message in stderr and "Traceback" not in stderr
    assert not (tmp_path / "escape.toml").exists()


def settings_for(data_dir: Path, **model: Any) -> Settings:
    return Settings.model_validate({"storage": {"data_dir": str(data_dir)}, "model": model})


def test_a_run_uses_the_network_heat_unless_it_overrides_it(
    data_dir: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Precedence (issue 19): the run's heat_w > the network's own heat > model.heat_w >
    model.heater_power_w on the heater nodes; model.heat_w never silently overrides."""
    identified = load_network(SAVED, data_dir).own_heat_w()
    plain = settings_for(data_dir)
    built = build_model(plain, RunParameters(network=SAVED))
    assert built.parameters.heat_w == identified and "network" in built.heat_source
    assert built.model.heat_w.tolist() == built.network.heat_w.tolist()
    with caplog.at_level(logging.WARNING, logger="daemon.run.setup"):
        told = build_model(settings_for(data_dir, heat_w={"2": 0.1}), RunParameters(network=SAVED))
    assert told.parameters.heat_w == identified
    assert "model.heat_w (2 = 0.1 W) not used" in caplog.text
    forced = build_model(plain, RunParameters(network=SAVED, heat_w={"9": 0.2}))
    assert forced.parameters.heat_w == {"9": 0.2} and forced.heat_source == "the run's heat_w"
    preset = load_network("thesis-two-link")
    assert resolve_heat(plain, None, preset) == (
        {"2": 0.5, "9": 0.5},
        "setting model.heater_power_w on the heater nodes",
    )
    assert resolve_heat(settings_for(data_dir, heat_w={"5": 1.0}), None, preset)[0] == {"5": 1.0}
    single = load_network("thesis-single-link")  # its heater is the hole "shaft", not node 2
    assert resolve_heat(settings_for(data_dir, heater_power_w=0.3), None, single)[0] == {
        "shaft": 0.3
    }


def test_a_heat_key_naming_no_node_is_one_clear_error(data_dir: Path) -> None:
    """The old default keys "2"/"9" against a network whose nodes are named otherwise: refused
    in one line naming the key, the network and its nodes."""
    network = load_network("thesis-single-link-moving")
    with pytest.raises(RunParameterError) as caught:
        resolve_heat(settings_for(data_dir), {"left-shaft": 0.5}, network)
    message = str(caught.value)
    assert "\n" not in message
    assert "heat input 'left-shaft' names no node of network 'thesis-single-link-moving'" in message
    assert f"its nodes: 1, 2, 3, 4, ..., 69 ({network.node_count} nodes; named: shaft, diode)" in (
        message
    )
    assert message.endswith("heat from the run's heat_w")


def test_the_observer_starts_from_the_identified_offsets(data_dir: Path) -> None:
    settings = settings_for(data_dir, prediction="model+ir")
    built = build_model(settings, RunParameters(network=SAVED, prediction="model+ir"))
    calibration = built.network.calibration
    assert calibration is not None
    regions = tuple(  # the sim's node-N regions, as the run's IR reader names them
        IrRegion(name=f"node-{node}", x=10 * k, y=40, width=3, height=20, node=node)
        for k, node in enumerate(("2", "9", "16"))
    )
    observer = build_observer(settings, built.model, regions)
    assert observer.offsets_c == pytest.approx(dict(calibration.ir_offsets_c))
    # the prior is the identified uncertainty, far below the FLIR's 2 degC
    prior = offset_prior_sigma_c(calibration, list(observer.offsets_c))
    assert prior == pytest.approx(max(calibration.ir_offset_sigma_c.values()))
    assert prior < 0.1 * OFFSET_SIGMA_C
    # a region identification never saw: the FLIR's accuracy, not a borrowed certainty
    assert offset_prior_sigma_c(calibration, ["node-2", "elsewhere"]) == OFFSET_SIGMA_C
    preset = build_model(settings, RunParameters(prediction="model+ir"))
    assert build_observer(settings, preset.model, regions).offsets_c == dict.fromkeys(
        observer.offsets_c, 0.0
    )


@pytest.mark.slow
def test_from_a_recorded_run_to_a_run_with_its_network(tmp_path: Path) -> None:
    """The CLI path end to end on the bench: an uncompensated run, `identify RUN --save`,
    then `run --network NAME` uses the identified heat (recorded with where it came from) and
    `--heat` still overrides it."""
    data = tmp_path / "data"
    config = tmp_path / "bench.toml"
    config.write_text(
        "[bench]\ntruth_network = 'thesis-two-link'\ntruth_heat_scale = 1.3\n"
        f"stand_drift_um = 0.0\n[storage]\ndata_dir = '{data}'\n"
    )
    recorded = run_main(
        ["run", "--config", str(config), "--compensation", "off", "--duration", "900",
         "--step", "10", "--scale", "20"]
    )  # fmt: skip
    assert recorded.returncode == 0, recorded.stderr
    saved = run_main(["identify", "1", "--config", str(config), "--save", "bench-links"])
    assert saved.returncode == 0, saved.stderr
    assert "saved as network 'bench-links'" in saved.stdout
    heat = load_network("bench-links", data).own_heat_w()
    assert heat["2"] == pytest.approx(0.65, rel=0.1)
    used = run_main(
        ["run", "--config", str(config), "--network", "bench-links", "--duration", "20",
         "--step", "10", "--prediction", "model+ir", "--json"]
    )  # fmt: skip
    assert used.returncode == 0, used.stderr
    assert json.loads(used.stdout)["parameters"]["heat_w"] == heat
    overridden = run_main(
        ["run", "--config", str(config), "--network", "bench-links", "--duration", "20",
         "--step", "10", "--heat", "2=0.4", "9=0.4", "--json"]
    )  # fmt: skip
    assert overridden.returncode == 0, overridden.stderr
    assert json.loads(overridden.stdout)["parameters"]["heat_w"] == {"2": 0.4, "9": 0.4}
    with Recorder(data) as recorder:
        snapshot = recorder.run(2)
        assert snapshot is not None
        network = snapshot.network
    assert network is not None
    assert network["heat_source"] == "network 'thesis-two-link-identified'"
    assert network["identification"]["source_runs"] == ["run 1"]


@pytest.mark.slow
async def test_saved_networks_are_listed_and_started_by_name_over_the_api(
    data_dir: Path,
) -> None:
    app = create_app(bench_settings(data_dir, clock="virtual"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        listed = (await client.get("/api/v1/networks", headers=CONTROL_HEADERS)).json()
        by_name = {n["name"]: n for n in listed["networks"]}
        assert by_name["thesis-two-link"]["source"] == "preset"
        assert by_name["thesis-two-link"]["identification"] is None
        saved = by_name[SAVED]
        network = load_network(SAVED, data_dir)
        assert saved["source"] == "identified"
        assert saved["heat_w"] == pytest.approx(network.own_heat_w())
        identification = saved["identification"]
        assert identification["source_runs"] == ["warmup.csv"]
        assert identification["base_network"] == "thesis-two-link"
        assert datetime.fromisoformat(identification["identified_at"])
        assert network.calibration is not None
        assert identification["identifiable"] == network.calibration.identifiable
        assert saved["slowest_time_constant_s"] == pytest.approx(
            network_facts(network).slowest_time_constant_s
        )
        # a network saved later is listed on the next request (no stale cache)
        copy = saved_networks_dir(data_dir) / "second.toml"
        copy.write_text((saved_networks_dir(data_dir) / f"{SAVED}.toml").read_text())
        (saved_networks_dir(data_dir) / "broken.toml").write_text("[[nodes]]\nname = 1\n")
        again = (await client.get("/api/v1/networks", headers=CONTROL_HEADERS)).json()
        assert "second" in {n["name"] for n in again["networks"]}
        unreadable = {p["name"]: p["error"] for p in again["unreadable"]}
        assert set(unreadable) == {"broken"} and "broken.toml" in unreadable["broken"]

        for body, status, message in (
            ({"network": "../../etc/passwd"}, 422, "String should match pattern"),
            ({"network": "/etc/hosts"}, 422, "String should match pattern"),
            ({"network": "lab.toml"}, 422, "is not a network name"),
            ({"network": "nonesuch"}, 404, "no network preset or saved network 'nonesuch'"),
        ):
            response = await client.post("/api/v1/runs", json=body, headers=CONTROL_HEADERS)
            assert response.status_code == status, (body, response.text)
            text = json.dumps(response.json())
            assert message in text, text
        unknown = await client.post(
            "/api/v1/runs", json={"network": "nonesuch"}, headers=CONTROL_HEADERS
        )
        assert "presets: thesis-single-link" in unknown.json()["message"]
        assert (
            f"saved in {saved_networks_dir(data_dir)}: broken, {SAVED}" in unknown.json()["message"]
        )

        started = await client.post(
            "/api/v1/runs",
            json={"network": SAVED, "duration_s": 20, "compensation": "off"},
            headers=CONTROL_HEADERS,
        )
        assert started.status_code == 201, started.text
        run = started.json()
        assert run["parameters"]["network"] == SAVED
        assert run["parameters"]["heat_w"] == pytest.approx(network.own_heat_w())
        await wait_state(client, "idle", timeout_s=60)
        done = (await client.get(f"/api/v1/runs/{run['id']}")).json()
        assert done["state"] == "finished"
        steps = (await client.get(f"/api/v1/runs/{run['id']}/steps")).json()["steps"]
        assert len(steps) >= 2 and steps[-1]["predicted_x_um"] > 0.01  # the network's heat
        # an explicit empty heat_w heats nothing, though the network carries heat of its own
        cold = await client.post(
            "/api/v1/runs",
            json={"network": SAVED, "duration_s": 20, "compensation": "off", "heat_w": {}},
            headers=CONTROL_HEADERS,
        )
        assert cold.status_code == 201, cold.text
        assert cold.json()["parameters"]["heat_w"] == {}
        await wait_state(client, "idle", timeout_s=60)
        steps = (await client.get(f"/api/v1/runs/{cold.json()['id']}/steps")).json()["steps"]
        assert steps and all(abs(s["predicted_x_um"]) < 1e-9 for s in steps), steps[-1]


def test_the_saved_file_is_plain_toml_with_its_identification_table(data_dir: Path) -> None:
    document = tomllib.loads((saved_networks_dir(data_dir) / f"{SAVED}.toml").read_text())
    table = document["identification"]
    assert table["source_runs"] == ["warmup.csv"]
    assert {p["name"] for p in table["parameters"]} >= {"convection", "offset"}
    assert all(isinstance(p["identifiable"], bool) for p in table["parameters"])
    heated = {n["name"]: n["heat_w"] for n in document["nodes"] if "heat_w" in n}
    assert set(heated) == {"2", "9"}


@pytest.mark.slow
def test_calibrate_model_chains_the_three_steps(tmp_path: Path) -> None:
    """`thermocomp calibrate model`: uncompensated run -> identify --save -> validation run
    with the saved network, its reduction measured against the calibration run's drift."""
    data = tmp_path / "data"
    config = tmp_path / "bench.toml"
    config.write_text("[bench]\ntruth_heat_scale = 1.3\ntruth_convection_scale = 0.7\n")
    options = ["--config", str(config), "--data-dir", str(data), "--duration", "900"]
    refused = run_main(["calibrate", "model", *options, "--save", "thesis-two-link"])
    assert refused.returncode == 2 and "a preset has that name" in refused.stderr
    assert not data.exists()  # nothing ran
    result = run_main(
        ["calibrate", "model", *options, "--step", "10", "--save", "chained", "--json"]
    )
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout)
    assert outcome["calibration_run"]["id"] == 1
    assert outcome["calibration_run"]["reduction_basis"] == "drift"
    validation = outcome["validation_run"]
    assert validation["id"] == 2 and validation["state"] == "finished"
    assert validation["reduction_basis"] == "reference" and validation["reference_run"] == 1
    assert validation["reduction_percent"] > 95.0
    fitted = {p["name"]: p["value"] for p in outcome["identified"]["parameters"]}
    assert fitted["heat:2"] > 1.1  # the truth's x1.3 seen (effective value, 17 vs 2 mm nodes)
    network = load_network("chained", data)
    assert network.calibration is not None and network.calibration.source_runs == ("run 1",)
    with Recorder(data) as recorder:
        row = recorder.run(2)
        assert row is not None
        assert row.parameters["network"] == "chained"
        assert row.parameters["heat_w"] == pytest.approx(network.own_heat_w())


def test_model_info_and_simulate_reach_a_saved_network(
    data_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from daemon.commands import model_options

    status, out, err = run_in_process(
        model_options.register,
        ["model", "info", SAVED, "--data-dir", str(data_dir), "--json"],
        capsys,
    )
    assert status == 0, err
    facts = network_facts(load_network(SAVED, data_dir))
    assert json.loads(out)["slowest_time_constant_s"] == pytest.approx(
        facts.slowest_time_constant_s
    )
    status, out, err = run_in_process(
        model_options.register,
        ["model", "simulate", "--network", SAVED, "--data-dir", str(data_dir), "--duration",
         "60", "--json"],
        capsys,
    )  # fmt: skip
    assert status == 0, err  # the saved network's own heat: no --heat needed
    status, _, err = run_in_process(model_options.register, ["model", "info", SAVED], capsys)
    assert status == 2 and f"no network preset '{SAVED}'" in err
