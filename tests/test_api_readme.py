"""The README's curl session, run as written against the real ``thermocomp serve`` (the
command ``make run`` starts) on the simulated bench: it must stay copy-paste runnable."""

from __future__ import annotations

import csv
import re
import subprocess
from pathlib import Path

from daemon.storage.recorder import STEP_COLUMNS
from tests.helpers import REPO_ROOT, running_server

README = REPO_ROOT / "README.md"


def curl_session() -> tuple[str, str]:
    """(the command that starts the server, the session) from the README."""
    text = README.read_text(encoding="utf-8")
    section = text.split("## Talking to it", 1)[1].split("### API overview", 1)[0]
    blocks = re.findall(r"```sh\n(.*?)```", section, flags=re.DOTALL)
    assert len(blocks) == 2, "expected the server command and the session"
    return blocks[0].strip(), blocks[1]


def test_readme_curl_session_runs(tmp_path: Path) -> None:
    start, session = curl_session()
    token = re.fullmatch(r"THERMOCOMP_API__CONTROL_TOKEN=(\S+) make run", start)
    assert token is not None, start
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": token.group(1),
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path / "data"),
    }
    with running_server(["--config", "config/sim.toml"], env=env) as base_url:
        script = session.replace("http://127.0.0.1:8000", base_url)
        result = subprocess.run(
            ["bash", "-e", "-o", "pipefail", "-c", script],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=90,
            check=False,
        )
    assert result.returncode == 0, result.stdout + result.stderr
    assert '"status":"ok"' in result.stdout and "running" in result.stdout
    assert '"reduction_percent"' in result.stdout  # the stopped run's summary
    with open(tmp_path / "run-1.csv", newline="") as handle:
        rows = list(csv.reader(handle))
    assert tuple(rows[0]) == STEP_COLUMNS and len(rows) > 2
