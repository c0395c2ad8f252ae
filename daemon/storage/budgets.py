"""The latest measurement error budget of the set-up, kept in the data directory by
``thermocomp budget --save`` (daemon/commands/budget_run.py) for those that cannot record one:
``GET /api/v1/budget`` and the run reports (daemon/storage/reports.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from daemon.analysis.budget import Budget

#: The latest ``thermocomp budget --save`` in the data directory (GET /api/v1/budget).
BUDGET_FILE = "budget.json"


def save_budget(data_dir: Path, budget: Budget, recorded: bool) -> Path:
    """Write ``budget`` as the data directory's latest (atomically: a reader never sees half)."""
    from datetime import UTC, datetime

    path = Path(data_dir) / BUDGET_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    document = {
        "made_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "recorded": recorded,
        **budget.to_dict(),
    }
    partial = path.with_suffix(".json.partial")
    partial.write_text(json.dumps(document, indent=2), encoding="utf-8")
    partial.replace(path)
    return path


def read_saved_budget(data_dir: Path) -> dict[str, Any] | None:
    """The latest saved budget, None when there is none or it does not read as one."""
    path = Path(data_dir) / BUDGET_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return data if isinstance(data, dict) and "sources" in data else None
