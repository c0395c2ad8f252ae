"""``thermocomp run``: one run to its end without the API, then its summary (thesis Table 6.1).

For scripts and tests. SIGINT/SIGTERM stop the run cleanly (robot held, recording committed);
a device fault ends the run (there is nobody to ask for a resume) with exit status 1.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from config import Settings, load_settings
from config.cli import (
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_STORAGE,
    EXIT_USAGE,
    add_config_argument,
    positive_float,
)
from daemon.heap import freeze_startup_heap, lock_memory, log_memory_lock
from daemon.run.states import RunParameters, RunState, RunStateError

if TYPE_CHECKING:  # the daemon (SciPy, Matplotlib, OpenCV) loads when a run starts, not
    # for `thermocomp run --help`
    from daemon.service import Daemon

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run one compensation run to its end and print its summary",
        description="Run one run on the configured devices (the simulated bench with "
        "config/sim.toml) without the API, record every step, and print the summary of "
        "thesis Table 6.1. Options override the [scheduler] and [compensation] settings.",
    )
    add_config_argument(parser)
    parser.add_argument(
        "--procedure",
        choices=["stationary", "moving", "repeatability"],
        help="what the robot does (thesis 6.2 stationary, 3.2.4 moving, 2.2.2 repeatability)",
    )
    parser.add_argument(
        "--compensation",
        choices=["off", "absolute", "incremental"],
        help="absolute: goal + offset (thesis 6.4.4); incremental: the thesis's comparison",
    )
    parser.add_argument("--duration", type=positive_float, metavar="S", help="run length (s)")
    parser.add_argument(
        "--step", type=positive_float, metavar="S", help="step period (s), 0.01 to 600"
    )
    parser.add_argument("--scale", type=positive_float, help="deformation scale (thesis 6.3)")
    parser.add_argument("--time-scale", type=positive_float, help="model s per run s (thesis 6.3)")
    parser.add_argument(
        "--network",
        help="network: a preset name, an identified network saved in the data directory "
        "(identify --save NAME), or a TOML file",
    )
    parser.add_argument(
        "--prediction",
        choices=["model", "model+ir"],
        help="model: open loop (thesis); model+ir: corrected each step from the IR regions",
    )
    parser.add_argument(
        "--heat",
        type=_heat,
        nargs="+",
        action="extend",
        metavar="NODE=WATTS",
        help="heat input per model node NAME while the heaters are on, overriding the "
        "network's own heat and model.heat_w (several after one --heat, or --heat repeated); "
        "a name the network lacks is refused",
    )
    parser.add_argument(
        "--reference-run",
        type=int,
        metavar="RUN",
        help="an uncompensated run (--compensation off) of the same bench and scale: the "
        "summary's reduction is then measured against its drift (else it is only stated "
        "against the model's prediction)",
    )
    parser.add_argument(
        "--duty-cycle",
        metavar="NAME|PATH",
        help="an arm run: the duty cycle (preset in config/duty or TOML file) to "
        "follow, its measured poses corrected in 6-DOF; sets arm.duty_cycle and arm.enabled",
    )
    parser.add_argument(
        "--arm-model",
        metavar="NAME",
        help="an arm run: the identified arm model saved in the data directory by "
        "`thermocomp identify RUN --save NAME` (default: the preset arm's model)",
    )
    parser.add_argument(
        "--data-dir", type=Path, help="folder of the run database (default: storage.data_dir)"
    )
    parser.add_argument("--csv", type=Path, help="also export the run's steps to this CSV file")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run_command)


def _heat(text: str) -> tuple[str, float]:
    node, equals, watts = text.partition("=")
    try:
        value = float(watts)
    except ValueError:
        value = math.nan
    if not equals or not node.strip() or not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected NODE=WATTS (watts >= 0), got {text!r}")
    return node.strip(), value


def _heat_map(pairs: list[tuple[str, float]]) -> dict[str, float]:
    heat: dict[str, float] = {}
    for node, watts in pairs:
        heat[node] = heat.get(node, 0.0) + watts
    return heat


def run_command(args: argparse.Namespace) -> int:
    try:
        settings = _settings(args)
        parameters = RunParameters.from_settings(
            settings,
            reference_run=args.reference_run,
            arm_model=args.arm_model,
            heat_w=_heat_map(args.heat) if args.heat else None,
        )
    except ValidationError as err:
        print(f"thermocomp run: invalid run parameters: {_describe(err)}", file=sys.stderr)
        return EXIT_USAGE
    from daemon.run.inputs import check_inputs  # lazy: the model stack, loaded to run
    from daemon.storage.recorder import RecorderError  # lazy: NumPy, loaded to run, not for --help

    # every file the run names loads before a device opens: a mistake is one line, exit 2
    # (raised as an InputError; api/cli.py prints it)
    check_inputs(settings, arm_model=args.arm_model)
    try:
        return asyncio.run(_run(settings, parameters, args))
    except RecorderError as err:  # e.g. the data directory is another process's: one line
        print(f"thermocomp run: {err}", file=sys.stderr)
        return EXIT_STORAGE


def _settings(args: argparse.Namespace) -> Settings:
    """The file's settings with the command line's options written into their sections, so
    that the simulated bench (which reads e.g. the deformation scale and the procedure from
    the settings) and the run agree."""
    settings = load_settings(args.config)
    overrides = {
        "scheduler": {
            "procedure": args.procedure,
            "duration_s": args.duration,
            "step_s": args.step,
        },
        "compensation": {
            "mode": args.compensation,
            "deformation_scale": args.scale,
            "time_scale": args.time_scale,
        },
        "model": {
            "network": args.network,
            "prediction": args.prediction,
        },
        "storage": {"data_dir": args.data_dir},
        "arm": {
            "duty_cycle": args.duty_cycle,
            "enabled": True if args.duty_cycle is not None else None,
        },
    }
    data = settings.model_dump()
    for section, values in overrides.items():
        data[section].update({k: v for k, v in values.items() if v is not None})
    return Settings.model_validate(data)


async def _run(settings: Settings, parameters: RunParameters, args: argparse.Namespace) -> int:
    # lazy: the daemon (SciPy, Matplotlib, OpenCV) loads when a run starts, not for --help
    from daemon.service import Daemon, RunParameterError

    loop = asyncio.get_running_loop()
    stop_requested = asyncio.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop_requested.set)
    try:
        async with Daemon(settings) as daemon:
            freeze_startup_heap()  # as `thermocomp serve`: no full collection in a step
            daemon.gc_policy.watch.reset()
            if settings.scheduler.lock_memory:
                log_memory_lock(lock_memory())
            try:
                info = await daemon.start_run(parameters)
            except RunParameterError as err:
                print(f"thermocomp run: {err}", file=sys.stderr)
                return EXIT_USAGE
            run_id = info["id"]
            if not args.json:
                print(f"run {run_id} started; recording to {daemon.recorder_path}", flush=True)
            final = await _supervise(daemon, stop_requested)
            if args.csv is not None:
                assert daemon.recorder is not None
                await asyncio.to_thread(daemon.recorder.export_csv, run_id, args.csv)
    finally:
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(signum)
    _print_result(final, args.json)
    return EXIT_OK if final["state"] == RunState.FINISHED.value else EXIT_FAILURE


async def _supervise(daemon: Daemon, stop_requested: asyncio.Event) -> dict[str, Any]:
    """Wait for the run to end; stop it on a signal or when it parks in fault/paused (nobody
    is there to resume it)."""
    stopper = asyncio.ensure_future(stop_requested.wait())
    waiter = asyncio.ensure_future(
        daemon.wait_state(RunState.FAULT, RunState.PAUSED, RunState.FINISHED)
    )
    try:
        done, _ = await asyncio.wait({waiter, stopper}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in (stopper, waiter):
            task.cancel()
        await asyncio.gather(stopper, waiter, return_exceptions=True)
    if stopper in done:
        return await _stop(daemon, "stopped by a signal", RunState.STOPPED)
    run = daemon.run
    assert run is not None
    if run.state in (RunState.FAULT, RunState.PAUSED):
        reason = run.reason or run.state.value
        return await _stop(daemon, f"{run.state.value}: {reason}", RunState.ABORTED)
    final = await daemon.wait_run()
    if daemon.settings.storage.report_at_end:  # a run that ran to its end: with its report
        written = await daemon.reports.wait(final["id"])
        from daemon.storage.report_queue import ReportStatus  # lazy: as RecorderError above

        if written is ReportStatus.WRITTEN:
            final["report"] = str(daemon.reports.html_path(final["id"]))
    return final


async def _stop(daemon: Daemon, reason: str, final: RunState) -> dict[str, Any]:
    try:
        return await daemon.stop(reason=reason, final=final)
    except RunStateError:  # it ended meanwhile
        return await daemon.wait_run()


def _print_result(final: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(final, indent=2, default=str, allow_nan=False, cls=_FiniteEncoder))
        return
    summary = final.get("summary") or {}
    print(
        f"run {final['id']} {final['state']}" + (f": {final['reason']}" if final["reason"] else "")
    )
    # lazy: every run kind's package, only once a run has ended (not for --help)
    from daemon.run.kinds import summary_rows

    rows = summary_rows(summary)
    for label, value, unit in rows:
        text = f"{_format(value)} {unit}"
        if unit == "%" and isinstance(value, float) and value < 0:
            # a reduction below zero is an increase (a short run's residual above the
            # prediction): said so, never printed as a negative reduction
            text = f"not reduced: {-value:.3f} % larger"
        print(f"  {label:<28} {text}".rstrip())
    missing = (summary.get("reference") or {}).get("missing") or {}
    for pose, why in missing.items():  # an arm run: a pose's zero is its first step
        print(f"  {'NO REFERENCE at ' + pose:<28} its first step is its zero ({why})")
    lateness = (summary.get("timing") or {}).get("lateness_s") or {}
    if lateness:
        values = "/".join(_format(1e3 * v) for v in lateness.values() if isinstance(v, float))
        print(f"  {'lateness p50/p99/max':<28} {values} ms")
    if final.get("report"):
        print(f"  {'report':<28} {final['report']}")


def _format(value: object) -> str:
    if isinstance(value, float):
        return "-" if math.isnan(value) else f"{value:.3f}"
    return "-" if value is None else str(value)


class _FiniteEncoder(json.JSONEncoder):
    """JSON without NaN/inf (not JSON): they become null."""

    def iterencode(self, o: Any, _one_shot: bool = False) -> Any:
        return super().iterencode(_finite(o), _one_shot)


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _describe(error: ValidationError) -> str:
    return "; ".join(
        f"{'.'.join(str(p) for p in item['loc']) or 'parameters'}: "
        + str(item["msg"]).removeprefix("Value error, ")
        for item in error.errors()
    )
