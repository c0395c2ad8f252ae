"""``thermocomp devices check``: open every configured device, grab one frame, one IR image and
the robot's pose, print what came back and write the preview (issue 18;
daemon/run/devices_check.py).

Exit statuses (docs/reference/cli.md): 0 every device answered; 1 a device could not be opened or
failed to answer (each failure one line, the others still described); 2 bad usage or configuration.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, add_config_argument
from drivers.clock import make_clock
from drivers.errors import DeviceError

if TYPE_CHECKING:
    from daemon.run.devices_check import DeviceCheck

# the device and vision modules (OpenCV, SciPy, the drivers) are imported where they are used:
# `thermocomp devices --help` must answer at once (issue 16)

PROG = "thermocomp devices check"


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "devices",
        help="bring-up: check that the configured devices answer",
        description="Bring-up of the lab's devices.",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    check = actions.add_parser(
        "check",
        help="grab one frame, one IR image and the robot pose; write a preview",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_config_argument(check)
    check.add_argument(
        "--preview",
        type=Path,
        metavar="FILE",
        help="write a PNG of the frame with the spot marked beside the thermal image with "
        "every IR region drawn and labelled",
    )
    check.add_argument("--json", action="store_true", help="print the result as JSON")
    check.set_defaults(handler=run_devices_check)


async def _check(settings: Settings) -> DeviceCheck:
    # lazy: the devices (the simulated bench: SciPy, OpenCV) load when the check runs, not
    # for --help (issue 16)
    from daemon.run.devices_check import check_devices
    from drivers.factory import open_devices

    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    async with open_devices(settings, clock) as devices:
        return await check_devices(devices, settings)


def run_devices_check(args: argparse.Namespace) -> int:
    # lazy: OpenCV (the preview PNG) loads when the check runs, not for --help (issue 16)
    from daemon.run.devices_check import describe, preview_png

    settings = load_settings(args.config)
    try:
        check = asyncio.run(_check(settings))
    except DeviceError as err:
        print(f"{PROG}: cannot open the devices: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        print(json.dumps(check.as_dict(), indent=2))
    else:
        for line in describe(check):
            print(line)
    if args.preview is not None:
        try:
            args.preview.write_bytes(preview_png(check))
        except (DeviceError, OSError, ValueError) as err:
            print(f"{PROG}: no preview written: {err}", file=sys.stderr)
            return EXIT_FAILURE
        print(f"preview written to {args.preview}", file=sys.stderr)
    for device, error in check.errors.items():
        print(f"{PROG}: {device}: {error}", file=sys.stderr)
    return EXIT_OK if check.ok else EXIT_FAILURE
