"""The two-link tutorial's curl session (docs/tutorials/two-link-bench.md), run as written
against the real ``thermocomp serve`` that its first command starts (``make run`` with a
control token) on the simulated bench: it must stay copy-paste runnable, and the outputs the
page shows must be the server's."""

from __future__ import annotations

import csv
import json
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from daemon.storage.recorder import STEP_COLUMNS
from tests.helpers import REPO_ROOT, running_server

TUTORIAL = REPO_ROOT / "docs" / "tutorials" / "two-link-bench.md"


def tutorial_blocks() -> tuple[str, str]:
    """(the command that starts the server, the curl session) from the tutorial."""
    text = TUTORIAL.read_text(encoding="utf-8")
    start = re.findall(r"```sh\n(.*?)```", text.split("## Start the daemon", 1)[1], re.DOTALL)
    section = text.split("## Drive it from a terminal", 1)[1].split("\n## ", 1)[0]
    session = re.findall(r"```sh\n(.*?)```", section, flags=re.DOTALL)
    assert start and len(session) == 1, "expected the server command and one session block"
    return start[0].strip(), session[0]


def shown_output(session: str, command: str) -> Any:
    """The JSON the page shows (``# {...}``) on the line after ``command``."""
    lines = session.splitlines()
    index = next(i for i, line in enumerate(lines) if line.startswith(command))
    comment = lines[index + 1]
    assert comment.startswith("# {"), f"no output shown after {command!r}"
    return json.loads(comment[2:])


def shape(value: Any) -> Any:
    """The keys of a JSON value, recursively (values differ from run to run, keys must not)."""
    if isinstance(value, dict):
        return {key: shape(item) for key, item in value.items()}
    return type(value).__name__


@pytest.mark.slow
@pytest.mark.timeout(300)  # two 600-step runs through a real server on a busy machine
def test_tutorial_curl_session_runs(tmp_path: Path) -> None:
    start, session = tutorial_blocks()
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
            timeout=240,
            check=False,
        )
    assert result.returncode == 0, result.stdout + result.stderr
    out = result.stdout.splitlines()
    health = json.loads(out[0])
    assert health["status"] == "ok" and health["daemon"] == "running"
    assert shape(health) == shape(shown_output(session, "curl -s $API/health"))
    # both runs watched to their end, the second measured against the first
    assert sum(line.startswith("finished 600 steps 100 %") for line in out) == 2, out
    (verdict,) = [line for line in out if line.startswith("drift ")]
    match = re.fullmatch(r"drift (\S+) um; residual (\S+) um; removed (\S+) % vs run 1", verdict)
    assert match is not None, verdict
    drift, residual, removed = (float(group) for group in match.groups())
    assert residual < drift and removed == pytest.approx(100 * (1 - residual / drift), abs=0.5)
    held = json.loads(out[-2])
    assert held["held"] is True
    assert shape(held) == shape(shown_output(session, "curl -s -X POST $API/robot/stop"))
    with open(tmp_path / "run-2.csv", newline="") as handle:
        rows = list(csv.reader(handle))
    assert tuple(rows[0]) == STEP_COLUMNS and len(rows) == 601
    assert out[-1].split() == ["601", "run-2.csv"]
