"""``thermocomp emulate c500c``: serve the emulated C500C console until a signal stops it
(``thermocomp emulate ur``: the UR e-Series, drivers/sim/ur/cli.py).

SIGINT/SIGTERM stop it (it prints that it stopped, within a fraction of a second); SIGUSR1
presses the controller's PAUSE/CONTINUE button (a motion waiting for the point of control goes
on).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import os
import signal
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from config.cli import non_negative_float, non_negative_int, port_number
from config.faults import Fault
from config.settings import SUPPORTED_BAUDRATES
from drivers.realtime import realtime_scheduling
from drivers.sim.ur import cli as ur_cli  # light: its work is imported when it runs

if TYPE_CHECKING:  # the emulators (NumPy) load when one is served, not for --help
    from drivers.sim.emulator import C500CEmulator, FaultKind
    from drivers.sim.joint_arm import JointArmConfig


def _faults(text: str) -> tuple[Fault[FaultKind], ...]:
    from drivers.sim.emulator import parse_faults  # lazy: NumPy loads to serve, not for --help

    try:
        return parse_faults(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "emulate",
        help="serve an emulated device (the C500C console, a UR)",
        description="Serve the emulated CRS C500C console on a pseudo-terminal (prints the "
        "device path to open) or a TCP port (prints a socket:// URL pyserial opens). "
        "SIGINT or SIGTERM stops it; SIGUSR1 presses PAUSE/CONTINUE (gives the point of "
        "control).",
        epilog="Fault SPEC: comma-separated KIND[=SECONDS][@N|%P] with KIND one of drop, "
        "corrupt, delay, stall, close, restart; @N strikes at the N-th command line, %P with "
        "probability P per command. Example: --faults 'drop@5,delay=2@9,corrupt%0.01'.",
    )
    parser.add_argument(
        "device",
        choices=["c500c", "ur"],
        help="the device to emulate: c500c (the console) or ur (a UR e-Series over RTDE and "
        "the Dashboard Server, drivers/sim/ur/)",
    )
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal (default)")
    where.add_argument(
        "--tcp", type=port_number, metavar="PORT", help="serve on 127.0.0.1:PORT (0: any)"
    )
    parser.add_argument(
        "--link", type=Path, help="path of the symlink to the pty (default: a temporary one)"
    )
    parser.add_argument(
        "--seed", type=non_negative_int, default=1, help="seed of the positioning noise"
    )
    parser.add_argument(
        "--noise-um",
        type=non_negative_float,
        default=0.9,
        help="1-sigma positioning error per axis in um (default 0.9: the thesis's S_x)",
    )
    parser.add_argument(
        "--move-ms", type=non_negative_float, default=5.0, help="time one move takes (default 5 ms)"
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=None,
        choices=SUPPORTED_BAUDRATES,
        help="baud rate the link is paced at (default 57600; 115200 with --server)",
    )
    parser.add_argument(
        "--no-pacing", action="store_true", help="answer at once instead of at the baud rate"
    )
    parser.add_argument("--faults", type=_faults, default=(), metavar="SPEC", help="faults")
    parser.add_argument(
        "--shell", action="store_true", help="start at the system shell `$ ` prompt"
    )
    parser.add_argument(
        "--server",
        action="store_true",
        help="serve the fast path's program (controller/PROTOCOL.md) instead of the console",
    )
    parser.add_argument(
        "--application", default="ash", help="the ash application's name (prompt `NAME> `)"
    )
    parser.add_argument(
        "--no-point-of-control",
        action="store_true",
        help="start without the point of control: a motion waits for SIGUSR1 (the button)",
    )
    parser.add_argument(
        "--arm",
        metavar="ARM",
        help="emulate the arm in joint space: a preset name (crs-a465) or an arm file "
        "(inverse kinematics, trapezoidal joint motion, JOINTS and PULSES in w2)",
    )
    parser.add_argument(
        "--layout",
        choices=["firmware", "single-line"],
        default="firmware",
        help="w0/w2 layout: the firmware's (default) or this project's older single line",
    )
    parser.add_argument(
        "--silence-s",
        type=float,
        default=None,
        metavar="SECONDS",
        help="with --server: the program halts and holds after this long without a frame "
        "(default 1 s, controller/thermocomp_server.r3 SILENCE_MS)",
    )
    parser.add_argument(
        "--pose-shm",
        metavar="NAME",
        help="publish the arm's motion record in this shared memory block, created by the "
        "caller (drivers/sim/shared_pose.py: the bench of a daemon running this emulator in "
        "its own process, bench.emulator = process)",
    )
    parser.add_argument(
        "--exit-with-stdin",
        action="store_true",
        help="stop when standard input closes (the parent that started it has ended)",
    )
    parser.add_argument(
        "--realtime-priority",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="run at SCHED_FIFO priority N when the host permits it (else a lower niceness); "
        "0: normal scheduling",
    )
    ur_cli.add_arguments(parser)
    parser.set_defaults(handler=run)


def _stop_at_eof(stop: asyncio.Event, parent_gone: asyncio.Event) -> None:
    """Standard input readable: at its end (the parent's pipe closed: the parent ended, however
    it ended) stop serving; anything else on it is ignored."""
    try:
        data = os.read(sys.stdin.fileno(), 4096)
    except OSError:
        data = b""
    if not data:
        asyncio.get_running_loop().remove_reader(sys.stdin.fileno())
        parent_gone.set()
        stop.set()


async def _serve(emulator: C500CEmulator, args: argparse.Namespace) -> None:
    stop, parent_gone = asyncio.Event(), asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    loop.add_signal_handler(signal.SIGUSR1, emulator.press_pause_continue)
    if args.exit_with_stdin:
        loop.add_reader(sys.stdin.fileno(), _stop_at_eof, stop, parent_gone)
    async with contextlib.AsyncExitStack() as stack:
        if args.pose_shm is not None:
            stack.enter_context(_publishing_pose(emulator, args.pose_shm))
        await stack.enter_async_context(emulator)
        # The emulator stands in for another machine: a full collection of the heap this
        # process imported (the whole stack, ~10-15 ms in CPython 3.11) would delay its paced
        # replies as no controller does. Freeze it once started, as the daemon does its own
        # (daemon/heap.py; issue 17).
        gc.collect()
        gc.freeze()
        print(emulator.device_path, flush=True)
        await stop.wait()
    if parent_gone.is_set() and args.link is not None:
        # Stopped because its parent is gone (however it ended): the directory of the link,
        # made by the parent (drivers/sim/emulator_process.py), goes too once empty.
        with contextlib.suppress(OSError):
            args.link.parent.rmdir()
    print("thermocomp emulate: stopped", flush=True)


@contextlib.contextmanager
def _publishing_pose(emulator: C500CEmulator, name: str) -> Iterator[None]:
    """Publish the console's motion record in the shared block ``name`` now and each time it
    changes (before the command that changed it is answered: the host never sees a reply
    before the pose it implies); the block is the caller's (it unlinks it)."""
    from drivers.sim import shared_pose  # lazy: loads with the emulator, not for --help

    block = shared_pose.attach(name)
    state = emulator.state

    def publish() -> None:
        record = shared_pose.record_of(state.previous_actual, state.actual, state.motion_end_s)
        shared_pose.write(shared_pose.buffer_of(block), record)

    publish()
    emulator.console.on_motion = publish
    try:
        yield
    finally:
        emulator.console.on_motion = None
        block.close()


