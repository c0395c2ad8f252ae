"""A followed run's removal on the UR bench's truth over an 8 h program (issue 31 targets:
uncompensated 3-D drift >= 100 um; preset model >= 80 % removed; joint temperatures with no
camera >= 90 % removed).

The UR emulator's controller (drivers/sim/ur/controller.py: the UR5e pick-and-place program
played on the joint arm, the bench truth with its own seeded geometry, heat, convection and
expansion, joint temperatures read like a sensor: noise and 1/16 degC resolution) is sampled
every SAMPLE_S of emulator time without its 500 Hz network loop (8 h of cycles would take
hours): at each sample the daemon's model (daemon/run/followed/setup.py's, the same code the
followed run steps) is advanced, fed the emulated joint temperatures (mode "joints") or not
(mode "preset"), and its correction at the program's current joints is taken as applied
exactly (the robot-side program's rate limit, 1 mm/s, is far above a thermal drift's rate);
the residual is the truth's error plus that correction. Reference in the same run: the
uncompensated drift (the truth's error alone). Removal = 1 - rms(residual)/rms(uncompensated)
over the samples of the last 4 h (a warm arm), worst = max |residual| over all samples.

Scenarios: the nominal bench (seeds 1, 2), and three written to break the model: motors
heating 60 % more than the model assumes (heat x1.6), a room drifting 1 degC/h, and a truth
with its convection halved (scale 0.4, the bench's 0.8). ``--quick``: 2 h, seed 1 only.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config.settings import Settings, load_settings
from daemon.arm.correction import correction_for
from daemon.arm.types import pose_difference
from daemon.run.followed.setup import followed_model
from daemon.run.states import RunParameters
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig
from drivers.sim.ur.controller import URController, URControllerConfig

CONFIG = Path(__file__).resolve().parent.parent / "config" / "ur5e-sim.toml"
SAMPLE_S = 60.0
HOURS = 8.0
UM_PER_MM = 1000.0


def scenarios(quick: bool) -> list[tuple[str, int, dict[str, Any]]]:
    nominal = [("nominal seed 1", 1, {})]
    if quick:
        return nominal
    return [
        *nominal,
        ("nominal seed 2", 2, {}),
        ("heat x1.6", 1, {"heat_scales": (1.6,) * 6}),
        ("room +1 degC/h", 1, {"ambient_drift_c_per_h": 1.0}),
        ("convection halved", 1, {"convection_scale": 0.4}),
    ]


def emulated(seed: int, truth: dict[str, Any]) -> URController:
    controller = URController(URControllerConfig(seed=seed))
    if truth:  # the same program, a truth made to break the model
        base = controller.bench.config
        config = ArmBenchConfig(
            arm=base.arm,
            seed=seed,
            node_spacing_mm=base.node_spacing_mm,
            payload_kg=base.payload_kg,
            **truth,
        )
        controller.bench = ArmBench(config, motion=controller.player, arm=controller.arm)
    return controller


def run(settings: Settings, seed: int, truth: dict[str, Any], hours: float) -> dict[str, Any]:
    parameters = RunParameters.from_settings(settings, step_s=SAMPLE_S)
    models = {
        "preset": followed_model(settings, parameters.model_copy(update={"prediction": "model"})),
        "joints": followed_model(settings, parameters),
    }
    controller = emulated(seed, truth)
    bench = controller.bench
    residual: dict[str, list[float]] = {name: [] for name in models}
    uncompensated: list[float] = []
    began = time.process_time()
    for t in (float(v) for v in np.arange(SAMPLE_S, hours * 3600.0 + 1e-6, SAMPLE_S)):
        controller.player.advance(t)
        temperatures = controller.joint_temperatures(t)  # advances the truth to t
        bench.advance_to(t)
        _, _, q = controller.joint_state(t)
        cold = bench.tool_pose_cold(q)
        error = pose_difference(cold, bench.tool_pose_true(q)).translation_mm
        uncompensated.append(float(np.linalg.norm(error)) * UM_PER_MM)
        for name, model in models.items():
            model.advance_to(t)
            model.observe(temperatures)
            correction = correction_for(model.tool_error(q)).translation_mm
            residual[name].append(float(np.linalg.norm(error + correction)) * UM_PER_MM)
    cpu_s = time.process_time() - began
    warm = len(uncompensated) // 2  # the last half: a warm arm

    def rms(values: list[float]) -> float:
        return math.sqrt(sum(v * v for v in values) / len(values))

    result: dict[str, Any] = {
        "samples": len(uncompensated),
        "uncompensated_rms_um": rms(uncompensated[warm:]),
        "uncompensated_max_um": max(uncompensated),
        "cpu_s": cpu_s,
    }
    for name, values in residual.items():
        result[f"{name}_rms_um"] = rms(values[warm:])
        result[f"{name}_max_um"] = max(values)
        result[f"{name}_removed"] = 1.0 - rms(values[warm:]) / result["uncompensated_rms_um"]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    hours = 2.0 if args.quick else HOURS
    settings = load_settings(CONFIG)
    rows = []
    results: dict[str, Any] = {"hours": hours, "sample_s": SAMPLE_S, "scenarios": {}}
    load_before = os.getloadavg()[0]
    for name, seed, truth in scenarios(args.quick):
        r = run(settings, seed, truth, hours)
        results["scenarios"][name] = r
        rows.append(
            [
                name,
                r["uncompensated_rms_um"],
                r["uncompensated_max_um"],
                r["preset_rms_um"],
                f"{100 * r['preset_removed']:.1f} %",
                r["joints_rms_um"],
                f"{100 * r['joints_removed']:.1f} %",
                r["joints_max_um"],
            ]
        )
    results["load_1min"] = [load_before, os.getloadavg()[0]]
    print(f"{hours:g} h of the UR5e pick-and-place program, sampled every {SAMPLE_S:g} s")
    print_table(
        [
            "scenario",
            "uncomp rms um",
            "uncomp max um",
            "preset rms um",
            "preset removed",
            "joints rms um",
            "joints removed",
            "joints max um",
        ],
        rows,
    )
    print(f"load (1 min) before/after: {results['load_1min']}")
    write_results("ur_followed", results)


if __name__ == "__main__":
    main()
