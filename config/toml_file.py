"""Reading a TOML file (settings, networks, arms, duty cycles, truths) with one clear line for
every way it can be bad; below config.settings, so config.arm_truth (which config.settings
imports) reads its files without an import circle."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

#: Largest settings or network file read (bytes): the biggest preset is a few KiB, so anything
#: this large is the wrong file, refused before it is parsed.
MAX_TOML_BYTES = 4 * 1024 * 1024


def read_toml(path: Path, error: type[Exception]) -> dict[str, Any]:
    """A TOML file's tables; any failure is ``error("<path>: <why>")`` (missing, not TOML,
    unreadable), so settings and network files report bad files the same way."""
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_TOML_BYTES + 1)
    except FileNotFoundError as err:
        raise error(f"{path}: no such file") from err
    except IsADirectoryError as err:
        raise error(f"{path}: is a folder, not a TOML file") from err
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from err
    if len(raw) > MAX_TOML_BYTES:
        raise error(f"{path}: over {MAX_TOML_BYTES // 1024} KiB: not a settings or network file")
    if b"\0" in raw:
        raise error(f"{path}: a binary file, not TOML text")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(f"{path}: not UTF-8 text (byte {err.start}): save it as UTF-8") from err
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(f"{path}: not valid TOML: {err}") from err
