"""Issue 20 through the daemon: calibration run -> identification -> compensated runs, on the
simulated arm bench (config/arm-sim.toml: the A465's pick-and-place, 8 h of arm time in 12
steps of 10 s at time_scale 240, virtual clock, the C500C emulator in joint space on a pty).

Every run goes through the real daemon (daemon.service.Daemon: scheduler, session, arm step,
recorder) and is read back from its database, as ``thermocomp run`` and ``thermocomp identify``
would (in process here, to time them):

1. a calibration run, compensation off, with another measurement noise (``bench.noise_seed``):
   ``thermocomp identify`` of it (daemon/commands/arm_identify.py: every parameter, then the
   identifiable ones refitted), saved as an arm model;
2. uncompensated (the drift; the reference of the reductions);
3. the preset arm model;
4. the identified arm model (``--arm-model``);
5. the identified arm model with the IR observer (``--prediction model+ir``).

Reported per run: the measured 3-D residual (RMS and largest over the steps; the drift
measured at each pose's taught goal relative to its cold reference), the share of the
uncompensated RMS removed, the RMS over the 3-D measurement's own 1-sigma (the meter's
estimate from the centroids' noise, ``measured_sigma_um``), the rotation error (RMS).

    .venv/bin/python benchmarks/bench_arm_daemon.py [--seed N] [--cameras N] [--frames N]
        [--no-identify]

``--cameras 1``: one camera at each measured pose (``arm.cameras``), the tool's pose from the
markers' pixels by perspective-n-point (daemon/vision/pnp.py). ``--no-identify``: the
uncompensated and preset runs only (no calibration run, no identification). ``--frames N``:
``arm.frames_per_measurement`` (each marker's centroid averaged over N frames per camera).
The rotation error is reported with the meter's own 1-sigma of the orientation
(``measured_rotation_sigma_urad``) and their ratio, as the 3-D drift is.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config import Settings, load_settings
from daemon.arm.arm_model import arm_model_toml, new_arm_model_path
from daemon.commands.arm_identify import arm_model_of, identify_arm_run, load_arm_run
from daemon.run.states import RunParameters
from daemon.service import Daemon
from drivers.clock import make_clock
from drivers.sim.arm_markers import CameraRig

CONFIG = Path(__file__).resolve().parent.parent / "config" / "arm-sim.toml"
#: The calibration run's measurement noise is drawn from this seed + the bench's seed.
CALIBRATION_NOISE_OFFSET = 1000
MODEL_NAME = "bench-calibration"


def settings_for(
    data_dir: Path,
    seed: int,
    noise_seed: int | None,
    cameras: int | None = None,
    frames: int | None = None,
) -> Settings:
    data = load_settings(CONFIG).model_dump()
    data["bench"].update({"seed": seed, "noise_seed": noise_seed})
    if cameras is not None:
        data["arm"]["cameras"] = cameras
    if frames is not None:
        data["arm"]["frames_per_measurement"] = frames
    data["storage"].update({"data_dir": str(data_dir), "report_at_end": False})
    return Settings.model_validate(data)


async def one_run(settings: Settings, **overrides: Any) -> tuple[int, dict[str, Any], list[Any]]:
    """One run through the daemon on the arm bench: (run id, final info, recorded steps)."""
    async with Daemon(settings, clock=make_clock("virtual")) as daemon:
        parameters = RunParameters.from_settings(settings, **overrides)
        info = await daemon.start_run(parameters)
        final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = [record.as_dict() for record in daemon.recorder.steps(info["id"])]
    if final["state"] != "finished":
        raise RuntimeError(f"run {info['id']} ended {final['state']}: {final.get('reason')}")
    return int(info["id"]), final, steps


def sight_of_one_camera(settings: Settings) -> np.ndarray | None:
    """With one camera per pose: the unit direction from the camera to the tool (the bench's
    rig, drivers/sim/arm_markers.py CameraRig: the same at every station), else None."""
    if settings.arm.cameras != 1:
        return None
    rig = CameraRig(count=1)
    elevation, azimuth = rig.elevation_rad, rig.azimuth_rad
    towards_camera = np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )
    return -towards_camera


def figures(steps: Sequence[dict[str, Any]], sight: np.ndarray | None = None) -> dict[str, Any]:
    drift = np.array([s["drift_3d_um"] for s in steps], dtype=float)
    rotation = np.array([s["rotation_error_urad"] for s in steps], dtype=float)
    sigma = np.array([s["measured_sigma_um"] for s in steps], dtype=float)
    rotation_sigma = np.array([s["measured_rotation_sigma_urad"] for s in steps], dtype=float)
    predicted = np.array([[s[f"predicted_t{a}_um"] for a in "xyz"] for s in steps], dtype=float)
    return {
        "rms_3d_um": float(np.sqrt(np.nanmean(drift**2))),
        "max_3d_um": float(np.nanmax(drift)),
        "last_third_rms_3d_um": float(np.sqrt(np.nanmean(drift[-len(drift) // 3 :] ** 2))),
        "rms_rotation_urad": float(np.sqrt(np.nanmean(rotation**2))),
        "max_rotation_urad": float(np.nanmax(rotation)),
        "noise_3d_um": float(np.nanmean(sigma)),
        "noise_rotation_urad": float(np.nanmean(rotation_sigma)),
        "predicted_max_3d_um": float(np.nanmax(np.linalg.norm(predicted, axis=1))),
        "drift_3d_um_per_step": [round(float(v), 2) for v in drift],
        "poses": [s["arm_pose"] for s in steps],
        **({} if sight is None else split_by_sight(steps, sight)),
    }


def split_by_sight(steps: Sequence[dict[str, Any]], sight: np.ndarray) -> dict[str, float]:
    """The measured drift's RMS along the one camera's line of sight and across it."""
    measured = np.array([[s[f"measured_t{a}_um"] for a in "xyz"] for s in steps], dtype=float)
    along = measured @ sight
    across = np.linalg.norm(measured - np.outer(along, sight), axis=1)
    return {
        "rms_along_sight_um": float(np.sqrt(np.nanmean(along**2))),
        "rms_across_sight_um": float(np.sqrt(np.nanmean(across**2))),
    }


async def bench(
    seed: int,
    data_dir: Path,
    cameras: int | None = None,
    identify: bool = True,
    frames: int | None = None,
) -> dict[str, Any]:
    started = time.perf_counter()
    walls: dict[str, float] = {}
    settings = settings_for(data_dir, seed, None, cameras, frames)
    if not identify:
        results = await compare(settings, {"none": {"compensation": "off"}, "preset": {}}, walls)
        return {
            "seed": seed,
            "cameras": settings.arm.cameras,
            "frames": settings.arm.frames_per_measurement,
            "steps": round(settings.scheduler.duration_s / settings.scheduler.step_s),
            "runs": results,
            "wall_s": {**walls, "total": time.perf_counter() - started},
        }
    calibration_settings = settings_for(
        data_dir, seed, seed + CALIBRATION_NOISE_OFFSET, cameras, frames
    )

    t = time.perf_counter()
    calibration_id, _, calibration_steps = await one_run(calibration_settings, compensation="off")
    walls["calibration run"] = time.perf_counter() - t
    t = time.perf_counter()
    run = await asyncio.to_thread(load_arm_run, data_dir, calibration_id)
    full, refit = await asyncio.to_thread(identify_arm_run, run, None)
    model = arm_model_of(MODEL_NAME, run, full, refit)
    path = new_arm_model_path(MODEL_NAME, data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(arm_model_toml(model), encoding="utf-8")
    walls["identification"] = time.perf_counter() - t

    cases: dict[str, dict[str, Any]] = {
        "none": {"compensation": "off"},
        "preset": {},
        "identified": {"arm_model": MODEL_NAME},
        "identified + model+ir": {"arm_model": MODEL_NAME, "prediction": "model+ir"},
    }
    results = await compare(settings, cases, walls)
    return {
        "seed": seed,
        "cameras": settings.arm.cameras,
        "frames": settings.arm.frames_per_measurement,
        "steps": round(settings.scheduler.duration_s / settings.scheduler.step_s),
        "calibration": {
            "run_id": calibration_id,
            "noise_seed": seed + CALIBRATION_NOISE_OFFSET,
            **figures(calibration_steps),
            "all": full.to_dict(),
            "refit": refit.to_dict(),
            "arm_model": model.provenance(),
        },
        "runs": results,
        "wall_s": {**walls, "total": time.perf_counter() - started},
    }


async def compare(
    settings: Settings, cases: dict[str, dict[str, Any]], walls: dict[str, float]
) -> dict[str, dict[str, Any]]:
    """One run per case, the first (uncompensated) the reference of the others."""
    results: dict[str, dict[str, Any]] = {}
    reference: int | None = None
    for name, case in cases.items():
        t = time.perf_counter()
        given = case if reference is None else {**case, "reference_run": reference}
        run_id, final, steps = await one_run(settings, **given)
        walls[name] = time.perf_counter() - t
        if name == "none":
            reference = run_id
        results[name] = {**figures(steps, sight_of_one_camera(settings)), "run_id": run_id}
        summary = final.get("summary") or {}
        results[name]["summary_reduction_3d_percent"] = summary.get("reduction_3d_percent")
    add_ratios(results)
    return results


def add_ratios(runs: dict[str, dict[str, Any]]) -> None:
    """Each run's share of the uncompensated run's ("none") RMS removed, in 3-D and rotation,
    and each RMS over the meter's own 1-sigma (this benchmark's and bench_arm_played's)."""
    drift = runs["none"]
    for run in runs.values():
        run["reduction_3d"] = 1.0 - run["rms_3d_um"] / drift["rms_3d_um"]
        run["rms_over_noise"] = run["rms_3d_um"] / run["noise_3d_um"]
        run["rotation_over_noise"] = run["rms_rotation_urad"] / run["noise_rotation_urad"]
        run["reduction_rotation"] = 1.0 - run["rms_rotation_urad"] / drift["rms_rotation_urad"]


