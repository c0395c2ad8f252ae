"""Reading a TOML file (settings, networks, arms, duty cycles, truths) with one clear line for
every way it can be bad; below config.settings, so config.arm_truth (which config.settings
imports) reads its files without an import circle."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from config.inputs import MAX_TOML_DEPTH, nesting_depth, read_regular_file

#: Largest settings or network file read (bytes): the biggest preset is a few KiB, so anything
#: this large is the wrong file, refused before it is parsed.
MAX_TOML_BYTES = 4 * 1024 * 1024


def read_toml(path: Path, error: type[Exception]) -> dict[str, Any]:
    """A TOML file's tables; any failure is ``error("<path>: <why>")`` in one line (missing, a
    folder, a FIFO or device, over 4 MiB, binary, not UTF-8, not TOML, nested deeper than
    ``MAX_TOML_DEPTH``), so every file thermocomp reads reports bad files the same way."""
    raw = read_regular_file(path, MAX_TOML_BYTES, "a TOML file", error)
    if b"\0" in raw:
        raise error(f"{path}: a binary file, not TOML text")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(f"{path}: not UTF-8 text (byte {err.start}): save it as UTF-8") from err
    too_deep = f"{path}: arrays or tables nested over {MAX_TOML_DEPTH} deep: not a thermocomp file"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(f"{path}: not valid TOML: {err}") from err
    except RecursionError as err:  # the parser recurses once per level of nesting
        raise error(too_deep) from err
    if nesting_depth(data, MAX_TOML_DEPTH) > MAX_TOML_DEPTH:
        raise error(too_deep)
    return data
