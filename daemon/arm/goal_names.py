"""The goal names a duty cycle's poses get on the controller (daemon/arm/controller.py): a
letter, then at most 13 letters, digits or ``_`` (``_GOAL_NAME``). Pure."""

from __future__ import annotations

import re
from collections.abc import Sequence

_GOAL_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,13}")


def goal_names(names: Sequence[str], keep: set[str]) -> list[str]:
    """A distinct valid goal name for each pose name: ``keep`` (the measured poses, already
    goals) and valid names as they are, others with each other character as ``_`` (e.g.
    ``pick-above`` -> ``pick_above``), else ``p<index>``."""
    used = set(keep)
    out = []
    for index, name in enumerate(names):
        if name in keep:
            out.append(name)
            continue
        candidate = re.sub(r"[^A-Za-z0-9_]", "_", name)
        if not _GOAL_NAME.fullmatch(candidate) or candidate in used:
            candidate = f"p{index}"
        while candidate in used:
            candidate += "_"
        used.add(candidate)
        out.append(candidate)
    return out
