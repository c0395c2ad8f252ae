"""``thermocomp emulate ur``: serve the emulated UR e-Series (RTDE on 30004, the Dashboard
Server on 29999) on a loopback address until a signal stops it.

SIGINT/SIGTERM stop it; SIGUSR1 triggers a protective stop (the Dashboard's "unlock protective
stop" then "play" recover); SIGUSR2 stops the program as an operator would on the pendant.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import ipaddress
import signal
import sys

from drivers.ur.registers import REGISTER_BASE_MAX, REGISTER_BASE_MIN


def _loopback(text: str) -> str:
    try:
        address = ipaddress.ip_address(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text!r} is not an IP address") from err
    if not address.is_loopback:
        raise argparse.ArgumentTypeError(f"{text} is not a loopback address (127.0.0.0/8, ::1)")
    return text


def _register_base(text: str) -> int:
    try:
        value = int(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from err
    if not REGISTER_BASE_MIN <= value <= REGISTER_BASE_MAX:
        raise argparse.ArgumentTypeError(f"between {REGISTER_BASE_MIN} and {REGISTER_BASE_MAX}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("ur (the UR e-Series emulator)")
    group.add_argument(
        "--host",
        type=_loopback,
        default="127.0.0.1",
        help="loopback address to serve on (default 127.0.0.1; any 127.0.0.N)",
    )
    group.add_argument(
        "--rtde-port", type=int, default=30004, help="RTDE port (default UR's 30004)"
    )
    group.add_argument(
        "--dashboard-port", type=int, default=29999, help="Dashboard port (default UR's 29999)"
    )
    group.add_argument(
        "--duty",
        default="ur5e-pick-and-place",
        help="the taught program: a duty cycle preset or file (default ur5e-pick-and-place)",
    )
    group.add_argument(
        "--register-base",
        type=_register_base,
        default=24,
        help="the program's first register (robot.register_base; default 24)",
    )
    group.add_argument(
        "--fieldbus",
        action="store_true",
        help="a fieldbus adapter is enabled: input registers 0-23 answer IN_USE",
    )
    group.add_argument(
        "--stopped", action="store_true", help="start with the program stopped (wait for play)"
    )


async def _serve(emulator: object) -> None:
    # lazy: the emulator (SciPy) loads when it serves, not for `emulate --help` (issue 16)
    from drivers.sim.ur.emulator import UREmulator

    assert isinstance(emulator, UREmulator)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    loop.add_signal_handler(signal.SIGUSR1, emulator.protective_stop)
    loop.add_signal_handler(signal.SIGUSR2, emulator.operator_stop)
    async with emulator:
        gc.collect()
        gc.freeze()  # as `emulate c500c`: no full collection delays a controller cycle
        print(
            f"RTDE {emulator.host}:{emulator.rtde_port} "
            f"Dashboard {emulator.host}:{emulator.dashboard_port}",
            flush=True,
        )
        await stop.wait()
    print(
        f"thermocomp emulate: stopped after {emulator.controller.cycles} cycles "
        f"({emulator.skipped_cycles} skipped); RTDE packages sent {emulator.rtde.sent_total}, "
        f"dropped at a full socket {emulator.rtde.skipped_total}",
        flush=True,
    )


def run(args: argparse.Namespace) -> int:
    # lazy: the arm's kinematics (SciPy) load when the emulator starts, not for `emulate --help`
    from daemon.arm.description import ArmError
    from daemon.arm.duty import DutyCycleError
    from drivers.sim.ur.controller import URControllerConfig
    from drivers.sim.ur.emulator import UREmulator

    config = URControllerConfig(
        duty=args.duty,
        register_base=args.register_base,
        seed=args.seed,
        autoplay=not args.stopped,
        fieldbus=args.fieldbus,
    )
    try:
        emulator = UREmulator(
            config, host=args.host, rtde_port=args.rtde_port, dashboard_port=args.dashboard_port
        )
    except (ArmError, DutyCycleError, ValueError) as err:
        print(f"thermocomp emulate ur: {err}", file=sys.stderr)
        return 2
    try:
        asyncio.run(_serve(emulator))
    except OSError as err:
        print(f"thermocomp emulate ur: {err}", file=sys.stderr)
        return 1
    gc.freeze()
    return 0
