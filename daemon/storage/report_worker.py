"""``python -m daemon.storage.report_worker DATA_DIR RUN_ID``: the child process that writes one
run's report for daemon/storage/report_queue.py. Exit 0 when written; otherwise the reason on
stderr."""

from __future__ import annotations

import sys
from pathlib import Path

from drivers.realtime import background_priority

#: The report writer runs this much nicer than the daemon, and never at its real-time priority.
REPORT_NICENESS = 10


def main(argv: list[str]) -> int:
    background_priority(REPORT_NICENESS)
    # lazy: Matplotlib and the analyses load after the child has left the daemon's real-time
    # scheduling, which it inherits: a second of imports would otherwise take a core from
    # every ordinary process of the lab PC
    from daemon.storage.reports import write_run_report

    data_dir, run_id = Path(argv[0]), int(argv[1])
    try:
        write_run_report(data_dir, run_id)
    except Exception as err:  # the parent logs the last line
        print(f"{type(err).__name__}: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