def _joint_arm(args: argparse.Namespace) -> JointArmConfig | None:
    """The --arm option's arm; ArmError (a bad name or file) is the caller's."""
    if args.arm is None:
        return None
    # lazy: the kinematics (SciPy) load only for an emulator with an arm
    from daemon.arm.loading import load_arm
    from drivers.sim.joint_arm import JointArmConfig

    return JointArmConfig(load_arm(args.arm))


def run(args: argparse.Namespace) -> int:
    # lazy: the arm's description (NumPy) loads when an emulator runs, not for --help
    from daemon.arm.description import ArmError

    if args.device == "ur":
        return ur_cli.run(args)
    if args.pose_shm is not None and args.arm is not None:
        print("thermocomp emulate: --pose-shm needs an emulator without --arm", file=sys.stderr)
        return 2
    if args.silence_s is not None and (not args.server or args.silence_s <= 0):
        print("thermocomp emulate: --silence-s is the server's and > 0", file=sys.stderr)
        return 2
    if args.realtime_priority:
        # The emulated controller stands for another machine, which the lab PC's load does not
        # touch: it runs at the control loop's priority (issue 30; drivers/realtime.py).
        print(f"thermocomp emulate: {realtime_scheduling(args.realtime_priority)}", file=sys.stderr)

    try:
        joint_arm = _joint_arm(args)
    except ArmError as err:
        print(f"thermocomp emulate: --arm: {err}", file=sys.stderr)
        return 2
    if args.server:
        return _run_server(args, joint_arm)
    # lazy: the emulators (NumPy) load when one is served, not for --help
    from drivers.sim.emulator import C500CEmulator, EmulatorConfig

    config = EmulatorConfig(
        seed=args.seed,
        noise_um=args.noise_um,
        move_ms=args.move_ms,
        baudrate=args.baud or 57600,
        paced=not args.no_pacing,
        faults=args.faults,
        start_in_shell=args.shell,
        application=args.application,
        point_of_control=not args.no_point_of_control,
        layout=args.layout,
        joint_arm=joint_arm,
    )
    emulator = C500CEmulator(
        config,
        transport="tcp" if args.tcp is not None else "pty",
        tcp_port=args.tcp or 0,
        link_path=args.link,
    )
    try:
        asyncio.run(_serve(emulator, args))
    except OSError as err:
        print(f"thermocomp emulate: {err}", file=sys.stderr)
        return 1
    # The process imported the whole stack (api.cli collects every command): collecting that
    # heap at interpreter exit took 0.7-1.2 s on the development machine. Frozen objects are
    # left alone, so the process ends within a fraction of a second of the signal (issue 21);
    # the emulator itself is closed already (pty and temporary directory removed).
    gc.freeze()
    return 0


def _run_server(args: argparse.Namespace, joint_arm: JointArmConfig | None) -> int:
    if args.faults or args.shell:
        print("thermocomp emulate: --faults and --shell are the console's", file=sys.stderr)
        return 2
    # lazy: the emulators (NumPy) load when one is served, not for --help
    from drivers.sim.server_emulator import (
        DEFAULT_SILENCE_TIMEOUT_S,
        SERVER_BAUDRATE,
        C500CServerEmulator,
        server_emulator_config,
    )

    config = server_emulator_config(
        seed=args.seed,
        noise_um=args.noise_um,
        move_ms=args.move_ms,
        baudrate=args.baud or SERVER_BAUDRATE,
        paced=not args.no_pacing,
        silence_timeout_s=args.silence_s or DEFAULT_SILENCE_TIMEOUT_S,
    )
    config = replace(config, console=replace(config.console, joint_arm=joint_arm))
    emulator = C500CServerEmulator(
        config,
        transport="tcp" if args.tcp is not None else "pty",
        tcp_port=args.tcp or 0,
        link_path=args.link,
    )
    try:
        asyncio.run(_serve(emulator, args))
    except OSError as err:
        print(f"thermocomp emulate: {err}", file=sys.stderr)
        return 1
    return 0
