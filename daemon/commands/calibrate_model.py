"""``thermocomp calibrate model``: the whole path from a wrong model to a validated one, in one
command, each step of which stays a command of its own:

1. an uncompensated calibration run at ``--scale`` (``thermocomp run --compensation off``);
2. identification of the run's network from it, saved in the data directory as NAME
   (``thermocomp identify RUN --save NAME``): the file carries the identified heat and IR
   offsets;
3. a compensated validation run with that network, at the same scale, its reduction measured
   against the calibration run's drift (``thermocomp run --network NAME --reference-run RUN``).

Between the runs the links must cool back to ambient: on the simulated bench every run starts
cold; in a lab give ``--cool-down S``. Exit statuses: 0 all three steps done and both runs
finished; 1 a run did not finish or a device failed; 2 bad usage, a name already taken, or
identification impossible.

On an arm (``[arm] enabled``, or ``--duty-cycle``) the same chain runs the arm's steps
(daemon/commands/calibrate_arm_model.py): an uncompensated calibration run of the arm's
calibration program (generated for the task's stations; ``--calibration-cycle`` runs another
cycle), the arm's model identified from it and saved as arm model NAME, and a validation run
of the task with ``--arm-model NAME`` whose 3-D residual is compared with the measurement's
noise (and with the calibration run's drift only when it ran the task itself:
``--calibration-cycle TASK``); ``--network`` and ``--scale`` do not apply there.

On a UR (``robot.driver = "ur-rtde"``) the arm's chain runs on the robot's own program
(daemon/commands/calibrate_ur_model.py): an uncompensated followed run measured by the tool
cameras at the program's dwells (or ``--calibration-run RUN``, one already recorded), the
arm's identification from it with the joint temperatures as the thermal input, saved as arm
model NAME, and a compensated validation followed run with it. With no tool camera it is
refused in one line, exit status 2 (daemon/commands/followed_refusals.py).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from config import Settings, load_settings
from config.cli import (
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_USAGE,
    add_config_argument,
    non_negative_float,
    positive_float,
)
from daemon.commands.calibrate_arm_model import run_calibrate_arm_model
from daemon.commands.calibrate_chain import PROG, StepFailedError, run_alone
from daemon.commands.calibrate_ur_model import run_calibrate_ur_model
from daemon.commands.followed_refusals import model_refusal
from daemon.commands.run import _finite

#: Thesis 6.3: a scaled calibration run puts more of the deformation on the chip than the
#: robot's noise (bench_identify_runs uses 20).
DEFAULT_SCALE = 20.0


def add_parser(kinds: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = kinds.add_parser(
        "model",
        help="uncompensated run -> identify -> validation run, in one go",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_config_argument(parser)
    parser.add_argument(
        "--save", metavar="NAME", required=True, help="name of the network (of an arm: arm model)"
    )
    parser.add_argument(
        "--network", help="two-link: the network to identify from (default model.network)"
    )
    parser.add_argument(
        "--duty-cycle",
        metavar="NAME|PATH",
        help="an arm: the duty cycle both runs follow (default arm.duty_cycle; implies "
        "arm.enabled); the saved model is an arm model",
    )
    parser.add_argument("--duration", type=positive_float, metavar="S", help="each run's length")
    parser.add_argument("--step", type=positive_float, metavar="S", help="each run's step")
    parser.add_argument(
        "--scale",
        type=positive_float,
        help=f"two-link: deformation scale of both runs (thesis 6.3; default {DEFAULT_SCALE:g})",
    )
    parser.add_argument(
        "--prediction",
        choices=["model", "model+ir"],
        help="the validation run's prediction (default model.prediction)",
    )
    parser.add_argument(
        "--cool-down",
        type=non_negative_float,
        default=0.0,
        metavar="S",
        help="wait this long between the runs for the links to cool (a lab; default 0)",
    )
    parser.add_argument(
        "--params",
        nargs="+",
        metavar="PARAM",
        help="the parameters identification fits, as `thermocomp identify --params` (default: "
        "identify's)",
    )
    parser.add_argument(
        "--calibration-cycle",
        metavar="NAME|PATH",
        help="an arm: the calibration run's duty cycle (default: the arm's calibration "
        "program, generated for the task's stations; daemon/arm/calibration_program.py)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="an arm: save the model even with a value outside its physical range (flagged)",
    )
    parser.add_argument(
        "--calibration-run",
        type=int,
        metavar="RUN",
        help="a UR: identify this recorded uncompensated followed run instead of running one",
    )
    parser.add_argument("--no-validate", action="store_true", help="stop after identification")
    parser.add_argument("--data-dir", type=Path, help="folder of the run database")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run_calibrate_model)


def _settings(args: argparse.Namespace) -> Settings:
    settings = load_settings(args.config)
    data = settings.model_dump()
    overrides = {
        "storage": {"data_dir": args.data_dir},
        "scheduler": {"duration_s": args.duration, "step_s": args.step},
        "model": {"network": args.network, "prediction": args.prediction},
        "arm": {
            "duty_cycle": args.duty_cycle,
            "enabled": True if args.duty_cycle is not None else None,
        },
    }
    for section, values in overrides.items():
        data[section].update({k: v for k, v in values.items() if v is not None})
    return Settings.model_validate(data)


def run_calibrate_model(args: argparse.Namespace) -> int:
    # lazy: SciPy and the network load when the command runs, not for --help (issue 16)
    from daemon.calibration.identify_run import saved_network_path

    settings = _settings(args)
    refusal = model_refusal(settings, recorded=args.calibration_run is not None)
    if refusal is None and args.calibration_run is not None and settings.robot.driver != "ur-rtde":
        refusal = (
            "--calibration-run is a UR's (robot.driver ur-rtde); another robot's recorded run "
            "is identified with thermocomp identify RUN --save NAME"
        )
    if refusal is not None:  # one line, before anything opens
        print(f"{PROG}: {refusal}", file=sys.stderr)
        return EXIT_USAGE
    if settings.robot.driver == "ur-rtde":  # issue 31: the robot plays its own program
        return run_calibrate_ur_model(args, settings)
    if settings.arm.enabled:  # issue 20: the arm's chain
        return run_calibrate_arm_model(args, settings)
    if args.scale is None:
        args.scale = DEFAULT_SCALE
    try:
        saved = saved_network_path(args.save, settings.storage.data_dir)
    except ValueError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        outcome = asyncio.run(_chain(settings, args, saved))
    except StepFailedError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return err.status
    if args.json:
        print(json.dumps(_finite(outcome), indent=2, default=str, allow_nan=False))
    else:
        _print(outcome)
    return EXIT_OK


def _identify_and_save(
    settings: Settings,
    run_id: int,
    saved: Path,
    outcome: dict[str, Any],
    params: list[str] | None = None,
) -> None:
    # lazy: SciPy and the run database load when the command runs, not for --help (issue 16)
    from daemon.calibration.identify_run import RunInputError, load_run
    from daemon.model import NetworkError, load_network
    from daemon.model.identified_network import calibration_of, network_toml
    from daemon.model.identify import IdentificationError, identify

    try:
        run = load_run(str(run_id), settings, None)
        base = load_network(run.network or settings.model.network, settings.storage.data_dir)
        result = identify(run.data_for(base), base, run.regions, params)
    except (RunInputError, NetworkError, IdentificationError) as err:
        raise StepFailedError(f"identification: {err}", EXIT_USAGE) from err
    provenance = calibration_of(
        result, base.name, [run.name], datetime.now(UTC).isoformat(timespec="seconds")
    )
    network = dataclasses.replace(result.network, calibration=provenance)
    header = f"identified by {PROG} from run {run_id} and {base.name}"
    try:
        saved.parent.mkdir(parents=True, exist_ok=True)
        saved.write_text(network_toml(network, header=header), encoding="utf-8")
    except OSError as err:
        raise StepFailedError(f"cannot save {saved}: {err}", EXIT_FAILURE) from err
    outcome["identified"] = {
        "parameters": [dataclasses.asdict(p) for p in result.parameters],
        "heat_w": result.heat_w,
        "ir_offsets_c": result.offsets_c,
        "warnings": list(result.warnings),
    }


async def _chain(settings: Settings, args: argparse.Namespace, saved: Path) -> dict[str, Any]:
    outcome: dict[str, Any] = {"network": args.save, "network_file": str(saved)}
    calibration = await run_alone(
        settings, "calibration run", compensation="off", deformation_scale=args.scale
    )
    outcome["calibration_run"] = _run_view(calibration)
    # blocking (SciPy, SQLite read-only, one file): nothing else runs meanwhile
    _identify_and_save(settings, int(calibration["id"]), saved, outcome, args.params)
    if args.no_validate:
        return outcome
    if args.cool_down > 0:  # a lab's links cool in real time
        await asyncio.sleep(args.cool_down)
    validation = await run_alone(
        settings,
        "validation run",
        network=args.save,
        deformation_scale=args.scale,
        reference_run=int(calibration["id"]),
    )
    outcome["validation_run"] = _run_view(validation)
    return outcome


def _run_view(final: dict[str, Any]) -> dict[str, Any]:
    summary = final.get("summary") or {}
    keys = (
        "n",
        "residual_max_um",
        "residual_mean_um",
        "residual_std_um",
        "reduction_basis",
        "reduction_percent",
        "measured_drift_max_um",
        "reference_run",
        "reference_max_um",
    )
    return {"id": final["id"], "state": final["state"], **{k: summary.get(k) for k in keys}}


def _print(outcome: dict[str, Any]) -> None:
    calibration = outcome["calibration_run"]
    print(
        f"1. calibration run {calibration['id']} (compensation off): measured drift max "
        f"{_number(calibration['measured_drift_max_um'])} um"
    )
    identified = outcome["identified"]
    print(f"2. identified and saved as network {outcome['network']!r} ({outcome['network_file']}):")
    for p in identified["parameters"]:
        verdict = "" if p["identifiable"] else f"  NOT identifiable: {p['reason']}"
        print(f"     {p['name']:<14} {p['value']:>10.4g} +- {p['standard_error']:.3g}{verdict}")
    print("     heat: " + ", ".join(f"{n} = {w:.4g} W" for n, w in identified["heat_w"].items()))
    validation = outcome.get("validation_run")
    if validation is None:
        print("3. validation skipped (--no-validate)")
        return
    print(
        f"3. validation run {validation['id']} with {outcome['network']!r}: residual max "
        f"{_number(validation['residual_max_um'])} um, S_x {_number(validation['residual_std_um'])}"
        f" um, mean {_number(validation['residual_mean_um'])} um; "
        f"{_reduction(validation['reduction_percent'])} of the drift of run "
        f"{validation['reference_run']} ({validation['reduction_basis']})"
    )


def _reduction(value: object) -> str:
    """A reduction, or the increase it is when below zero (never a negative reduction)."""
    if isinstance(value, float) and value < 0:
        return f"not reduced: {-value:.3f} % larger than"
    return f"reduction {_number(value)} %"


def _number(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else "-" if value is None else str(value)
