"""``thermocomp calibrate model`` on a UR (``robot.driver = "ur-rtde"``, issue 31): the arm's
chain (daemon/commands/calibrate_arm_model.py) on a robot that plays its own program, each
step still a command of its own:

1. an UNCOMPENSATED followed run (``thermocomp run --compensation off``; daemon/run/followed/):
   the robot plays its program, the daemon follows it and writes a zero correction every step
   (the program's heartbeat), the tool cameras measure the tool at the program's dwells and
   every step records the joint temperatures. The program is the calibration: a UR's PC
   cannot make it play another (``--calibration-cycle`` is the A465's). ``--calibration-run
   RUN`` identifies an already-recorded uncompensated followed run instead;
2. the arm's identification from it (daemon/commands/followed_identify.py reads the run: the
   cameras' measurements as the tool errors, the joint temperatures as the thermal input; the
   fit, the identifiability flags of the final fit, the physical ranges, ``--force`` and the
   loud warning are the A465's, daemon/commands/arm_identify.py), saved as arm model NAME;
3. a compensated validation followed run with that model (``thermocomp run --arm-model NAME``:
   the identified factors, the joint sensors' identified offsets as the observer's start):
   its cameras' residual against its 1-sigma, and (the UR bench) the truth's removal; then its
   thermal displacement predicted by the identified model and the preset, nothing refitted.

Refused in one line before anything opens: no tool camera (daemon/commands/
followed_refusals.py), ``--network``/``--scale`` (the two-link bench's), ``--calibration-cycle``.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from config import Settings
from config.cli import EXIT_USAGE
from daemon.commands.calibrate_arm_model import (
    _identify_and_save,
    _prediction_check,
    run_arm_chain,
)
from daemon.commands.calibrate_chain import PROG, run_alone


def ur_usage_error(args: argparse.Namespace) -> str | None:
    """The one line refusing an option a UR's chain cannot use, or None."""
    for given, option, why in (
        (args.network, "--network", "the two-link bench's"),
        (args.scale, "--scale", "the two-link bench's (thesis 6.3)"),
        (
            getattr(args, "calibration_cycle", None),
            "--calibration-cycle",
            "the A465's: a UR plays its own program, which is the calibration run",
        ),
    ):
        if given is not None:
            return f"{option} is {why}; a UR is identified from a followed run of its program"
    return None


def run_calibrate_ur_model(args: argparse.Namespace, settings: Settings) -> int:
    """The UR chain (module docstring); the exit statuses of the arm's."""
    refusal = ur_usage_error(args)
    if refusal is None and settings.arm.duty_cycle is None:
        refusal = "a UR is calibrated on the program it plays: set arm.duty_cycle"
    if refusal is not None:
        print(f"{PROG}: {refusal}", file=sys.stderr)
        return EXIT_USAGE
    return run_arm_chain(args, settings, _chain, _print)


async def _chain(
    settings: Settings, args: argparse.Namespace, saved: Path
) -> tuple[dict[str, Any], str]:
    outcome: dict[str, Any] = {"arm_model": args.save, "arm_model_file": str(saved)}
    recorded = getattr(args, "calibration_run", None)
    if recorded is None:
        calibration = await run_alone(settings, "calibration run", compensation="off")
        outcome["calibration_run"] = _run_view(calibration)
        calibration_id = int(calibration["id"])
    else:
        calibration_id = int(recorded)
        outcome["calibration_run"] = {"id": calibration_id, "recorded": True}
    # blocking: nothing else runs meanwhile (no daemon is open)
    table, run, refit = _identify_and_save(
        settings,
        calibration_id,
        args.save,
        saved,
        outcome,
        params=args.params,
        force=bool(getattr(args, "force", False)),
    )
    if args.no_validate:
        return outcome, table
    if args.cool_down > 0:  # a lab's arm cools in real time
        await asyncio.sleep(args.cool_down)
    validation = await run_alone(
        settings, "validation run", compensation="absolute", arm_model=args.save
    )
    outcome["validation_run"] = _run_view(validation)
    outcome["prediction"] = _prediction_check(settings, run, refit, int(validation["id"]))
    return outcome, table


def _run_view(final: dict[str, Any]) -> dict[str, Any]:
    """A followed run's figures for the chain's report: the cameras' (residual RMS over their
    mean 1-sigma) and, on the UR bench, the truth's removal."""
    summary = final.get("summary") or {}
    measured = summary.get("measured") or {}
    truth = summary.get("bench_truth") or {}
    rms, sigma = measured.get("rms_residual_um"), measured.get("mean_sigma_um")
    return {
        "id": final["id"],
        "state": final["state"],
        "measurements": measured.get("measurements"),
        "rms_residual_um": rms,
        "rms_uncompensated_um": measured.get("rms_uncompensated_um"),
        "mean_sigma_um": sigma,
        "rms_over_noise": rms / sigma if rms is not None and sigma else None,
        "truth_removed_fraction": truth.get("removed_fraction"),
    }


def _print(outcome: dict[str, Any], table: str) -> None:
    calibration = outcome["calibration_run"]
    if calibration.get("recorded"):
        print(f"1. calibration run {calibration['id']}: recorded (--calibration-run)")
    else:
        print(
            f"1. calibration run {calibration['id']} (the program, compensation off): "
            f"{_number(calibration['measurements'])} camera measurements, 3-D drift RMS "
            f"{_number(calibration['rms_residual_um'])} um"
        )
    print(f"2. identified and saved as arm model {outcome['arm_model']!r} "
          f"({outcome['arm_model_file']}):")  # fmt: skip
    print("\n".join(f"     {line}" for line in table.splitlines()))
    validation = outcome.get("validation_run")
    if validation is None:
        print("3. validation skipped (--no-validate)")
        return
    print(
        f"3. validation run {validation['id']} with --arm-model {outcome['arm_model']}: "
        f"{_number(validation['measurements'])} camera measurements, 3-D residual RMS "
        f"{_number(validation['rms_residual_um'])} um = {_number(validation['rms_over_noise'])}"
        f" x their mean 1-sigma ({_number(validation['mean_sigma_um'])} um)"
    )
    removed = validation["truth_removed_fraction"]
    if removed is not None:
        print(f"   the UR bench's truth: {100.0 * removed:.1f} % of the drift removed (RMS)")
    prediction = outcome["prediction"]
    identified, preset = prediction["identified"], prediction["preset"]
    print(
        f"   its thermal displacement predicted, nothing refitted: identified model RMS "
        f"{_um(identified['marker_rms_mm'])} um, preset {_um(preset['marker_rms_mm'])} um"
    )


def _um(value_mm: object) -> str:
    return _number(1000.0 * value_mm) if isinstance(value_mm, float) else "-"


def _number(value: object) -> str:
    return f"{value:.3g}" if isinstance(value, float) else "-" if value is None else str(value)
