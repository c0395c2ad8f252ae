"""The emulated arm's pose, shared by the emulator's process with the bench's (issue 30).

With ``bench.emulator = "process"`` the emulated C500C runs in a process of its own
(drivers/sim/emulator_process.py) while the bench's physics, in the daemon, needs where the arm
is at the moment it images the spot. The emulator publishes the console's motion record
(drivers/sim/ash.py ``Console.actual_pose``: ``actual`` once ``now_s >= motion_end_s``, else
``previous_actual``) in a shared memory block each time a motion starts or halts, before it
answers the command; the bench evaluates the same rule at ``time.monotonic()``, the clock the
emulator's event loop (``loop.time()``) runs on too, one CLOCK_MONOTONIC per machine.

The block is a seqlock (one writer, any readers, nobody waits): a sequence number, odd while a
write is in progress, then the record. A reader copies the record between two reads of the
sequence and retries when they differ or the first was odd. Python writes the bytes in program
order and x86-64 keeps stores in order (TSO), so an even, unchanged sequence means an untorn
record. This module is the framing only; the memory itself is ``multiprocessing.shared_memory``.
"""

from __future__ import annotations

import struct
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing import resource_tracker
from multiprocessing.shared_memory import SharedMemory

from drivers.errors import DeviceError
from drivers.sim.ash_state import Location, as_location

#: The sequence number: even when the record is whole, odd while it is written.
SEQUENCE = struct.Struct("<Q")
#: previous_actual (6), actual (6): x, y, z mm and z-, y-, x-rotation degrees; motion_end_s.
RECORD = struct.Struct("<6d6dd")
#: Bytes of the shared block.
SIZE = SEQUENCE.size + RECORD.size
#: Reads tried back to back before the reader sleeps: a write is a few microseconds of the
#: emulator's Python, so most reads that meet one find it ended a few reads later.
SPIN_READS = 100
#: The reader's sleep between spins (s): lets a writer that the kernel preempted mid-write (a
#: loaded machine: the emulator at normal priority) run and end its write.
SPIN_PAUSE_S = 0.0002
#: How long a reader waits for a write to end (s) before it calls the writer dead mid-write:
#: far beyond any preemption of a live process (tests/test_shared_pose.py races a writer on a
#: loaded machine; a fixed 10,000 hot reads gave up within a few milliseconds there).
READ_TIMEOUT_S = 1.0


class SharedPoseError(DeviceError):
    """The shared pose cannot be read: never written, or a write that never ended (a device
    fault of the emulated controller, handled as the driver's are)."""

    def __init__(self, message: str) -> None:
        super().__init__("emulated controller", message)


@dataclass(frozen=True, slots=True)
class PoseRecord:
    """The console's motion record (drivers/sim/ash_state.py ``ConsoleState``)."""

    previous_actual: Location
    actual: Location
    motion_end_s: float

    def pose_at(self, now_s: float) -> Location:
        """Where the arm is at ``now_s`` (CLOCK_MONOTONIC): drivers/sim/ash.py's rule."""
        return self.actual if now_s >= self.motion_end_s else self.previous_actual


def pack(record: PoseRecord) -> bytes:
    return RECORD.pack(*record.previous_actual, *record.actual, record.motion_end_s)


def unpack(data: bytes | memoryview) -> PoseRecord:
    values = RECORD.unpack(data)
    return PoseRecord(as_location(values[0:6]), as_location(values[6:12]), values[12])


def write(buffer: memoryview, record: PoseRecord) -> None:
    """Publish ``record`` (the one writer): sequence odd, the record, sequence even again.

    The sequence is stored by one 8-byte copy (slice assignment: memcpy), never by
    ``struct.pack_into``, which zeroes its target before filling it: a reader would see a
    transient 0 there."""
    (sequence,) = SEQUENCE.unpack_from(buffer, 0)
    data = pack(record)
    buffer[: SEQUENCE.size] = SEQUENCE.pack(sequence + 1)
    buffer[SEQUENCE.size : SIZE] = data
    buffer[: SEQUENCE.size] = SEQUENCE.pack(sequence + 2)


def read(buffer: memoryview, timeout_s: float = READ_TIMEOUT_S) -> PoseRecord:
    """The last whole record; SharedPoseError when none was ever written or no read within
    ``timeout_s`` found the sequence even and unchanged around the copy."""
    deadline = time.monotonic() + timeout_s
    while True:
        for _ in range(SPIN_READS):
            (before,) = SEQUENCE.unpack_from(buffer, 0)
            if before % 2:
                continue
            data = bytes(buffer[SEQUENCE.size : SIZE])
            (after,) = SEQUENCE.unpack_from(buffer, 0)
            if before == after:
                if before == 0:
                    raise SharedPoseError("the emulator has not published its pose yet")
                return unpack(data)
        if time.monotonic() > deadline:
            raise SharedPoseError(
                f"no whole pose record within {timeout_s:g} s: a write never ended"
            )
        time.sleep(SPIN_PAUSE_S)


def record_of(
    previous_actual: Sequence[float], actual: Sequence[float], end_s: float
) -> PoseRecord:
    """The record of the console state's three fields (drivers/sim/ash_state.py)."""
    return PoseRecord(as_location(previous_actual), as_location(actual), float(end_s))


def buffer_of(block: SharedMemory) -> memoryview:
    """The open block's bytes (SharedPoseError once it is closed)."""
    if block.buf is None:
        raise SharedPoseError(f"the shared pose block {block.name} is closed")
    return block.buf


def attach(name: str) -> SharedMemory:
    """The block ``name`` another process created (and will unlink), opened without the
    resource tracker: before Python 3.13 every attach registers the block with this process's
    tracker, which unlinks it when this process exits and starts a tracker process for it
    (CPython gh-82300; 3.13's ``track=False`` is the fix)."""
    if sys.version_info >= (3, 13):
        return SharedMemory(name, track=False)  # type: ignore[call-arg,unused-ignore]
    register = resource_tracker.register
    resource_tracker.register = lambda *args: None  # type: ignore[assignment,unused-ignore]
    try:
        return SharedMemory(name)
    finally:
        resource_tracker.register = register