#: The columns every arm benchmark's table of controllers starts with (:func:`controller_row`).
CONTROLLER_COLUMNS = [
    "controller",
    "RMS 3-D um",
    "max 3-D um",
    "last 1/3 RMS um",
    "3-D removed",
    "RMS/noise",
    "RMS rot urad",
    "rot/noise",
    "rot removed",
]


def controller_row(name: str, run: dict[str, Any]) -> list[Any]:
    """A controller's figures in the order of CONTROLLER_COLUMNS."""
    return [
        name,
        run["rms_3d_um"],
        run["max_3d_um"],
        run["last_third_rms_3d_um"],
        "-" if name == "none" else f"{100 * run['reduction_3d']:.1f} %",
        run["rms_over_noise"],
        run["rms_rotation_urad"],
        run["rotation_over_noise"],
        "-" if name == "none" else f"{100 * run['reduction_rotation']:.1f} %",
    ]


def print_parameter_table(calibration: dict[str, Any]) -> None:
    """Every parameter of the calibration run's identification: value, standard error,
    identifiable, the refit value (or the preset's) and why not (this benchmark's and
    bench_arm_played's)."""
    refit = {p["name"]: p for p in calibration["refit"]["parameters"]}
    print_table(
        ["parameter", "all: value", "SE", "identifiable", "refit", "why not"],
        [
            [
                p["name"],
                p["value"],
                p["standard_error"] if math.isfinite(p["standard_error"]) else "inf",
                p["identifiable"],
                refit[p["name"]]["value"] if p["name"] in refit else "(preset)",
                p["reason"] or "-",
            ]
            for p in calibration["all"]["parameters"]
        ],
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--cameras", type=int, default=None, help="arm.cameras per pose")
    parser.add_argument("--no-identify", action="store_true", help="none and preset runs only")
    parser.add_argument("--frames", type=int, default=None, help="arm.frames_per_measurement")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    with tempfile.TemporaryDirectory(prefix="bench-arm-daemon-") as folder:
        result = asyncio.run(
            bench(
                args.seed,
                Path(folder),
                args.cameras,
                identify=not args.no_identify,
                frames=args.frames,
            )
        )
    load = os.getloadavg()
    result["load_average"] = list(load)
    runs = result["runs"]
    print(
        f"A465 'a465-pick-and-place' through the daemon, config/arm-sim.toml, seed {args.seed}, "
        f"{result['cameras']} camera(s) per pose, {result['frames']} frame(s) per measurement: "
        f"8 h of arm time, {result['steps']} steps"
    )
    print_table(
        [*CONTROLLER_COLUMNS, "predicted max um"],
        [[*controller_row(name, r), r["predicted_max_3d_um"]] for name, r in runs.items()],
    )
    print(
        f"\n3-D measurement noise (the meter's 1-sigma per position): "
        f"{runs['none']['noise_3d_um']:.2f} um; of the orientation "
        f"{runs['none']['noise_rotation_urad']:.1f} urad"
    )
    for name, r in runs.items():
        if "rms_along_sight_um" in r:
            print(
                f"{name}: RMS along the camera's line of sight {r['rms_along_sight_um']:.2f} um, "
                f"across it {r['rms_across_sight_um']:.2f} um"
            )
    calibration = result.get("calibration")
    if calibration is None:
        walls = result["wall_s"]
        print(
            "\nwall time: "
            + ", ".join(f"{name} {value:.1f} s" for name, value in walls.items())
            + f"; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
        )
        write_results("bench_arm_daemon", result)
        return 0
    print(
        f"\nidentification of the calibration run (noise seed {calibration['noise_seed']}, "
        f"drift {calibration['max_3d_um']:.1f} um max):"
    )
    print_parameter_table(calibration)
    walls = result["wall_s"]
    print(
        "\nwall time: "
        + ", ".join(f"{name} {value:.1f} s" for name, value in walls.items())
        + f"; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs"
    )
    write_results("bench_arm_daemon", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
