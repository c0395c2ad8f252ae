"""What a new user meets (issue 28): ``thermocomp serve`` as ``make run`` starts it (no token
configured, loopback) prints the dashboard's address with a control token made on first start
and kept in the data directory (mode 0600); the dashboard takes it from the address, drops it
from the address bar, and can Start and Hold. A restarted daemon's dashboard plots the last
run from the database. Headless Debian Chromium against the real server."""

from __future__ import annotations

import os
import re
import stat
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Browser

from api.security import CONTROL_TOKEN_FILE, local_control_token
from api.startup import StartupError, with_local_control_token
from config import Settings
from tests.helpers import REPO_ROOT, cli_command, free_port
from tests.test_dashboard import browser, new_page  # noqa: F401 (the fixture)

#: The address ``thermocomp serve`` prints once it serves.
DASHBOARD_URL = re.compile(r"dashboard \(control\): (http://127\.0\.0\.1:\d+/\?token=(\S+))")


@contextmanager
def make_run(data_dir: Path, log: Path, *extra: str) -> Iterator[tuple[str, str]]:
    """``make run``'s command (config/sim.toml, no token in the environment) on a free port;
    yields the printed address and the server's base URL. The output goes to a file, read
    as a user reads the terminal."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("THERMOCOMP_")}
    env["THERMOCOMP_STORAGE__DATA_DIR"] = str(data_dir)
    # 20 bench seconds per second: the run moves visibly
    env["THERMOCOMP_BENCH__CLOCK"] = "accelerated"
    env["THERMOCOMP_BENCH__TIME_FACTOR"] = "20"
    port = free_port()
    with log.open("w") as output:
        process = subprocess.Popen(
            cli_command("serve", "--config", "config/sim.toml", "--port", str(port), *extra),
            cwd=REPO_ROOT,
            env=env,
            stdout=output,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            deadline = time.monotonic() + 60
            while not (found := DASHBOARD_URL.search(log.read_text())):
                assert process.poll() is None, log.read_text()
                assert time.monotonic() < deadline, log.read_text()
                time.sleep(0.1)
            yield found.group(1), f"http://127.0.0.1:{port}"
        finally:
            process.terminate()
            process.wait(timeout=30)


@pytest.mark.slow
def test_a_fresh_make_run_can_start_and_hold(browser: Browser, tmp_path: Path) -> None:  # noqa: F811
    data = tmp_path / "data"
    with make_run(data, tmp_path / "serve.log") as (address, server):
        token = address.rsplit("=", 1)[1]
        token_file = data / CONTROL_TOKEN_FILE
        assert token_file.read_text().strip() == token
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        # without the token, control is refused (anonymous reads on loopback only)
        assert httpx.post(f"{server}/api/v1/robot/stop", timeout=10).status_code == 401

        page = new_page(browser)
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(address)
        page.wait_for_selector("#stream-state.open")
        # the token left the address bar (history, bookmarks, screen shares)
        assert "token" not in page.url
        assert page.evaluate("localStorage.getItem('thermocomp-token')") == token
        page.wait_for_selector("#daemon-state:text-is('idle')")
        page.fill("input[name=duration_s]", "3600")
        page.click("#btn-start")
        page.wait_for_selector("#daemon-state:text-is('running')")
        page.wait_for_selector("#doing.running")
        assert (page.text_content("#doing") or "").startswith("Run 1 running")
        page.click("#btn-hold")
        page.wait_for_selector("#robot-badges .badge.held")
        state = httpx.get(f"{server}/api/v1/state", timeout=10).json()
        assert state["robot"]["motion_held"] is True
        assert state["state"] == "paused" and state["run"]["state"] == "paused"
        # the badge comes from the state event, the message from the hold's answer
        page.wait_for_selector("#message:text-matches('^hold acknowledged')")
        page.wait_for_selector("#doing.held")
        assert "Robot HELD" in (page.text_content("#doing") or "")
        assert errors == []

    # a second start keeps the token (the file is the user's; a bookmark stays valid)
    assert local_control_token(data) == token


def _settings(tmp_path: Path, **api: object) -> Settings:
    return Settings.model_validate({"storage": {"data_dir": str(tmp_path)}, "api": api})


def test_a_configured_token_wins_and_remote_binds_get_none(tmp_path: Path) -> None:
    settings, made = with_local_control_token(_settings(tmp_path, control_token="mine"))
    assert made is None and settings.api.control_token == "mine"
    settings, made = with_local_control_token(
        _settings(tmp_path, host="0.0.0.0", anonymous_read=True)
    )
    assert made is None and settings.api.control_token is None  # read-only, as before
    assert not (tmp_path / CONTROL_TOKEN_FILE).exists()
    settings, made = with_local_control_token(_settings(tmp_path))
    assert made is not None and settings.api.control_token == made
    assert len(made) >= 40


def test_a_token_file_others_can_read_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / CONTROL_TOKEN_FILE
    path.write_text("leaked\n")
    path.chmod(0o644)
    with pytest.raises(StartupError) as refused:
        with_local_control_token(_settings(tmp_path))
    message = str(refused.value)
    assert "readable by other users (mode 0644)" in message and "chmod 600" in message
    assert "\n" not in message
    path.chmod(0o600)
    assert with_local_control_token(_settings(tmp_path))[1] == "leaked"
    path.write_text("")  # an empty file: a new token, nothing to lose
    assert len(local_control_token(tmp_path)) >= 40


@pytest.mark.slow
def test_past_runs_are_plotted_after_a_restart(browser: Browser, tmp_path: Path) -> None:  # noqa: F811
    data = tmp_path / "data"
    with make_run(data, tmp_path / "first.log") as (_, server):
        token = local_control_token(data)
        headers = {"Authorization": f"Bearer {token}"}
        answer = httpx.post(
            f"{server}/api/v1/runs", json={"duration_s": 40, "step_s": 1}, headers=headers
        )
        assert answer.status_code == 201, answer.text
        deadline = time.monotonic() + 60
        while httpx.get(f"{server}/api/v1/runs/1", timeout=10).json()["summary"] is None:
            assert time.monotonic() < deadline
            time.sleep(0.2)
        # (the first export starts an export process: seconds on a busy machine)
        steps = httpx.get(f"{server}/api/v1/runs/1/steps", timeout=90).json()["steps"]
        # what each plot must hold: the steps with a value (a busy machine skips some frames)
        measured = sum(step["residual_um"] is not None for step in steps)
        predicted = sum(step["predicted_x_um"] is not None for step in steps)
        assert measured > 10
    with make_run(data, tmp_path / "second.log") as (address, _):
        page = new_page(browser)
        page.goto(address)
        page.wait_for_selector("#stream-state.open")
        page.wait_for_function(
            f"window.thermocomp.plots.residual && "
            f"window.thermocomp.plots.residual.data[0].length === {measured}",
            timeout=30_000,
        )
        assert page.evaluate("window.thermocomp.plots.predicted.data[0].length") == predicted
        assert "plots: run 1 (finished)" in (page.text_content("#shown-run") or "")
        row = page.locator("#run-history tr.shown td")
        assert row.nth(0).text_content() == "1"
        assert row.nth(2).text_content() == "two-link: stationary, thesis-two-link"
        assert row.nth(3).text_content() == "absolute"
        # the headline of an ended run: what it removed, not "so far"
        page.wait_for_selector("#removed-text:has-text('Largest error')")
        assert "so far" not in (page.text_content("#removed-text") or "")
