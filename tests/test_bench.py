"""The simulated bench: physics where it should be, one clock, and seeded determinism."""

from __future__ import annotations

import asyncio
import hashlib
import math
import os
from typing import Any

import numpy as np
import pytest

from config import ConfigError
from config.settings import Settings
from daemon.model import load_network
from daemon.vision import measure_centroid, measure_with_camera_settings
from drivers.c500c.robot import C500CRobot
from drivers.clock import VirtualClock
from drivers.factory import open_devices
from drivers.sim.bench import Bench, scale_convection
from drivers.sim.devices import LINK_ROWS


def settings(**sections: dict[str, Any]) -> Settings:
    data: dict[str, Any] = {"robot": {"command_timeout_s": 2.0}}
    for name, values in sections.items():
        data[name] = {**data.get(name, {}), **values}
    return Settings.model_validate(data)


async def record_run(config: Settings) -> list[str]:
    """Digest of everything a short compensation-like run observes."""
    clock = VirtualClock()
    observed: list[str] = []
    async with open_devices(config, clock) as devices:
        assert devices.bench is not None
        await devices.robot.teach_goal()
        for step in range(4):
            await clock.sleep_until(step * 300.0)
            offset_um = -devices.bench.true_deformation_um(clock.now())[0]
            move = await devices.robot.move_absolute((offset_um / 1000.0, 0.0, 0.0))
            frame = await devices.camera.grab()
            reading = await devices.ir.read()
            assert reading.frame_c is not None
            observed += [
                repr(move.actual),
                hashlib.sha256(frame.image.tobytes()).hexdigest(),
                hashlib.sha256(reading.frame_c.tobytes()).hexdigest(),
            ]
    return observed


@pytest.mark.slow
async def test_same_seed_same_run_other_seed_other_run() -> None:
    first = await record_run(settings(bench={"seed": 11}))
    assert first == await record_run(settings(bench={"seed": 11}))
    other = await record_run(settings(bench={"seed": 12}))
    assert all(a != b for a, b in zip(first[1::3], other[1::3], strict=True))  # frames


async def test_sim_robot_is_the_real_driver_on_a_real_pty() -> None:
    async with open_devices(settings(), VirtualClock()) as devices:
        assert isinstance(devices.robot, C500CRobot)
        assert devices.emulator is not None
        target = await asyncio.to_thread(os.readlink, devices.emulator.device_path)
        assert target.startswith("/dev/pts/")
        assert devices.robot.status().link.value == "connected"


async def test_sim_drivers_need_the_bench() -> None:
    with pytest.raises(ConfigError, match=r"bench\.enabled"):
        async with open_devices(settings(bench={"enabled": False}), VirtualClock()):
            pass


async def test_spot_goes_where_physics_puts_it() -> None:
    """Deformation x scale + robot offset + stand drift, through the 8.6 x 8.3 um pitch,
    measured back with the centroid of the vision work. (Spread 0: the stand drift is exactly
    the configured first-order lag; the seed's draw is tested in test_bench_truth.py.)"""
    config = settings(
        bench={
            "robot_noise_um": 0.0,
            "stand_drift_um": 2.0,
            "stand_drift_tau_s": 600.0,
            "stand_drift_spread": 0.0,
        },
        compensation={"deformation_scale": 5.0},
    )
    clock = VirtualClock()
    async with open_devices(config, clock) as devices:
        bench = devices.bench
        assert bench is not None
        await devices.robot.teach_goal()
        await clock.sleep_until(600.0)
        deformation = bench.true_deformation_um(600.0)
        assert deformation[0] > 10.0 and deformation[1] == deformation[2] == 0.0
        drift = 2.0 * (1.0 - math.exp(-1.0))
        assert bench.stand_drift_um(600.0) == pytest.approx(drift)
        move = await devices.robot.move_absolute((-0.050, 0.0, 0.0172))
        assert move.actual.x == pytest.approx(move.commanded_mm[0] + 457.2)
        expected_x = (5.0 * deformation[0] - 50.0 + drift) / 8.6
        assert move.commanded_mm == (-0.05, 0.0, 0.017)  # the console's 0.001 mm
        expected_y = -17.0 / 8.3
        centre = bench.spot_centre_px(600.0)
        assert centre[0] == pytest.approx(375.5 + expected_x, abs=1e-9)
        assert centre[1] == pytest.approx(290.5 + expected_y, abs=1e-9)
        frame = await devices.camera.grab()
        assert frame.timestamp_s == 600.0 and frame.image.dtype == np.uint16
        # the bench's camera knows its sensor and says so (bench.camera_gain_e_per_count)
        assert frame.gain_e_per_count == 1.0
    measured = measure_centroid(frame.image, bit_depth=16)
    assert measured.x_px == pytest.approx(centre[0], abs=0.05)
    assert measured.y_px == pytest.approx(centre[1], abs=0.05)


