"""A followed run on the UR bench (config/ur5e-sim.toml) through a real uvicorn server: the UR
emulator on a loopback address serves RTDE to the real UR driver; the run follows the
program, the steps are recorded with the joint temperatures and the bench truth; a hold
through the API reaches the emulated program as its hold flag and no correction is written
into its registers after it; the run stops with a followed summary."""

from __future__ import annotations

import asyncio
from pathlib import Path

import httpx
import pytest
from websockets.asyncio.client import connect

from api.app import create_app
from config import CONFIG_DIR
from config.settings import load_settings
from daemon.service import Daemon
from drivers.ur import registers
from drivers.ur.modes import RuntimeState
from tests.loopback import loopback_host
from tests.test_api_runs import CONTROL_HEADERS, next_of_type, wait_state
from tests.test_api_server import CONTROL, READ, serve

WAIT_S = 60.0


@pytest.mark.slow
async def test_a_followed_run_through_the_api_holds_the_program(tmp_path: Path) -> None:
    base = load_settings(CONFIG_DIR / "ur5e-sim.toml")
    host = loopback_host()  # the emulator serves UR's fixed ports on an address of its own
    settings = base.model_validate(
        {
            **base.model_dump(),
            # the emulator runs in this process: on a loaded machine a second without a state
            # package is the test starved, not a link fault (tests/test_ur_program_pause.py)
            "robot": {**base.robot.model_dump(), "host": host, "ur_timeout_s": 10.0},
            "scheduler": {**base.scheduler.model_dump(), "step_s": 0.1, "duration_s": 600.0},
            "storage": {**base.storage.model_dump(), "data_dir": str(tmp_path / "data")},
            "api": {"control_token": CONTROL, "read_token": READ, "control_burst": 50},
        }
    )
    app = create_app(settings, service_factory=Daemon)

    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
        connect(
            f"ws://{address}/api/v1/ws?topics=steps",
            additional_headers={"Authorization": f"Bearer {READ}"},
        ) as ws,
    ):
        daemon: Daemon = app.state.context.service
        emulator = daemon._devices.ur_emulator  # type: ignore[union-attr]
        assert emulator is not None
        controller = emulator.controller
        regs = controller.registers
        # no camera and no IR reader: health says so, never "open" as if a frame were to come
        devices = (await client.get("/api/v1/health")).json()["devices"]
        assert (devices["camera"], devices["ir"]) == ("none", "none"), devices
        started = await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)
        assert started.status_code == 201, started.text
        run_id = started.json()["id"]
        steps = [(await next_of_type(ws, "step", WAIT_S))["data"] for _ in range(5)]
        assert {s["run_id"] for s in steps} == {run_id}
        last = steps[-1]
        # the bench truth's residual, or (the first step of a dwell at a measured pose) the
        # tool cameras' measurement: a step measures either way
        camera = last["measured_sigma_um"] is not None
        assert camera != ("bench-truth" in last["flags"]) and last["drift_3d_um"] is not None
        assert last["ir_json"] is not None and "joint6" in last["ir_json"]
        assert last["correction_tx_mm"] is not None
        assert controller.writes[regs.target[0]] >= 1  # corrections reached the program

        held = await client.post("/api/v1/robot/stop", headers=CONTROL_HEADERS)
        assert held.status_code == 200 and held.json()["held"] is True
        async with asyncio.timeout(WAIT_S):  # the hold flag reaches the controller, then
            # its program (a cycle later); what was written before it has been read by then.
            # Or the hold's pause of the program (robot.pause_program_on_hold, sent after the
            # flag) came before that cycle: a paused program applies nothing either
            while not (  # noqa: ASYNC110 -- the emulator's state, read not awaited
                controller.program.status & registers.STATUS_HELD
                or controller.runtime_state is RuntimeState.PAUSED
            ):
                await asyncio.sleep(0.01)
        assert controller.inputs[regs.hold] == 1
        written = controller.writes[regs.target[0]]
        frozen = controller.program.applied
        heartbeats = controller.writes[regs.sequence]
        await asyncio.sleep(1.0)  # ten step periods
        assert controller.writes[regs.target[0]] == written  # no correction after the hold
        assert controller.writes[regs.sequence] > heartbeats  # the heartbeat goes on
        assert controller.program.applied == frozen  # the offset frozen where it was
        await wait_state(client, "paused")

        stopped = await client.post(f"/api/v1/runs/{run_id}/stop", headers=CONTROL_HEADERS)
        assert stopped.status_code == 200, stopped.text
        info = stopped.json()
        assert info["state"] == "stopped"
        summary = info["summary"]
        assert summary["kind"] == "followed" and summary["corrections_written"] >= 5
        assert summary["bench_truth"]["steps"] >= 5
