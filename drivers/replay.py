"""What the camera and IR replay drivers share: a folder of files in natural order on a time base.

Natural order sorts the digits in names as numbers (``frame2`` before ``frame10``), the order a
frame grabber numbering its files without leading zeros means.
"""

from __future__ import annotations

import asyncio
import math
import re
from collections.abc import Iterable
from pathlib import Path

from drivers.clock import Clock
from drivers.errors import DeviceError, NotConnectedError

_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple[tuple[int, int | str], ...]:
    """Sort key: digit runs compare as numbers, the rest as case-folded text."""
    return tuple(
        (0, int(part)) if part.isdigit() else (1, part.casefold())
        for part in _DIGITS.split(name)
        if part
    )


def list_files(folder: Path, suffixes: Iterable[str], device: str) -> list[Path]:
    """The files of ``folder`` with one of ``suffixes`` (case-insensitive), in natural order."""
    wanted = {suffix.lower() for suffix in suffixes}
    if not folder.is_dir():
        raise NotConnectedError(device, f"replay folder {folder} does not exist")
    files = sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in wanted),
        key=lambda p: natural_key(p.name),
    )
    if not files:
        raise NotConnectedError(
            device, f"replay folder {folder} holds no {', '.join(sorted(wanted))} files"
        )
    return files


class ReplayTimeBase:
    """Which file a replay returns next, and its timestamp on the run clock.

    Without a period every request takes the next file, stamped with the clock's now. With a
    period, file i belongs to ``i * period_s`` since the replay opened: a request returns the
    latest file due at the clock's now, stamped with its own time, as the recording had it.
    """

    def __init__(
        self, count: int, clock: Clock, period_s: float | None, loop: bool, device: str
    ) -> None:
        self.count = count
        self.clock = clock
        self.period_s = period_s
        self.loop = loop
        self.device = device
        self.start_s = clock.now()
        self._next = 0

    def next(self) -> tuple[int, float]:
        """(index of the file, timestamp in s on the run clock)."""
        now = self.clock.now()
        if self.period_s is None:
            position = self._next
            self._next += 1
            stamp = now
        else:
            position = math.floor((now - self.start_s) / self.period_s + 1e-9)
            stamp = self.start_s + position * self.period_s
        if position >= self.count and not self.loop:
            raise DeviceError(self.device, f"replay exhausted after {self.count} files")
        return position % self.count, stamp


class ReplayFolder:
    """A folder opened for replay: its files listed (off the event loop) and a time base.
    The camera and IR replay drivers each only turn the file it gives into their reading."""

    def __init__(
        self,
        folder: Path,
        suffixes: Iterable[str],
        clock: Clock,
        *,
        period_s: float | None,
        loop: bool,
        device: str,
    ) -> None:
        self.folder = folder
        self.suffixes = tuple(suffixes)
        self.clock = clock
        self.period_s = period_s
        self.loop = loop
        self.device = device
        self.files: list[Path] = []
        self._time_base: ReplayTimeBase | None = None

    async def open(self) -> None:
        self.files = await asyncio.to_thread(list_files, self.folder, self.suffixes, self.device)
        self._time_base = ReplayTimeBase(
            len(self.files), self.clock, self.period_s, self.loop, self.device
        )

    def close(self) -> None:
        self._time_base = None

    def next(self) -> tuple[Path, float]:
        """(the file due now, its timestamp on the run clock)."""
        if self._time_base is None:
            raise NotConnectedError(self.device, "replay is not open")
        index, stamp = self._time_base.next()
        return self.files[index], stamp
