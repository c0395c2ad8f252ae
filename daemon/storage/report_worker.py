"""``python -m daemon.storage.report_worker DATA_DIR RUN_ID``: the child process that writes one
run's report for daemon/storage/report_queue.py. Exit 0 when written; otherwise the reason on
stderr."""

from __future__ import annotations

import sys
from pathlib import Path

from daemon.storage.reports import write_run_report


def main(argv: list[str]) -> int:
    data_dir, run_id = Path(argv[0]), int(argv[1])
    try:
        write_run_report(data_dir, run_id)
    except Exception as err:  # the parent logs the last line
        print(f"{type(err).__name__}: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
