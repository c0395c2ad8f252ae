"""Arm truths drawn at random within the documented plausible ranges (config/arm_truth.py
``PLAUSIBLE``, docs/explanation/bench-truth.md), written in the truth file's format: the
scenarios a user could write, for benchmarks/bench_arm_scenarios.py."""

from __future__ import annotations

import json
import tomllib

import numpy as np

from config.arm_truth import (
    PLAUSIBLE,
    PLAUSIBLE_ROOM_EXCURSION_C,
    implausible,
    parse_arm_truth,
)

#: The A465's joints (one heat factor each).
JOINTS = 6
#: The room: its start (degC), a drift and a swing drawn so that it stays within the plausible
#: excursion over 8 hours (redrawn otherwise), a swing's period (h).
ROOM_START_C = (16.0, 28.0)
ROOM_SWING_PERIOD_H = (1.0, 12.0)
#: The sensors: a camera jitter, IR noise and IR offsets around the bench's defaults.
JITTER_PX = (0.02, 0.045)
IR_NOISE_C = (0.03, 0.1)
IR_OFFSET_SIGMA_C = (0.1, 0.5)


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return round(float(rng.uniform(*bounds)), 4)


def random_truth_toml(rng: np.random.Generator, description: str) -> str:
    """A plausible truth (every factor uniform within its plausible range, a room within
    PLAUSIBLE_ROOM_EXCURSION_C of its start over 8 h) as a truth file's text."""
    while True:
        heats = [_uniform(rng, PLAUSIBLE["motors.heat"]) for _ in range(JOINTS)]
        limit = PLAUSIBLE_ROOM_EXCURSION_C / 8.0
        lines = [
            f"description = {json.dumps(description)}",
            f"seed = {int(rng.integers(0, 2**31))}",
            "",
            "[motors]",
            f"heat_scales = {json.dumps(heats)}",
            "",
            "[thermal]",
            *(
                f"{key} = {_uniform(rng, PLAUSIBLE[f'thermal.{key}'])}"
                for key in (
                    "expansion_scale",
                    "convection_scale",
                    "capacity_scale",
                    "bending_share",
                )
            ),
            "",
            "[room]",
            f"start_c = {_uniform(rng, ROOM_START_C)}",
            f"drift_c_per_h = {_uniform(rng, (-limit, limit))}",
            f"swing_c = {_uniform(rng, (0.0, 1.0))}",
            f"swing_period_h = {_uniform(rng, ROOM_SWING_PERIOD_H)}",
            "",
            "[measurement]",
            f"jitter_px = {_uniform(rng, JITTER_PX)}",
            f"ir_noise_c = {_uniform(rng, IR_NOISE_C)}",
            f"ir_offset_sigma_c = {_uniform(rng, IR_OFFSET_SIGMA_C)}",
        ]
        text = "\n".join(lines) + "\n"
        if not implausible(parse_arm_truth(tomllib.loads(text), "random truth")):
            return text


__all__ = ["random_truth_toml"]
