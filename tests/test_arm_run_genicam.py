"""An arm run on the hardware path end to end (issue 20): ``robot.driver = "c500c"``, the real
console driver on a real pty to the C500C emulator in joint space (as the arm bench's, but
opened by the factory as a real port: no bench), and ``arm.camera_devices`` = pylon's emulated
GenICam cameras (PYLON_CAMEMU) serving the tool's markers rendered at the run's measured pose
(drivers/sim/camemu.py, tests/test_genicam_markers.py for the measurement itself).

Each emulated camera serves its own folder, one file per frame in name order: the reference's
frames at the taught pose, then one frame per step, the first steps at the taught pose and the
last ones with the tool moved by a known 6-DOF offset. So the run must record ~0 drift, then
the offset, through the real driver, the factory's device order and the arm run's own
measurement."""

from __future__ import annotations

import asyncio
import importlib.util
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

# pylon reads the number of emulated cameras when its transport layers start: before any import
os.environ.setdefault("PYLON_CAMEMU", "2")

from config import Settings
from daemon.arm.loading import load_arm
from daemon.run.arm.prepare import reference_frames
from daemon.run.arm.setup import default_arm_setup
from daemon.run.states import RunParameters
from daemon.service import Daemon
from daemon.vision.cameras import write_cameras
from daemon.vision.markers import marker_pixels
from drivers.clock import make_clock
from drivers.factory import Devices
from drivers.genicam.camera import GenICamCamera
from drivers.sim.arm_devices import VIRTUAL_SPEED_FACTOR
from drivers.sim.camemu import write_emulation_frames, write_feature_file
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.joint_arm import DEFAULT_ACCELERATION_DEG_S2, DEFAULT_SPEED_DEG_S, JointArmConfig
from tests.test_genicam_markers import (
    EMULATED,
    OFFSET_MM,
    OFFSET_RAD,
    device,
    frame_of,
    marker_radius_mm,
    markers_world,
    moved,
    rig,
)

needs_pylon = pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)
ARM = "crs-a465"
DUTY = "a465-pick-and-place"
POSE = "camera"  # the preset's camera station
STEPS = 6
STATIC_STEPS = 3  # then the tool is seen moved by the known offset
BIT_DEPTH = 12
WAIT_S = 120.0


def hardware_settings(tmp_path: Path, port: str, **arm: Any) -> Settings:
    """The lab's settings: a real console port, no bench; the laser-spot camera and the IR
    reader replay one recorded frame (an arm run reads the IR regions each step)."""
    spot = tmp_path / "spot"
    spot.mkdir(exist_ok=True)
    write_emulation_frames(spot, [np.full((582, 752), 3, dtype=np.uint8)], 8)
    thermal = tmp_path / "ir"
    thermal.mkdir(exist_ok=True)
    (thermal / "0.csv").write_text("22.5,22.5\n22.5,22.5\n", encoding="utf-8")
    return Settings.model_validate(
        {
            "bench": {"enabled": False},
            "storage": {"data_dir": str(tmp_path / "data"), "report_at_end": False},
            "scheduler": {"duration_s": 10.0 * STEPS, "step_s": 10.0},
            "compensation": {"time_scale": 240.0},
            "robot": {"driver": "c500c", "port": port, "readback_every": 1},
            "camera": {
                "driver": "replay",
                "replay_dir": str(spot),
                "replay_loop": True,
                "bit_depth": 8,
            },
            "ir": {
                "driver": "replay",
                "replay_dir": str(thermal),
                "replay_loop": True,
                "regions": [{"name": "link", "x": 0, "y": 0, "width": 2, "height": 2}],
            },
            "arm": {
                "enabled": True,
                "arm_file": ARM,
                "duty_cycle": DUTY,
                "measured_poses": [POSE],
                # the frames are a fixed sequence of files, one per grab: the run moves only
                # to the measured pose (an accelerated run cannot play the cycle on a real arm)
                "play_duty_cycle": False,
                **arm,
            },
        }
    )


def joint_space_emulator(seed: int) -> C500CEmulator:
    """The C500C emulator in joint space on a pty (as drivers/sim/arm_devices.py opens it for
    the arm bench), its joints fast on the virtual clock."""
    return C500CEmulator(
        EmulatorConfig(
            seed=seed,
            joint_arm=JointArmConfig(
                arm=load_arm(ARM),
                speed_deg_s=DEFAULT_SPEED_DEG_S * VIRTUAL_SPEED_FACTOR,
                acceleration_deg_s2=DEFAULT_ACCELERATION_DEG_S2 * VIRTUAL_SPEED_FACTOR**2,
            ),
        )
    )


