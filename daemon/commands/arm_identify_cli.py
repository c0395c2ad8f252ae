"""``thermocomp identify RUN_ID`` of an arm run: the command and what it prints (the
identification itself, loading a run, validating and saving a model, is
daemon/commands/arm_identify.py, which calibrate_arm_model.py shares)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace

from config import Settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.arm.arm_model import arm_model_toml, new_arm_model_path
from daemon.arm.identify import (
    ArmFitQuality,
    Progress,
)
from daemon.arm.identify_final import ArmCalibration
from daemon.calibration.identify_run import (
    finite_json,
    write_outputs,
)
from daemon.commands.arm_identify import (
    ArmValidation,
    ImplausibleModelError,
    arm_model_of,
    checked_for_save,
    identify_arm_run,
    implausible_values,
    load_arm_run,
    not_identified_warning,
    validate_arm_run,
    validated_model,
)
from daemon.commands.arm_run import ArmRunInputError
from daemon.model.identify import IdentificationError

#: At most one progress line per this many seconds (the fit's iterations take milliseconds).
PROGRESS_EVERY_S = 2.0


def progress_to_stderr(prefix: str, every_s: float = PROGRESS_EVERY_S) -> Progress:
    """A progress sink printing a line on stderr at most every ``every_s`` (and each refit's
    announcement): the fit takes seconds to tens of them."""
    last = [-math.inf]

    def show(line: str) -> None:
        now = time.monotonic()
        if now - last[0] >= every_s or line.startswith("refit"):
            last[0] = now
            print(f"{prefix}: {line}", file=sys.stderr, flush=True)

    return show


def format_validation(validation: ArmValidation) -> str:
    def rms(quality: ArmFitQuality) -> str:
        marker = "n/a" if quality.marker_rms_mm is None else f"{1000 * quality.marker_rms_mm:.3g}"
        temperature = (
            "n/a" if quality.temperature_rms_c is None else f"{quality.temperature_rms_c:.3g}"
        )
        return f"tool translation RMS {marker} um, IR RMS {temperature} degC"

    identified, preset = validation.identified, validation.preset
    return (
        f"validation on {validation.run} ({validation.duty_cycle}; "
        f"{identified.marker_samples} translation values, {identified.temperature_samples} IR "
        f"values), nothing refitted: identified {rms(identified)}; preset {rms(preset)}"
    )


def format_arm_result(calibration: ArmCalibration) -> str:
    full, final = calibration.full, calibration.final
    assert full is not None and final is not None
    firsts = {p.name: p for p in full.parameters}
    lines = [
        f"{'parameter':<22} {'first fit':>10} {'value':>10} {'std error':>10} {'rel.':>8}  "
        "identifiable (final fit)"
    ]
    for p in calibration.parameters():
        first = f"{firsts[p.name].value:>10.4g}" if p.name in firsts else f"{'-':>10}"
        if p.identifiable:
            value = f"{p.value:>10.4g} {p.standard_error:>10.3g} {_percent(p.relative_error):>8}"
            verdict = "yes"
        else:
            value = f"{'(preset)':>10} {'':>10} {'':>8}"
            verdict = f"NO: {p.reason}"
        lines.append(f"{p.name:<22} {first} {value}  {verdict}")
    fit = final.fit
    marker = "n/a" if fit.marker_rms_mm is None else f"{1000 * fit.marker_rms_mm:.3g}"
    temperature = "n/a" if fit.temperature_rms_c is None else f"{fit.temperature_rms_c:.3g}"
    lines.append(
        f"fit: tool translation RMS {marker} um ({fit.marker_samples} values), IR RMS "
        f"{temperature} degC ({fit.temperature_samples} values); conditioning "
        f"{final.conditioning:.3g} (first fit {full.conditioning:.3g})"
    )
    if not final.success:
        lines.append(f"WARNING: the final fit did not converge: {final.message}")
    if calibration.not_identified:
        lines.append(f"WARNING: {not_identified_warning(calibration)} (the saved model says so)")
    return "\n".join(lines)


def _percent(relative: float | None) -> str:
    """A relative standard error as a percentage; past 1000 % (nothing seen) only that."""
    if relative is None:
        return ""
    return f"{100 * relative:7.2f}%" if relative <= 10.0 else "  >1000%"


def run_arm_identify(args: argparse.Namespace, settings: Settings) -> int:
    """``thermocomp identify RUN_ID`` of an arm run (daemon/commands/identify.py delegates)."""
    data_dir = settings.storage.data_dir
    if args.network or args.heater_off is not None:
        print(
            "thermocomp identify: --network and --heater-off are for two-link runs; an arm "
            "run is identified against its own arm and duty cycle",
            file=sys.stderr,
        )
        return EXIT_USAGE
    if args.validate is not None and not args.validate.isdigit():
        print(
            f"thermocomp identify: --validate {args.validate!r}: an arm model is validated on "
            "a recorded arm run, by its number",
            file=sys.stderr,
        )
        return EXIT_USAGE
    try:
        saved = None if args.save is None else new_arm_model_path(args.save, data_dir)
        run = load_arm_run(data_dir, int(args.target))
        other = None if args.validate is None else load_arm_run(data_dir, int(args.validate))
    except ValueError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_USAGE
    except (ArmRunInputError, OSError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        calibration = identify_arm_run(run, args.params, progress_to_stderr("thermocomp identify"))
        assert calibration.final is not None
        validation = None if other is None else validate_arm_run(run, calibration.final, other)
    except IdentificationError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_USAGE
    except ArmRunInputError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    model = validated_model(
        arm_model_of(args.save or f"run-{args.target}", run, calibration), validation
    )
    try:
        model = checked_for_save(model, bool(args.force))
    except ImplausibleModelError as err:
        if saved is not None or args.out is not None:
            print(format_arm_result(calibration))
            print(f"thermocomp identify: {err}", file=sys.stderr)
            return EXIT_FAILURE
        model = replace(model, implausible=tuple(implausible_values(model)))
    header = f"identified by thermocomp identify {args.target} (arm {model.arm})"
    written = [path for path in (args.out, saved) if path is not None]
    try:
        write_outputs(written, arm_model_toml(model, header=header))
    except OSError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        document = {
            "run": run.name,
            "arm": model.arm,
            "duty_cycle": run.duty_cycle,
            "all": None if calibration.full is None else calibration.full.to_dict(),
            "refit": calibration.final.to_dict(),
            "not_identified": {  # the reason of one fitted in combination is the final fit's
                p.name: p.reason for p in calibration.parameters() if p.name in model.not_identified
            },
            "arm_model": model.provenance(),
            "validation": None if validation is None else validation.to_dict(),
            "saved_arm_model": args.save,
            "arm_model_file": None if args.out is None else str(args.out),
        }
        print(json.dumps(finite_json(document), indent=2, allow_nan=False))
    else:
        print(format_arm_result(calibration))
        for line in model.implausible:
            if line:
                print(f"WARNING: {line}")
        if validation is not None:
            print(format_validation(validation))
        if saved is not None:
            print(
                f"saved as arm model {args.save!r} ({saved}): `thermocomp run --arm-model "
                f'{args.save}`, or "arm_model": "{args.save}" in POST /runs'
            )
    return EXIT_OK
