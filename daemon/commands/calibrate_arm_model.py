"""``thermocomp calibrate model`` on an arm (``[arm] enabled``, issue 20): the two-link chain
(daemon/commands/calibrate_model.py) with the arm's steps, each still a command of its own:

1. an uncompensated calibration run of the arm's CALIBRATION PROGRAM (issue 29,
   daemon/arm/calibration_program.py: each joint worked in turn, a gravity hold, a rest,
   measured at the task's camera stations), generated from the arm and the task's duty cycle
   into ``<data_dir>/calibration-programs/``; ``--calibration-cycle NAME|PATH`` runs another
   cycle instead (the task's own: ``--calibration-cycle TASK``);
2. the arm's identification from it, saved in the data directory as arm model NAME
   (``thermocomp identify RUN --save NAME``; daemon/commands/arm_identify.py): each joint's heat,
   convection, alpha and the IR offsets, the identifiable ones refitted;
3. a compensated validation run of the task's duty cycle with that model (``thermocomp run
   --arm-model NAME``, with ``--reference-run RUN`` when the calibration ran the task itself):
   its 3-D residual, the reduction against the calibration run's drift (only then: same arm,
   same duty cycle, uncompensated), and the residual RMS over the 3-D
   measurement's own 1-sigma; then, as ``identify --validate`` does, the validation run's
   thermal displacement (its measured drift minus the correction commanded) predicted by the
   identified model and by the preset, nothing refitted.

Each run has a daemon of its own, opened and closed around it: identification computes with no
device open, so a virtual clock cannot jump meanwhile (the two-link chain's rule). There is no
deformation scale here (``--scale`` is the two-link bench's, thesis 6.3) and no network
(``--network``): the arm's model is its arm file's.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import TYPE_CHECKING, Any

from config import Settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.commands.calibrate_chain import PROG, StepFailedError, run_alone
from daemon.commands.run import _finite

#: Where ``calibrate model`` writes the calibration programs it generates (data directory).
CALIBRATION_PROGRAMS_FOLDER = "calibration-programs"

if TYPE_CHECKING:
    from daemon.arm.identify import ArmIdentification
    from daemon.commands.arm_run import ArmRun


def run_calibrate_arm_model(args: argparse.Namespace, settings: Settings) -> int:
    """The arm chain (module docstring); the exit statuses of the two-link one."""
    for given, option in ((args.network, "--network"), (args.scale, "--scale")):
        if given is not None:
            print(
                f"{PROG}: {option} is for the two-link bench; an arm is identified against its "
                "own arm file and duty cycle, at scale 1",
                file=sys.stderr,
            )
            return EXIT_USAGE
    if settings.arm.duty_cycle is None:
        print(
            f"{PROG}: an arm is calibrated on a duty cycle: give --duty-cycle NAME|PATH or set "
            "arm.duty_cycle",
            file=sys.stderr,
        )
        return EXIT_USAGE
    return run_arm_chain(args, settings, _chain, _print)


def run_arm_chain(
    args: argparse.Namespace,
    settings: Settings,
    chain: Callable[
        [Settings, argparse.Namespace, Path], Coroutine[Any, Any, tuple[dict[str, Any], str]]
    ],
    report: Callable[[dict[str, Any], str], None],
) -> int:
    """An arm's chain run after its refusals (the A465's, a UR's: calibrate_ur_model.py): the
    arm model's file named (a bad NAME: usage), ``chain`` run to its outcome (a step failed:
    its status, one line), the outcome printed as JSON (``--json``) or by ``report``."""
    # lazy: NumPy and SciPy load when the command runs, not for --help (issue 16)
    from daemon.arm.arm_model import new_arm_model_path

    try:
        saved = new_arm_model_path(args.save, settings.storage.data_dir)
    except ValueError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        outcome, table = asyncio.run(chain(settings, args, saved))
    except StepFailedError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return err.status
    if args.json:
        print(json.dumps(_finite(outcome), indent=2, default=str, allow_nan=False))
    else:
        report(outcome, table)
    return EXIT_OK


def _identify_and_save(
    settings: Settings,
    run_id: int,
    name: str,
    saved: Path,
    outcome: dict[str, Any],
    *,
    params: list[str] | None,
    force: bool = False,
) -> tuple[str, ArmRun, ArmIdentification]:
    """Step 2, blocking (SciPy, SQLite read-only, one file): the identification table, the
    run as identification read it, and the refit the saved model holds."""
    # lazy: SciPy and the run database load when the command runs, not for --help (issue 16)
    from daemon.arm.arm_model import arm_model_toml
    from daemon.calibration.identify_run import write_outputs
    from daemon.commands.arm_identify import (
        ImplausibleModelError,
        arm_model_of,
        checked_for_save,
        identify_arm_run,
        load_arm_run,
    )
    from daemon.commands.arm_identify_cli import format_arm_result, progress_to_stderr
    from daemon.commands.arm_run import ArmRunInputError
    from daemon.model.identify import IdentificationError

    try:
        run = load_arm_run(settings.storage.data_dir, run_id)
    except (ArmRunInputError, OSError) as err:
        raise StepFailedError(f"identification: {err}", EXIT_FAILURE) from err
    try:
        calibration = identify_arm_run(run, params, progress_to_stderr(f"{PROG}: identification"))
    except IdentificationError as err:
        raise StepFailedError(f"identification: {err}", EXIT_USAGE) from err
    table = format_arm_result(calibration)
    try:
        model = checked_for_save(arm_model_of(name, run, calibration), force)
    except ImplausibleModelError as err:
        print(table)
        raise StepFailedError(f"identification: {err}", EXIT_FAILURE) from err
    header = f"identified by {PROG} from run {run_id} (arm {model.arm})"
    try:
        write_outputs([saved], arm_model_toml(model, header=header))
    except OSError as err:
        raise StepFailedError(f"cannot save {saved}: {err}", EXIT_FAILURE) from err
    assert calibration.final is not None
    outcome["identified"] = {
        "all": None if calibration.full is None else calibration.full.to_dict(),
        "refit": calibration.final.to_dict(),
        "arm_model": model.provenance(),
    }
    for line in model.implausible:
        if line:
            table += f"\nWARNING: {line}"
    return table, run, calibration.final


def calibration_cycle(settings: Settings, chosen: str | None) -> str:
    """The calibration run's duty cycle: ``chosen`` (a name or path), else the arm's
    calibration program generated for the task (module docstring), written into the data
    directory (StepFailedError when the arm or the task cannot be read)."""
    if chosen:
        return chosen
    # lazy: the arm's kinematics and run set-up (NumPy, SciPy) load to calibrate, not for --help
    from daemon.arm.calibration_program import duty_cycle_toml, program_for_task
    from daemon.arm.duty import arm_inverse, load_duty_cycle
    from daemon.arm.loading import load_arm
    from daemon.run.arm.setup import arm_file

    assert settings.arm.duty_cycle is not None
    try:
        arm = load_arm(arm_file(settings))
        task = load_duty_cycle(settings.arm.duty_cycle, arm_inverse(arm))
        name = f"{task.name}-calibration"
        program = program_for_task(arm, task, settings.arm.arm_file, name)
        folder = Path(settings.storage.data_dir) / CALIBRATION_PROGRAMS_FOLDER
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{name}.toml"
        header = f"Generated by {PROG} for {arm.name} and {task.name} (issue 29)."
        path.write_text(duty_cycle_toml(program, settings.arm.arm_file, header), "utf-8")
    except (OSError, ValueError) as err:
        raise StepFailedError(f"calibration program: {err}", EXIT_FAILURE) from err
    return str(path)


def _prediction_check(
    settings: Settings, run: ArmRun, refit: ArmIdentification, validation: int
) -> dict[str, Any]:
    """Step 3's offline part: the validation run predicted by the identified model and by the
    preset, nothing refitted (blocking)."""
    # lazy: SciPy and the run database load when the command runs, not for --help (issue 16)
    from daemon.commands.arm_identify import load_arm_run, validate_arm_run
    from daemon.commands.arm_run import ArmRunInputError
    from daemon.model.identify import IdentificationError

    try:
        other = load_arm_run(settings.storage.data_dir, validation)
        return validate_arm_run(run, refit, other).to_dict()
    except (ArmRunInputError, IdentificationError, OSError) as err:
        raise StepFailedError(f"validation: {err}", EXIT_FAILURE) from err


async def _chain(
    settings: Settings, args: argparse.Namespace, saved: Path
) -> tuple[dict[str, Any], str]:
    outcome: dict[str, Any] = {"arm_model": args.save, "arm_model_file": str(saved)}
    program = calibration_cycle(settings, getattr(args, "calibration_cycle", None))
    outcome["calibration_cycle"] = program
    same_cycle = program == settings.arm.duty_cycle
    program_settings = settings.model_copy(
        update={
            "arm": settings.arm.model_copy(
                update={"duty_cycle": program, "measured_poses": settings.arm.measured_poses}
                if same_cycle
                else {"duty_cycle": program, "measured_poses": ()}
            )
        }
    )
    calibration = await run_alone(program_settings, "calibration run", compensation="off")
    outcome["calibration_run"] = _run_view(calibration)
    calibration_id = int(calibration["id"])
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
        settings,
        "validation run",
        compensation="absolute",
        arm_model=args.save,
        reference_run=calibration_id if same_cycle else None,
    )
    view = _run_view(validation)
    drift_rms = outcome["calibration_run"]["drift_3d_rms_um"] if same_cycle else None
    residual_rms = view["drift_3d_rms_um"]
    view["reduction_3d_rms_percent"] = (
        100.0 * (1.0 - residual_rms / drift_rms) if residual_rms is not None and drift_rms else None
    )
    outcome["validation_run"] = view
    outcome["prediction"] = _prediction_check(settings, run, refit, int(validation["id"]))
    return outcome, table


_SUMMARY_KEYS = (
    "arm_n",
    "duty_cycle",
    "drift_3d_max_um",
    "drift_3d_rms_um",
    "rotation_error_max_urad",
    "rotation_error_rms_urad",
    "measurement_sigma_um",
    "reduction_basis",
    "reference_run",
    "reference_drift_3d_max_um",
    "reduction_3d_percent",
    "reduction_rotation_percent",
)


def _run_view(final: dict[str, Any]) -> dict[str, Any]:
    """A run's figures for the chain's report: the arm summary's, and the 3-D RMS over the
    measurement's own 1-sigma."""
    summary = final.get("summary") or {}
    view = {
        "id": final["id"],
        "state": final["state"],
        **{k: summary.get(k) for k in _SUMMARY_KEYS},
    }
    rms, sigma = view["drift_3d_rms_um"], view["measurement_sigma_um"]
    view["rms_over_noise"] = rms / sigma if rms is not None and sigma else None
    return view


