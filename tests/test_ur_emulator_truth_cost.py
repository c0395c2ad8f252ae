"""The UR emulator's controller cycle stays short while its thermal truth advances (issue 31,
the correction latency): the truth follows the arm's motion every TRUTH_FOLLOW_CYCLES cycles
(drivers/sim/arm_bench.py ``follow_motion``), so no cycle -- nor the package of joint
temperatures that steps the truth every 2 s -- samples a whole truth step of motion at once
(before: 200 samples and their motor torques inside one 2 ms cycle, every 2 s). Counted in
motion samples per call, not in milliseconds; and the truth it gives is the one the whole
steps gave (the same trapezoids on the same 10 ms grid)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from daemon.arm.types import FloatArray
from drivers.sim.ur.controller import TRUTH_FOLLOW_CYCLES, URController
from drivers.ur.rtde_protocol import CONTROLLER_CYCLE_S

#: emulated time run (s): past two of the truth's 2-s steps
RUN_S = 4.5


def test_no_cycle_samples_a_whole_truth_step_of_motion() -> None:
    controller = URController()
    energy = controller.bench.energy
    sampled: list[int] = []
    powers = energy._powers

    def counted(times: NDArray[np.floating[Any]]) -> FloatArray:
        sampled.append(int(times.size))
        return powers(times)

    energy._powers = counted  # type: ignore[method-assign]
    per_cycle: list[int] = []
    for cycle in range(1, round(RUN_S / CONTROLLER_CYCLE_S) + 1):
        t = cycle * CONTROLLER_CYCLE_S
        before = sum(sampled)
        controller.cycle(t)
        controller.joint_temperatures(t)  # what a package of the driver's recipe reads
        per_cycle.append(sum(sampled) - before)
    assert controller.bench.thermal.time_s == 4.0  # two truth steps were taken
    follow_s = TRUTH_FOLLOW_CYCLES * CONTROLLER_CYCLE_S
    # at most one follow's motion (10 ms samples) in any cycle: never a whole 2-s step
    assert max(per_cycle) <= round(follow_s / energy.motion_step_s) + 1, max(per_cycle)
    assert sum(sampled) >= round(4.0 / energy.motion_step_s)  # the motion was integrated


def test_the_truth_it_follows_is_the_one_of_whole_steps() -> None:
    followed, stepped = URController(), URController()
    for cycle in range(1, round(RUN_S / CONTROLLER_CYCLE_S) + 1):
        t = cycle * CONTROLLER_CYCLE_S
        followed.cycle(t)
        stepped.player.advance(t)  # the same motion, its truth stepped as before: whole
        if cycle % round(2.0 / CONTROLLER_CYCLE_S) == 0:  # steps at their boundaries
            stepped.bench.advance_to(t)
    stepped.bench.advance_to(RUN_S)
    followed.bench.advance_to(RUN_S)
    heated = followed.bench.thermal.temperatures_c - followed.bench.config.ambient_c
    assert float(np.max(heated)) > 1e-4  # the motors heated the arm: a real comparison
    np.testing.assert_allclose(
        followed.bench.thermal.temperatures_c,
        stepped.bench.thermal.temperatures_c,
        rtol=0.0,
        atol=1e-9 * float(np.max(heated)) + 1e-12,
    )