@pytest.mark.slow
def test_truth_is_linear_in_heat_and_follows_the_heater_schedule() -> None:
    clock = VirtualClock()
    base = Bench(settings(), clock)
    doubled = Bench(settings(bench={"truth_heat_scale": 2.0}), clock)
    for t_s in (30.0, 900.0):
        assert doubled.true_deformation_um(t_s)[0] == pytest.approx(
            2.0 * base.true_deformation_um(t_s)[0], rel=1e-9
        )
    cooling = Bench(settings(bench={"heater_off_s": 900.0}), clock)
    at_off = cooling.true_deformation_um(900.0)[0]
    assert at_off == pytest.approx(base.true_deformation_um(900.0)[0], rel=1e-12)
    assert cooling.true_deformation_um(2000.0)[0] < at_off
    unheated = Bench(settings(bench={"heater_power_w": 0.0}), clock)
    assert unheated.true_deformation_um(900)[0] == pytest.approx(0.0, abs=1e-6)


def test_truth_is_finer_than_the_model_and_can_differ_from_it() -> None:
    bench = Bench(settings(), VirtualClock())
    model_nodes = load_network("thesis-two-link").node_count
    assert bench.network.node_count > 10 * model_nodes
    more_air = Bench(settings(bench={"truth_convection_scale": 3.0}), VirtualClock())
    assert more_air.true_deformation_um(1800)[0] < bench.true_deformation_um(1800)[0]


def test_moving_case_cools_the_wiping_link_only() -> None:
    network = load_network("thesis-two-link")
    scaled = scale_convection(network, 2.0, 330.2)
    moving = network.positions_mm >= 330.2
    assert np.array_equal(scaled.r_ambient_c_per_w[~moving], network.r_ambient_c_per_w[~moving])
    assert np.allclose(scaled.r_ambient_c_per_w[moving], network.r_ambient_c_per_w[moving] / 2)
    still = Bench(settings(), VirtualClock())
    wiping = Bench(settings(scheduler={"procedure": "moving"}), VirtualClock())
    positions = np.array([100.0, 600.0])
    t_still = still.temperatures_at(positions, 1800.0)
    t_wiping = wiping.temperatures_at(positions, 1800.0)
    assert t_wiping[1] < t_still[1]  # the moving link runs cooler
    assert t_wiping[0] - 22.0 > 0.9 * (t_still[0] - 22.0)  # the still link barely changes


async def test_ir_reads_the_truth_with_its_noise_and_offset() -> None:
    config = settings(ir={"noise_c": 0.08, "offset_c": 1.5})
    clock = VirtualClock()
    async with open_devices(config, clock) as devices:
        bench = devices.bench
        assert bench is not None
        await clock.sleep_until(1200.0)
        reading = await devices.ir.read()
    network = load_network("thesis-two-link")
    assert set(reading.regions) == {"node-2", "node-9", "node-16"}
    for region in reading.regions.values():
        assert region.node is not None
        position = float(network.positions_mm[network.node_index(region.node)])
        truth = float(bench.temperatures_at(np.array([position]), 1200.0)[0])
        pixels = 3 * (LINK_ROWS[1] - LINK_ROWS[0])
        # the region spans 3 columns of ~4 mm: allow the profile's slope over them
        assert region.mean_c == pytest.approx(truth + 1.5, abs=5 * 0.08 / math.sqrt(pixels) + 0.1)
    assert reading.frame_c is not None
    background = reading.frame_c[:20].ravel()
    assert np.std(background, ddof=1) == pytest.approx(0.08, rel=0.1)
    assert np.mean(background) == pytest.approx(22.0 + 1.5, abs=0.01)


def test_a_run_starts_from_cold_at_its_own_time() -> None:
    fresh = Bench(settings(), VirtualClock())
    reused = Bench(settings(bench={"heater_off_s": 50.0}), VirtualClock())
    assert reused.true_deformation_um(1000.0)[0] > 0  # warmed and cooled before the run
    reused.start_run(1000.0, deformation_scale=4.0, heater_off_s=None)
    assert reused.true_deformation_um(1000.0)[0] == 0.0
    # time-invariant physics: the run at 1000 + t is the fresh bench at t
    assert reused.true_deformation_um(1600.0)[0] == pytest.approx(
        fresh.true_deformation_um(600.0)[0], rel=1e-9
    )
    x_um, _ = reused.spot_offset_um(1600.0)
    assert x_um == pytest.approx(
        4.0 * fresh.true_deformation_um(600.0)[0] + reused.stand_drift_um(1600.0), rel=1e-9
    )


async def test_sim_camera_can_keep_its_gain_to_itself() -> None:
    """As a GenICam camera does (SFNC has no electrons-per-count node): no gain on the frame,
    and the centroid measures it on the frame."""
    config = settings(bench={"camera_reports_gain": False, "camera_gain_e_per_count": 4.0})
    clock = VirtualClock()
    async with open_devices(config, clock) as devices:
        frame = await devices.camera.grab()
    assert frame.gain_e_per_count is None
    result = measure_with_camera_settings(frame.image, config.camera)
    assert result.gain_source == "frames"
    assert result.gain_e_per_count == pytest.approx(4.0, rel=0.3)