@pytest.mark.slow
@needs_pylon
async def test_an_arm_run_on_the_console_measures_the_known_drift_on_genicam_frames(
    tmp_path: Path,
) -> None:
    async with joint_space_emulator(seed=5) as emulator:
        probe = hardware_settings(tmp_path, emulator.device_path)
        # the pose the run teaches and measures, as the run's own setup computes it
        plan = default_arm_setup(probe, RunParameters.from_settings(probe, duty_cycle=DUTY))
        assert [p.name for p in plan.poses] == [POSE]
        taught = np.asarray(plan.poses[0].tool_pose, dtype=np.float64)
        drifted = moved(taught, OFFSET_MM, OFFSET_RAD)
        models = rig(len(EMULATED), taught[:3, 3])
        write_cameras(tmp_path / "cameras.toml", models)
        rng = np.random.default_rng(11)
        # the reference's frames before the first step (at least MIN_REFERENCE_FRAMES: the
        # meter measures its cameras' scatter on them), then one frame per step
        references = reference_frames(probe)
        poses = [taught] * (references + STATIC_STEPS) + [drifted] * (STEPS - STATIC_STEPS)
        devices = []
        for serial, model in zip(EMULATED, models, strict=True):
            assert marker_pixels(model, markers_world(taught, probe))[1].all()
            frames = [frame_of(model, markers_world(p, probe), BIT_DEPTH, rng) for p in poses]
            folder = write_emulation_frames(tmp_path / serial, frames, BIT_DEPTH)
            feature_file = write_feature_file(tmp_path / f"{serial}.pfs", folder)
            devices.append(device(serial, feature_file, BIT_DEPTH).model_dump(mode="json"))
        settings = hardware_settings(
            tmp_path,
            emulator.device_path,
            cameras_file=str(tmp_path / "cameras.toml"),
            camera_devices=devices,
        )
        async with Daemon(settings, clock=make_clock("virtual")) as daemon:
            opened = daemon.devices
            assert isinstance(opened, Devices)
            assert opened.bench is None and opened.emulator is None  # the hardware path
            assert [type(c) for c in opened.cameras] == [GenICamCamera] * len(EMULATED)
            info = await daemon.start_run(
                RunParameters.from_settings(settings, duty_cycle=DUTY, compensation="absolute")
            )
            async with asyncio.timeout(WAIT_S):
                final = await daemon.wait_run()
            assert daemon.recorder is not None
            steps = [record.as_dict() for record in daemon.recorder.steps(info["id"])]
        commands = list(emulator.state.commands)
    assert final["state"] == "finished", final
    assert len(steps) == STEPS
    assert all(s["flags"] == "" for s in steps), [s["error"] for s in steps]
    # taught at the pose over the console, then moved to goal + correction each step
    assert any(c.startswith(f"here g_{POSE}") for c in commands)
    assert len([c for c in commands if c.startswith("wshift cur,")]) == 1 + 1 + STEPS
    measured_um = np.array([[s[f"measured_t{a}_um"] for a in "xyz"] for s in steps])
    measured_urad = np.array([[s[f"measured_r{a}_urad"] for a in "xyz"] for s in steps])
    sigma_um = np.array([s["measured_sigma_um"] for s in steps])
    assert np.all(sigma_um < 3.0)  # the measurement's 1-sigma (~1.5 um per measurement)
    # the drift relative to the reference frame: two measurements' noise, then the offset
    expected_um = np.zeros((STEPS, 3))
    expected_um[STATIC_STEPS:] = np.array(OFFSET_MM) * 1000.0
    expected_urad = np.zeros((STEPS, 3))
    expected_urad[STATIC_STEPS:] = np.array(OFFSET_RAD) * 1e6
    drift_sigma_um = math.sqrt(2.0) * sigma_um
    translation_error = np.linalg.norm(measured_um - expected_um, axis=1)
    rotation_error = np.linalg.norm(measured_urad - expected_urad, axis=1)
    assert np.all(translation_error < 4 * drift_sigma_um), (translation_error, drift_sigma_um)
    radius_mm = marker_radius_mm(probe)
    assert np.all(rotation_error < 4 * drift_sigma_um / radius_mm * 1000.0), rotation_error
    assert np.all(np.array([s["drift_3d_um"] for s in steps[STATIC_STEPS:]]) > 40.0)
