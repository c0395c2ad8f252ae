"""What every input file and every name a person types shares (issues 26 and 28): one error
class whose ``str()`` is the one line shown, bounded reads of regular files, bounded nesting,
and "no such name" lines that list what exists and guess the name meant.

It sits in the bottom layer (no pydantic, no NumPy: ``config.cli`` imports stay cheap) so that
the loaders of every layer -- settings, networks, arms and URDFs, duty cycles, camera files,
arm models, images -- refuse bad input the same way, and the entry points (``api/cli.py``,
``thermocomp serve``'s start-up checks) turn any of them into one line and exit status 2.
"""

from __future__ import annotations

import difflib
import os
import stat
from collections.abc import Iterable
from pathlib import Path

#: Deepest nesting of arrays and tables read from any TOML file: the deepest real file (a
#: network's identification table of parameters) nests 3; Python's TOML parser recurses per
#: level and raises RecursionError near 1,000 (a crash, not a message) (issue 26).
MAX_TOML_DEPTH = 16

#: How close a typed name must be to a real one to be offered as "did you mean" (difflib's
#: ratio: "thesis-two-lnk" vs "thesis-two-link" is 0.97, "nosuch" vs "cal" 0.2).
SUGGESTION_CUTOFF = 0.6


class InputError(ValueError):
    """A file, a name or a value given to thermocomp is unusable. ``str()`` is one line naming
    the thing and what is wrong (and, for a name, the names that exist); every entry point
    shows it as it is and exits with status 2 (``config.cli.EXIT_USAGE``)."""


def one_line(text: object) -> str:
    """``text`` on one line: its lines joined by "; " (a validation error lists several)."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


def did_you_mean(name: str, names: Iterable[str]) -> list[str]:
    """The names of ``names`` close to ``name`` (difflib), closest first, at most two."""
    others = [known for known in names if known != name]
    return difflib.get_close_matches(name, others, n=2, cutoff=SUGGESTION_CUTOFF)


def no_such_name(kind: str, name: str, names: Iterable[str], listing: str | None = None) -> str:
    """The line for a name that names nothing: ``no <kind> 'x' (did you mean 'y'?; <kind>s:
    a, b, c)``. ``listing`` replaces the default list (e.g. "presets: a, b; saved in D: c")."""
    existing = sorted(set(names))
    guesses = " or ".join(repr(guess) for guess in did_you_mean(name, existing))
    parts = [f"did you mean {guesses}?"] if guesses else []
    parts.append(listing if listing is not None else f"{kind}s: {', '.join(existing) or 'none'}")
    return f"no {kind} {name!r} ({'; '.join(parts)})"


def read_regular_file(path: Path, max_bytes: int, what: str, error: type[Exception]) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes``; anything else is
    ``error("<path>: <why>")`` in one line: missing, a folder, a FIFO or device (reading one
    blocks forever, issue 26), unreadable, or larger than ``max_bytes`` (not read whole).

    The file is opened non-blocking and checked with fstat before the first read, so a FIFO
    named as a file is refused at once rather than waited on."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError as err:
        raise error(f"{path}: no such file") from err
    except IsADirectoryError as err:
        raise error(f"{path}: is a folder, not {what}") from err
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from err
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise error(f"{path}: is a folder, not {what}")
        if not stat.S_ISREG(mode):
            raise error(f"{path}: not a regular file (a pipe, socket or device), not {what}")
        os.set_blocking(fd, True)
        with os.fdopen(fd, "rb", closefd=True) as handle:
            fd = -1
            data = handle.read(max_bytes + 1)
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from err
    finally:
        if fd >= 0:
            os.close(fd)
    if len(data) > max_bytes:
        raise error(f"{path}: over {_size(max_bytes)}: not {what}")
    return data


def check_regular_file(path: Path, what: str, error: type[Exception]) -> None:
    """``path`` is a regular file (not missing, a folder, a FIFO or a device), else
    ``error`` in one line; for readers that take a path (OpenCV, lxml)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError as err:
        raise error(f"{path}: no such file") from err
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from err
    if stat.S_ISDIR(mode):
        raise error(f"{path}: is a folder, not {what}")
    if not stat.S_ISREG(mode):
        raise error(f"{path}: not a regular file (a pipe, socket or device), not {what}")


def nesting_depth(value: object, limit: int) -> int:
    """How deep ``value`` (parsed TOML/JSON: dicts and lists) nests, counted up to
    ``limit + 1`` at most (without recursion, so any depth is safe to measure)."""
    deepest = 0
    stack: list[tuple[object, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        deepest = max(deepest, depth)
        if depth > limit:
            return depth
        if isinstance(item, dict):
            stack.extend((child, depth + 1) for child in item.values())
        elif isinstance(item, list | tuple):
            stack.extend((child, depth + 1) for child in item)
    return deepest


def _size(count: int) -> str:
    return f"{count // (1024 * 1024)} MiB" if count >= 1024 * 1024 else f"{count // 1024} KiB"


__all__ = [
    "MAX_TOML_DEPTH",
    "InputError",
    "check_regular_file",
    "did_you_mean",
    "nesting_depth",
    "no_such_name",
    "one_line",
    "read_regular_file",
]
