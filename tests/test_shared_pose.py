"""The emulated arm's shared motion record (drivers/sim/shared_pose.py): its framing, its seqlock
against a writer in another process, and its rule against the inline emulator's own
``Console.actual_pose`` for the same moves."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from multiprocessing.shared_memory import SharedMemory

import numpy as np
import pytest

from drivers.sim import shared_pose
from drivers.sim.ash import Console
from drivers.sim.emulator_config import EmulatorConfig
from tests.helpers import REPO_ROOT


@pytest.fixture
def block() -> Iterator[SharedMemory]:
    memory = SharedMemory(create=True, size=shared_pose.SIZE)
    try:
        yield memory
    finally:
        memory.close()
        memory.unlink()


def test_a_record_survives_packing() -> None:
    record = shared_pose.PoseRecord(
        (1.0, 2.0, 3.0, 4.0, 5.0, 6.0), (1.5, 2.5, 3.5, 4.5, 5.5, 6.5), 123.456789
    )
    assert shared_pose.unpack(shared_pose.pack(record)) == record
    assert len(shared_pose.pack(record)) + shared_pose.SEQUENCE.size == shared_pose.SIZE


def test_the_rule_is_the_consoles(block: SharedMemory) -> None:
    record = shared_pose.PoseRecord((0.0,) * 6, (1.0,) * 6, 10.0)
    assert record.pose_at(9.999) == (0.0,) * 6
    assert record.pose_at(10.0) == (1.0,) * 6


def test_nothing_is_read_before_the_first_write(block: SharedMemory) -> None:
    with pytest.raises(shared_pose.SharedPoseError, match="not published"):
        shared_pose.read(shared_pose.buffer_of(block))


def test_a_write_that_never_ends_is_an_error_not_a_hang(block: SharedMemory) -> None:
    buffer = shared_pose.buffer_of(block)
    shared_pose.write(buffer, shared_pose.PoseRecord((0.0,) * 6, (1.0,) * 6, 1.0))
    shared_pose.SEQUENCE.pack_into(buffer, 0, 3)  # a writer that died mid-write
    with pytest.raises(shared_pose.SharedPoseError, match="never ended"):
        shared_pose.read(buffer, timeout_s=0.05)


WRITER = """
import sys, time
from drivers.sim import shared_pose
block = shared_pose.attach(sys.argv[1])
buffer = shared_pose.buffer_of(block)
k = 0
end = time.monotonic() + float(sys.argv[2])
print("ready", flush=True)
while time.monotonic() < end:
    k += 1
    v = float(k)
    shared_pose.write(buffer, shared_pose.PoseRecord((v,) * 6, (v,) * 6, v))
    if k % 100 == 0:
        time.sleep(float(sys.argv[3]))  # bursts: a reader retries through each one
print(k, flush=True)
block.close()
"""


def test_a_reader_never_sees_a_torn_record_of_a_writer_in_another_process(
    block: SharedMemory,
) -> None:
    # A writer process writes records whose 13 numbers are all equal, in bursts of 100 back to
    # back (the emulator writes one per move: 50 a second at a 20 ms step); a torn copy would
    # mix two of them. Without the sequence check this fails (torn records) on two cores.
    buffer = shared_pose.buffer_of(block)
    shared_pose.write(buffer, shared_pose.PoseRecord((0.0,) * 6, (0.0,) * 6, 0.0))
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER, block.name.lstrip("/"), "1.0", "0.001"],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert writer.stdout is not None
    assert writer.stdout.readline().strip() == "ready"
    values = set()
    end = time.monotonic() + 0.8
    while time.monotonic() < end:
        record = shared_pose.read(buffer)
        numbers = {*record.previous_actual, *record.actual, record.motion_end_s}
        assert len(numbers) == 1, f"torn record: {record}"
        values |= numbers
    written = int(writer.stdout.readline())
    assert writer.wait(timeout=10) == 0
    writer.stdout.close()
    assert written > 1000 and len(values) > 10  # it did race: many records went by


async def test_the_published_record_gives_the_inline_emulators_poses(block: SharedMemory) -> None:
    # The inline console, its motion record published on each change (as the emulator's
    # process does): at every instant around each move, the shared rule and the console's
    # own actual_pose agree, and the record is there before the move returns its answer.
    console = Console(EmulatorConfig(seed=3, noise_um=0.9, move_ms=5.0), np.random.default_rng(3))
    buffer = shared_pose.buffer_of(block)
    state = console.state
    console.on_motion = lambda: shared_pose.write(
        buffer, shared_pose.record_of(state.previous_actual, state.actual, state.motion_end_s)
    )
    for line in ["wx 1.5", "wy -0.25", "wz 0.125"]:
        assert await console.execute(line) == []
        record = shared_pose.read(buffer)  # written before execute answered
        end_s = state.motion_end_s
        for t_s in (end_s - 0.005, end_s - 1e-6, end_s, end_s + 1e-6, end_s + 10.0):
            assert record.pose_at(t_s) == console.actual_pose(t_s)
    assert state.motion_count == 3
    assert await console.execute("wx 2") == []
    console.halt_motion(console.now())
    record = shared_pose.read(buffer)
    assert record.pose_at(console.now()) == console.actual_pose(console.now())