def _print(outcome: dict[str, Any], table: str) -> None:
    calibration = outcome["calibration_run"]
    print(
        f"1. calibration run {calibration['id']} ({calibration['duty_cycle']}, compensation "
        f"off): 3-D drift max {_number(calibration['drift_3d_max_um'])} um, RMS "
        f"{_number(calibration['drift_3d_rms_um'])} um"
    )
    print(f"2. identified and saved as arm model {outcome['arm_model']!r} "
          f"({outcome['arm_model_file']}):")  # fmt: skip
    print("\n".join(f"     {line}" for line in table.splitlines()))
    validation = outcome.get("validation_run")
    if validation is None:
        print("3. validation skipped (--no-validate)")
        return
    print(
        f"3. validation run {validation['id']} with --arm-model {outcome['arm_model']}: 3-D "
        f"residual max {_number(validation['drift_3d_max_um'])} um, RMS "
        f"{_number(validation['drift_3d_rms_um'])} um = "
        f"{_number(validation['rms_over_noise'])} x the 3-D measurement's 1-sigma "
        f"({_number(validation['measurement_sigma_um'])} um); rotation error RMS "
        f"{_number(validation['rotation_error_rms_urad'])} urad"
    )
    print(f"   {_reduction(validation, outcome['arm_model'])}")
    prediction = outcome["prediction"]
    identified, preset = prediction["identified"], prediction["preset"]
    print(
        f"   its thermal displacement predicted, nothing refitted: identified model RMS "
        f"{_um(identified['marker_rms_mm'])} um, preset {_um(preset['marker_rms_mm'])} um"
    )


def _reduction(validation: dict[str, Any], arm_model: str) -> str:
    """The validation run's reduction, or why there is none: a calibration program is not the
    task, so its drift is no reference for the task's run (the module docstring, step 3)."""
    reference = validation["reference_run"]
    if reference is None:
        return (
            "no reduction measured: the calibration run played the calibration program, not "
            "the task's duty cycle; measure one against an uncompensated run RUN of the task: "
            f"thermocomp run --arm-model {arm_model} --reference-run RUN"
        )
    return (
        f"reduction of the drift of run {reference}: "
        f"{_number(validation['reduction_3d_percent'])} % (largest), "
        f"{_number(validation['reduction_3d_rms_percent'])} % (RMS)"
    )


def _um(value_mm: object) -> str:
    return _number(1000.0 * value_mm) if isinstance(value_mm, float) else "-"


def _number(value: object) -> str:
    return f"{value:.3g}" if isinstance(value, float) else "-" if value is None else str(value)
