"""End to end (issue 20): an arm run on the arm bench through the daemon, the console driver
and the C500C emulator in joint space over a real pty, with compensation on: the recorded 3-D
residual must be smaller than the uncompensated drift of a same-seed run.

Virtual clock; the duty cycle's hours pass in model time (``time_scale``): 24 steps of 10 s of
run clock at x120 are 8 h of the arm warming up (the A465 preset drifts ~180 um in 8 h). The
controller's model is the presets' (daemon/arm/controller.py through the daemon's default
arm setup); the truth heats 20 % more, on a finer network (tests/arm_sim.py), so the residual
is the model's error plus the 3-D measurement's noise.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from config import Settings
from daemon.runs import RunParameters
from daemon.service import Daemon
from drivers.clock import Clock, make_clock
from tests.arm_sim import HEAT_FACTOR, ArmDevices, open_arm_devices, write_duty_cycle

SEED = 7
STEPS = 24
WAIT_S = 60.0


def settings_for(tmp_path: Path) -> Settings:
    tmp_path.mkdir(parents=True, exist_ok=True)
    duty = str(write_duty_cycle(tmp_path))
    return Settings.model_validate(
        {
            "storage": {"data_dir": str(tmp_path), "report_at_end": False},
            "scheduler": {"duration_s": 10.0 * STEPS, "step_s": 10.0},
            "compensation": {"time_scale": 120.0},
            "robot": {"driver": "sim", "readback_every": 1},
            "camera": {"bit_depth": 12, "grab_timeout_s": 10.0},
            "arm": {"enabled": True, "duty_cycle": duty},
        }
    )


async def one_run(
    tmp_path: Path, **overrides: Any
) -> tuple[dict[str, Any], list[dict[str, Any]], ArmDevices]:
    settings = settings_for(tmp_path)
    clock = make_clock("virtual")
    opened: list[ArmDevices] = []

    @asynccontextmanager
    async def opener(settings: Settings, clock: Clock) -> AsyncIterator[ArmDevices]:
        async with open_arm_devices(settings, clock, SEED) as devices:
            opened.append(devices)
            yield devices

    async with Daemon(settings, clock=clock, open_devices=opener) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings, **overrides))
        async with asyncio.timeout(WAIT_S):
            final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = [record.as_dict() for record in daemon.recorder.steps(info["id"])]
    return final, steps, opened[0]


async def test_compensated_arm_run_beats_the_uncompensated_drift(tmp_path: Path) -> None:
    off, off_steps, off_devices = await one_run(tmp_path / "off", compensation="off")
    on, on_steps, devices = await one_run(tmp_path / "on", compensation="absolute")
    for final, steps in ((off, off_steps), (on, on_steps)):
        assert final["state"] == "finished", final
        assert len(steps) == STEPS
        assert all(s["flags"] in ("", "no-readback") for s in steps), [s["error"] for s in steps]
        assert all(s["drift_3d_um"] is not None for s in steps)
    # the robot was taught each measured pose and moved to goal + correction through the pty
    commands = list(devices.emulator.state.commands)
    assert any(c.startswith("here g_camera") for c in commands)
    assert any(c.startswith("here g_place") for c in commands)
    # two teaching moves, the two references, then one move per step: each `wshift cur,...`
    shifts = [c for c in commands if c.startswith("wshift cur,")]
    assert len(shifts) == 2 + 2 + STEPS, commands[-20:]
    drift = np.array([s["drift_3d_um"] for s in off_steps])
    residual = np.array([s["drift_3d_um"] for s in on_steps])
    predicted = np.array(
        [np.linalg.norm([s[f"predicted_t{a}_um"] for a in "xyz"]) for s in on_steps]
    )
    # uncompensated: the arm drifts by ~HEAT_FACTOR x the prediction (the truth heats more)
    assert drift.max() > 100.0
    assert drift[-1] == pytest.approx(HEAT_FACTOR * predicted[-1], rel=0.3)
    # compensated: what is left is the model's error and the measurement's noise
    assert residual.max() < 0.5 * drift.max()
    assert np.sqrt(np.mean(residual[-8:] ** 2)) < 0.5 * np.sqrt(np.mean(drift[-8:] ** 2))
    corrections = np.array([[s[f"correction_t{a}_mm"] for a in "xyz"] for s in on_steps])
    np.testing.assert_allclose(
        corrections * 1000.0,
        -np.array([[s[f"predicted_t{a}_um"] for a in "xyz"] for s in on_steps]),
        atol=1e-6,
    )
    summary = on["summary"]
    assert summary["drift_3d_max_um"] == pytest.approx(residual.max())
    assert off_devices.bench.duty_cycles == [str(tmp_path / "off" / "bench-pick-and-place.toml")]
