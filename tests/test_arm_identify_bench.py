"""Identification of an arm run recorded on the arm bench through the daemon (issue 20): an
uncompensated calibration run of config/arm-sim.toml's make-up (8 h of arm time in 12 steps,
virtual clock, the C500C emulator in joint space on a pty, the bench's cameras and IR), then
``thermocomp identify RUN --json``: joint 2's heat factor (the upper arm's motor, the best
seen) must be the bench truth's own factor (drivers/sim/arm_bench.py: each motor's losses x a
seeded factor) within three of its standard errors."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from config import Settings
from daemon.commands import identify as identify_cli
from daemon.run.states import RunParameters
from daemon.service import Daemon
from drivers.clock import make_clock
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig
from tests.helpers import run_in_process

SEED = 1
STEPS = 12
#: What a 12-step run identifies (the wrist joints' heat is not: docs/explanation/arm.md,
#: "Identifying the arm's model"); fitting only these keeps the test fast.
PARAMS = (
    "--params",
    "heat:2",
    "heat:3",
    "convection",
    "alpha",
    "offset:upper-arm-mid",
    "offset:forearm-mid",
)


def bench_settings(data_dir: Path) -> Settings:
    return Settings.model_validate(
        {
            "bench": {"seed": SEED, "clock": "virtual"},
            "storage": {"data_dir": str(data_dir), "report_at_end": False},
            "scheduler": {"duration_s": 10.0 * STEPS, "step_s": 10.0},
            "compensation": {"time_scale": 240.0, "mode": "off"},
            "camera": {"bit_depth": 12, "grab_timeout_s": 30.0},
            "arm": {
                "enabled": True,
                "duty_cycle": "a465-pick-and-place",
                "bending": True,
                "motor_side_share": 0.75,
            },
        }
    )


@pytest.mark.slow
async def test_identify_a_calibration_run_of_the_arm_bench(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    settings = bench_settings(tmp_path)
    async with Daemon(settings, clock=make_clock("virtual")) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings))
        async with asyncio.timeout(90):
            final = await daemon.wait_run()
    assert final["state"] == "finished", final
    status, out, err = await asyncio.to_thread(
        run_in_process,
        identify_cli.register,
        ["identify", str(info["id"]), "--data-dir", str(tmp_path), "--json", *PARAMS],
        capsys,
    )
    assert status == 0, err
    document = json.loads(out)
    refit = {p["name"]: p for p in document["refit"]["parameters"]}
    truth = ArmBench(ArmBenchConfig(seed=SEED)).heat_scales
    heat = refit["heat:2"]
    assert heat["identifiable"] and 0 < heat["standard_error"] < 0.1
    assert abs(heat["value"] - float(truth[1])) < 3 * heat["standard_error"], (heat, truth)
    assert {"offset:upper-arm-mid", "offset:forearm-mid"} <= set(refit)
    assert document["refit"]["fit"]["marker_samples"] == 3 * STEPS
