"""The dashboard in headless Debian Chromium (Playwright driving the system browser), against
the real ``thermocomp serve`` on the simulated bench: load, start a run, see the plots and the
camera view update, pause, resume, hold, stop, find it in the history; a refused token; the
run states and robot badges in the API's words (issue 21)."""

from __future__ import annotations

import itertools
import json
import math
import re
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser, Page, Route, sync_playwright

from daemon.arm.arm_model import ArmModel, arm_model_toml, saved_arm_models_dir
from daemon.run.states import RunState
from tests.helpers import running_server
from tests.loopback import loopback_host

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]
CONTROL = "dashboard-control-token-42"
#: steps the plots must show before the run is stopped
STEPS_SEEN = 15
#: The thesis two-link network's nodes (17), all plotted.
MODEL_NODES = 17
#: Smallest CIELAB distance (Delta E 1976) between any two series' colours: ~2.3 is a just
#: noticeable difference, ~20 tells thin lines apart at a glance. The greedy palette gives
#: 28.9 for the 20 series of the sim (17 nodes + 3 IR regions), 21 for 30.
MIN_COLOUR_DISTANCE = 20.0
FINAL_STATES = ("finished", "stopped", "aborted", "fault", "interrupted")


@pytest.fixture
def browser() -> Iterator[Browser]:
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture
def server(tmp_path: Path) -> Iterator[str]:
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path / "data"),
        # 20 bench seconds per second: a 1 s step every 50 ms, the plots move visibly
        "THERMOCOMP_BENCH__CLOCK": "accelerated",
        "THERMOCOMP_BENCH__TIME_FACTOR": "20",
    }
    with running_server(["--config", "config/sim.toml"], env=env) as base_url:
        yield base_url


def points(page: Page, plot: str) -> int:
    count: int = page.evaluate(f"window.thermocomp.plots.{plot}.data[0].length")
    return count


def message(page: Page) -> str:
    return page.text_content("#message") or ""


def new_page(browser: Browser) -> Page:
    """A page whose test code may wait on JavaScript expressions: Playwright evaluates them
    with eval, which the server's Content-Security-Policy refuses, so these pages bypass it
    (test_the_dashboard_runs_under_its_own_csp checks the page itself needs no exception)."""
    return browser.new_page(viewport={"width": 1400, "height": 1000}, bypass_csp=True)


def open_dashboard(browser: Browser, server: str) -> tuple[Page, list[str]]:
    page = new_page(browser)
    page_errors: list[str] = []
    page.on("pageerror", lambda error: page_errors.append(str(error)))
    page.goto(server + "/")
    page.wait_for_selector("#stream-state.open")
    # the state comes with the stream's hello and the network list from its own request:
    # both arrive after the socket opens, so wait for them rather than read them at once
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'idle'")
    return page, page_errors


def start_run(page: Page) -> None:
    page.fill("#token", CONTROL)
    page.click("#token-form button")
    page.wait_for_selector("#stream-state.open")
    page.fill("input[name=duration_s]", "3600")
    page.fill("input[name=step_s]", "1")
    page.click("#btn-start")
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'running'")
    page.wait_for_function(
        f"window.thermocomp.plots.residual.data[0].length >= {STEPS_SEEN}", timeout=60_000
    )


def _lab(colour: str) -> tuple[float, float, float]:
    """CIELAB (D65) of a #rrggbb colour."""

    def linear(c: int) -> float:
        v = c / 255
        return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4

    r, g, b = (linear(int(colour[i : i + 2], 16)) for i in (1, 3, 5))
    x = (0.4124 * r + 0.3576 * g + 0.1805 * b) / 0.95047
    y = 0.2126 * r + 0.7152 * g + 0.0722 * b
    z = (0.0193 * r + 0.1192 * g + 0.9505 * b) / 1.08883

    def f(t: float) -> float:
        return t ** (1 / 3) if t > 0.008856 else 7.787 * t + 16 / 116

    return 116 * f(y) - 16, 500 * (f(x) - f(y)), 200 * (f(y) - f(z))


@pytest.mark.slow
def test_dashboard_drives_a_live_run(browser: Browser, server: str, tmp_path: Path) -> None:
    page, page_errors = open_dashboard(browser, server)
    preset = page.locator("#network-select option[value='thesis-two-link']")
    preset.wait_for(state="attached")
    assert preset.count() == 1
    # the device states of /health, as badges
    page.locator("#device-badges .badge", has_text="robot: connected").wait_for()

    # without a token, control is refused and the page says so, in the API's words
    page.fill("input[name=duration_s]", "3600")
    page.click("#btn-start")
    page.wait_for_selector("#message.error")
    assert "401" in message(page) and "control scope is needed" in message(page)

    start_run(page)
    for plot in ("predicted", "offset", "residual", "temperature"):
        assert points(page, plot) >= STEPS_SEEN
    # the plotted values are the recorded ones: the predicted deformation grows under heat
    predicted_x = page.evaluate("window.thermocomp.plots.predicted.data[1]")
    assert predicted_x[-1] > predicted_x[1] > 0

    # every model node is plotted, in natural order, each series in a colour of its own
    names: list[str] = page.evaluate("window.thermocomp.plots.temperature.names")
    nodes = [n for n in names if n.startswith("node ")]
    assert len(nodes) == MODEL_NODES
    assert nodes == [f"node {i}" for i in range(1, MODEL_NODES + 1)]  # node 2 before node 16
    legend = page.locator("#plot-temperature .u-legend .u-label").all_text_contents()
    assert legend == names  # what the reader sees, in that order
    drawn: list[str] = page.evaluate(
        "window.thermocomp.plots.temperature.plot.series.slice(1).map((s, i) =>"
        " typeof s.stroke === 'function' ? s.stroke(window.thermocomp.plots.temperature.plot,"
        " i + 1) : s.stroke)"
    )
    assert len(set(drawn)) == len(drawn) == len(names)
    closest = min(math.dist(_lab(a), _lab(b)) for a, b in itertools.combinations(drawn, 2))
    assert closest >= MIN_COLOUR_DISTANCE, closest

    # the camera view: a zoom around the spot, contrast-stretched, and the full frame on click
    page.wait_for_function(
        "document.querySelector('#frame-caption').textContent.includes('centroid (')",
        timeout=30_000,
    )
    canvas = page.locator("#frame-canvas")
    assert canvas.get_attribute("data-view") == "zoom"
    low, high = (int(v) for v in (canvas.get_attribute("data-contrast") or "").split("-"))
    assert high > low
    assert "frame px at full resolution" in (page.text_content("#frame-detail") or "")
    canvas.click()
    page.wait_for_selector("#frame-canvas[data-view='full']")
    assert "full frame, reduced 1:4 (188 x 145 px)" in (page.text_content("#frame-detail") or "")
    canvas.click()
    page.wait_for_selector("#frame-canvas[data-view='zoom']")
    page.screenshot(path=str(tmp_path / "dashboard-live.png"), full_page=True)

    # each action answers with what happened
    with page.expect_response(re.compile(r".*/runs/1/pause$")) as answer:
        page.click("#btn-pause")
    page.wait_for_function("document.querySelector('#message').textContent.includes('paused')")
    paused = re.fullmatch(r"run 1 paused at step (\d+)", message(page))
    assert paused, message(page)
    run = httpx.get(f"{server}/api/v1/runs/1", timeout=10).json()
    # the last step the page knew of: at least the answer's, at most the last one recorded
    # (a step under way when the pause came is still recorded)
    said = int(paused.group(1))
    assert answer.value.json()["steps_recorded"] - 1 <= said <= run["steps_recorded"] - 1
    assert run["state"] == "paused"
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'paused'")
    page.click("#btn-resume")
    page.wait_for_function("document.querySelector('#message').textContent.includes('resumed')")
    assert re.fullmatch(r"run 1 resumed at step \d+", message(page)), message(page)
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'running'")

    # hold: the answer says what it means, and the badge shows it
    assert page.locator("#robot-badges .badge.held").count() == 0
    page.click("#btn-hold")
    page.wait_for_selector("#robot-badges .badge.held")
    assert page.text_content("#robot-badges .badge.held") == "robot held"
    # the badge comes from the state event, the message from the hold's answer: either may
    # land first (CI saw the badge while the message still said "resumed")
    page.wait_for_function(
        "document.querySelector('#message').textContent.startsWith('hold acknowledged')"
    )
    assert message(page).startswith("hold acknowledged: no motion can be sent"), message(page)

    # a refused action answers with the API's error message, not a bare status. Pause is
    # disabled while paused, so the test enables it and clicks it in one task of the page:
    # enabled and then clicked apart, the page's own refreshes still in flight after the hold
    # (its answer's, the state event's, the 3 s poll's) disabled it again in between, and the
    # click did nothing (no request, no message: a 30 s wait for #message.error under load)
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'paused'")
    with page.expect_response(re.compile(r".*/runs/1/pause$")) as refused:
        page.evaluate(
            "() => { const pause = document.querySelector('#btn-pause');"
            " pause.disabled = false; pause.click(); }"
        )
    assert refused.value.status == 409
    page.wait_for_selector("#message.error")
    assert message(page).startswith("pause refused: 409 conflict: "), message(page)

    page.click("#btn-stop")
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'idle'")
    run = httpx.get(f"{server}/api/v1/runs/1", timeout=10).json()
    assert run["state"] == "stopped" and run["reason"] == "stopped by request"
    assert run["steps_recorded"] >= STEPS_SEEN
    assert message(page).startswith(f"run 1 {run['state']} after {run['steps_recorded']} steps")
    # the history shows the API's word for the stopped run, its reason on hover and on click
    word = page.locator("#run-history tr:first-child .state")
    word.wait_for()
    page.wait_for_function(
        f"document.querySelector('#run-history tr:first-child .state').textContent"
        f" === {json.dumps(run['state'])}"
    )
    assert run["state"] in (word.get_attribute("class") or "").split()
    if run["reason"]:
        assert run["reason"] in (word.get_attribute("title") or "")
    word.click()
    assert message(page).startswith(f"run 1 {run['state']}: ")
    # no reference run was named: the figure is labelled relative to the model (issue 19)
    relative = run["summary"]["reduction_vs_prediction_percent"]
    cells = page.locator("#run-history tr:first-child td")
    expected = f"{relative:.1f} % vs model" if relative >= 0 else "none: error above model"
    assert cells.nth(8).text_content() == expected
    # the row says what the run was, besides its state and reason
    assert cells.nth(2).text_content() == "two-link: stationary, thesis-two-link"
    assert cells.nth(3).text_content() == "absolute"
    assert page_errors == []


@pytest.mark.slow
def test_a_refused_token_shows_a_banner_and_the_plots_go_on(browser: Browser, server: str) -> None:
    page, page_errors = open_dashboard(browser, server)
    start_run(page)
    assert page.is_hidden("#auth-banner")
    before = points(page, "residual")

    page.fill("#token", "not-the-token")
    page.click("#token-form button")
    page.wait_for_selector("#auth-banner", state="visible")
    banner = page.text_content("#auth-banner") or ""
    assert "The token was refused (401 unauthorized: unknown token)" in banner
    assert "keep what they show" in banner
    # nothing was cleared, and the plots go on (anonymous reading on loopback) while the
    # banner stays until a valid token is entered
    assert points(page, "residual") >= before
    page.wait_for_function(
        f"window.thermocomp.plots.residual.data[0].length >= {before + 10}", timeout=60_000
    )
    assert page.is_visible("#auth-banner")
    # control with the refused token: the API's answer, in the message line
    page.click("#btn-pause")
    page.wait_for_selector("#message.error")
    assert "pause refused: 401 unauthorized: unknown token" in message(page)

    page.fill("#token", CONTROL)
    page.click("#token-form button")
    page.wait_for_selector("#auth-banner", state="hidden")
    page.click("#btn-stop")
    page.wait_for_function("document.querySelector('#daemon-state').textContent === 'idle'")
    assert page_errors == []


def _run(run_id: int, state: str, reason: str | None) -> dict[str, Any]:
    base = f"/api/v1/runs/{run_id}"
    return {
        "id": run_id,
        "state": state,
        "reason": reason,
        "started_at": 1_790_000_000.0 + run_id,
        "ended_at": 1_790_000_100.0 + run_id,
        "parameters": {"duration_s": 100.0, "step_s": 1.0},
        "steps_recorded": 10 * run_id,
        "progress_percent": 100.0,
        "remaining_s": 0.0,
        "eta_s": 0.0,
        "summary": None,
        "links": {"self": base, "steps_csv": f"{base}/steps?format=csv", "report": base},
    }


@pytest.mark.slow
def test_run_states_and_robot_badges_in_the_apis_words(browser: Browser, server: str) -> None:
    """Every final state the API may give (the lead adds `stopped`), and the robot and device
    states: the page shows the API's answers as they are, so these are served to it."""
    runs = [
        _run(i, state, None if state == "finished" else f"why {state}")
        for i, state in enumerate(FINAL_STATES, start=1)
    ]
    page = new_page(browser)

    def fulfil(body: dict[str, Any]) -> Any:
        return lambda route: route.fulfill(
            status=200, content_type="application/json", body=json.dumps(body)
        )

    page.route(
        re.compile(r".*/api/v1/runs\?limit=20$"),
        fulfil({"runs": runs[::-1], "limit": 20, "offset": 0, "next_offset": None}),
    )

    def state(route: Route) -> None:
        real = httpx.get(f"{server}/api/v1/state", timeout=10).json()
        real["robot"] = {
            "link": "awaiting-point-of-control",
            "motion_held": True,
            "last_error": None,
        }
        route.fulfill(status=200, content_type="application/json", body=json.dumps(real))

    page.route(re.compile(r".*/api/v1/state$"), state)
    page.route(
        re.compile(r".*/api/v1/health$"),
        fulfil(
            {
                "status": "ok",
                "version": "0",
                "daemon": "running",
                "devices": {
                    "robot": "awaiting-point-of-control",
                    "camera": "ok",
                    "ir": "timeout error",
                },
            }
        ),
    )
    page.goto(server + "/")
    page.wait_for_selector("#run-history tr:nth-child(5) .state")
    for run in runs:
        cell = page.locator(f"#run-history tr:has(td:text-is('{run['id']}')) .state")
        assert cell.text_content() == run["state"]
        assert run["state"] in (cell.get_attribute("class") or "").split()
        title = cell.get_attribute("title") or ""
        assert (run["reason"] or "no reason given") in title
        cell.click()
        reason = run["reason"] or "no reason given"
        assert message(page) == f"run {run['id']} {run['state']}: {reason}"

    page.wait_for_selector("#robot-badges .badge.waiting")
    assert page.text_content("#robot-badges .badge.waiting") == (
        "waiting for the operator: press PAUSE/CONTINUE"
    )
    assert page.text_content("#robot-badges .badge.held") == "robot held"
    page.wait_for_selector("#device-badges .badge")
    kinds = {
        page.text_content(f"#device-badges .badge.{kind}") or "": kind
        for kind in ("good", "warn", "bad")
    }
    assert kinds == {
        "camera: ok": "good",
        "robot: awaiting-point-of-control": "warn",
        "ir: timeout error": "bad",
    }


@pytest.mark.slow
def test_a_move_refused_by_a_hold_is_not_counted_as_an_error(browser: Browser, server: str) -> None:
    """After Stop or Hold, a step in flight has its move refused by the held permit
    (kind "motion-held", the request's reason): the hold doing its job. The errors panel lists
    it greyed with why, and counts it apart, so that "Errors (none)" still means nothing went
    wrong; a hold for any other reason (a lost link) stays an error."""
    page = new_page(browser)
    held = {
        "time": 1.0e9,
        "device": "robot",
        "kind": "motion-held",
        "message": "robot: motion is held until resume(): stopped by request",
    }
    stale = {
        "time": 1.0e9 + 1,
        "device": "camera",
        "kind": "device",
        "message": "camera: stale frame: 2.2 s old",
    }

    def state(errors: list[dict[str, Any]]) -> Any:
        def answer(route: Route) -> None:
            real = httpx.get(f"{server}/api/v1/state", timeout=10).json()
            real["errors"] = errors
            route.fulfill(status=200, content_type="application/json", body=json.dumps(real))

        return answer

    page.route(re.compile(r".*/api/v1/state$"), state([held]))
    page.goto(server + "/")
    page.wait_for_selector("#error-list li.expected")
    assert page.text_content("#error-count") == "(none) · 1 move refused by a hold"
    assert "expected: the robot was held" in (page.text_content("#error-list li") or "")
    page.unroute(re.compile(r".*/api/v1/state$"))
    # a hold nobody asked for (the UR's link lost) is an error, whatever its kind
    lost = {**held, "time": 1.0e9 + 2}
    lost["message"] = "robot: motion is held until resume(): link lost: no RTDE package for 1.0 s"
    page.route(re.compile(r".*/api/v1/state$"), state([held, lost, stale]))
    page.reload()
    page.wait_for_selector("#error-list li:not(.expected)")
    assert page.text_content("#error-count") == "(2) · 1 move refused by a hold"
    assert page.locator("#error-list li:not(.expected)").count() == 2
    assert page.text_content("#error-list li:first-child") == (
        f"{page.evaluate('new Date(1e12 + 1000).toLocaleTimeString()')} camera device: "
        "camera: stale frame: 2.2 s old"
    )
    assert "link lost" in (page.text_content("#error-list li:nth-child(2)") or "")


@pytest.mark.slow
def test_the_dashboard_runs_under_its_own_csp(browser: Browser, server: str) -> None:
    """With the Content-Security-Policy enforced (no eval-based waits here: selectors only),
    the page loads its scripts and styles, opens the stream, shows the daemon's state and the
    device preview, and the browser reports no violation."""
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    violations: list[str] = []
    page.on(
        "console",
        lambda m: violations.append(m.text) if "Content Security Policy" in m.text else None,
    )
    page.on("pageerror", lambda error: violations.append(str(error)))
    answer = page.goto(server + "/")
    assert answer is not None and "default-src 'self'" in answer.headers["content-security-policy"]
    page.wait_for_selector("#stream-state.open")
    page.wait_for_selector("#daemon-state:text-is('idle')")
    # a first start: no empty plots, but what to do
    page.wait_for_selector("#no-run:has-text('No run yet')")
    # the bring-up preview while idle (issue 18): the daemon's own devices, as a picture
    page.click("#btn-preview")
    page.wait_for_selector("#preview-dialog[open] #preview-image:not([hidden])")
    page.wait_for_selector("#preview-caption:has-text('spot at')")
    assert page.locator("#preview-image").evaluate("image => image.naturalWidth") > 0
    assert violations == []
    page.close()


@pytest.mark.slow
def test_the_api_description_runs_under_its_own_csp(browser: Browser, server: str) -> None:
    """/docs (the vendored Swagger UI, started by a script file: no inline script) renders the
    description with the CSP enforced and no violation."""
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    violations: list[str] = []
    page.on(
        "console",
        lambda m: violations.append(m.text) if "Content Security Policy" in m.text else None,
    )
    page.on("pageerror", lambda error: violations.append(str(error)))
    answer = page.goto(server + "/docs")
    assert (
        answer is not None and "frame-ancestors 'none'" in answer.headers["content-security-policy"]
    )
    page.wait_for_selector(".swagger-ui .info .title")
    assert violations == []
    page.close()


@pytest.mark.slow
@pytest.mark.timeout(300)  # an arm run renders 5 MP frames: minutes on a busy 2-core machine
def test_an_arm_run_plots_the_3d_drift_and_the_rotation_error(
    browser: Browser, tmp_path: Path
) -> None:
    """Issue 20: on the arm bench the run form offers the saved arm models (GET /arm-models)
    and a run started with one uses it; an arm run's steps draw the tool's 3-D drift and
    rotation error (norm and components), and its history row gives the 3-D figures. With
    arm.adapt (issue 29) the adapted factors of the latest step are shown, each with its
    1-sigma, as the step recorded them."""
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path / "data"),
        "THERMOCOMP_ARM__ADAPT": "true",
    }
    folder = saved_arm_models_dir(tmp_path / "data")
    folder.mkdir(parents=True)
    model = ArmModel(name="cal", arm="CRS A465", heat_scales=(1.0, 0.84, 0.85, 1.0, 1.0, 1.0))
    (folder / "cal.toml").write_text(arm_model_toml(replace(model, source_runs=("run 7",))))
    steps = 12  # config/arm-sim.toml: 120 s at a 10 s step
    with running_server(["--config", "config/arm-sim.toml"], env=env) as server:
        page, page_errors = open_dashboard(browser, server)
        # an arm daemon's page from the start: its fields, none of the two-link's, and the
        # 3-D drift and rotation at the top
        page.wait_for_selector("#run-kind:text-is('Start an arm run')")
        for field in ("duty_cycle", "arm_model"):
            assert page.locator(f"#start-form [name={field}]").is_visible()
        for field in ("procedure", "network", "deformation_scale", "heater_off_s"):
            assert page.locator(f"#start-form [name={field}]").is_hidden()
        assert page.locator("#slot-residual").is_hidden()
        slots = page.evaluate(
            "[...document.querySelectorAll('#plots .plot')].filter(e => !e.hidden).map(e => e.id)"
        )
        assert slots[:2] == ["slot-drift3d", "slot-rotation"]
        offered = page.locator("#arm-model-select option", has_text="cal (identified from run 7)")
        offered.wait_for(state="attached")
        assert page.locator("#arm-model-field").is_visible()
        page.select_option("#arm-model-select", "cal")
        page.fill("#token", CONTROL)
        page.click("#token-form button")
        page.wait_for_selector("#stream-state.open")
        page.fill("input[name=duration_s]", "120")
        page.fill("input[name=step_s]", "10")
        page.click("#btn-start")
        page.wait_for_selector("#message:has-text('run 1 ')")
        run = httpx.get(f"{server}/api/v1/runs/1", timeout=10).json()
        assert run["parameters"]["arm_model"] == "cal"
        # the run's end, then every measured step drawn (under load a step's frame may come
        # too late and the step records no measurement: the plots draw the measured ones)
        deadline = time.monotonic() + 180.0
        while not RunState(
            httpx.get(f"{server}/api/v1/runs/1", timeout=10).json()["state"]
        ).is_terminal:
            assert time.monotonic() < deadline, "the arm run did not end"
            time.sleep(0.5)
        steps_json = httpx.get(f"{server}/api/v1/runs/1/steps?format=json", timeout=10).json()
        recorded = steps_json["steps"]
        assert len(recorded) == steps
        measured = [s for s in recorded if s["drift_3d_um"] is not None]
        assert len(measured) >= steps // 2, "most steps measured the tool"
        page.wait_for_function(
            f"window.thermocomp.plots.drift3d && "
            f"window.thermocomp.plots.drift3d.data[0].length >= {len(measured)}",
            timeout=120_000,
        )
        assert page.locator("#slot-drift3d").is_visible()
        assert page.locator("#slot-rotation").is_visible()
        # one series per measured pose: each pose's points on its own line, none between
        names = page.evaluate("window.thermocomp.plots.drift3d.names")
        poses = list(dict.fromkeys(step["arm_pose"] for step in recorded))
        assert names == poses and len(poses) >= 2
        hours, *columns = page.evaluate("window.thermocomp.plots.drift3d.data")
        for pose, column in zip(poses, columns, strict=True):
            mine = [s for s in measured if s["arm_pose"] == pose]
            drawn = [(h, v) for h, v in zip(hours, column, strict=True) if v is not None]
            assert drawn == [(s["model_time_s"] / 3600, s["drift_3d_um"]) for s in mine]
        rotation = page.evaluate("window.thermocomp.plots.rotation.data")
        assert sum(v is not None for column in rotation[1:] for v in column) == len(measured)
        # every tool camera's view, its markers crossed (the camera panel was black)
        lit = page.locator("#camera-grid .camera-tile:not([data-markers='0'])")
        lit.first.wait_for(timeout=60_000)
        assert "markers seen" in (lit.first.text_content() or "")
        # the temperatures grouped per link and joint (~70 model nodes), the legend folded
        groups = page.evaluate("window.thermocomp.plots.temperature.names")
        assert "upper-arm" in groups and "forearm" in groups and len(groups) <= 16
        assert page.locator("#slot-temperature details.legend:not([open])").count() == 1
        # the adaptation's estimates of the latest step that has them, each +- its 1-sigma
        adapted = [s for s in recorded if s.get("observer_json")]
        assert adapted, "arm.adapt recorded no estimates"
        latest = json.loads(adapted[-1]["observer_json"])
        page.wait_for_selector("#adaptation:not([hidden])")
        page.wait_for_selector(f"#adaptation-step:text-is('step {adapted[-1]['step']}')")
        shown = page.evaluate(
            "[...document.querySelectorAll('#adaptation-rows tr')].map(r => "
            "[r.dataset.name, r.querySelector('.value').textContent, "
            "r.querySelector('.sigma').textContent])"
        )
        assert sorted(name for name, _, _ in shown) == sorted(latest)
        assert {"heat:2", "alpha", "convection", "share"} <= set(latest)
        for name, value, sigma in shown:
            estimate, one_sigma = latest[name]
            assert sigma.startswith("± ")
            decimals = len(value.partition(".")[2])  # as many as the 1-sigma needs, 2 to 4
            assert 2 <= decimals <= 4 and len(sigma.partition(".")[2]) == decimals
            rounding = 0.5 * 10.0**-decimals + 1e-9
            assert float(value) == pytest.approx(estimate, abs=rounding)
            assert float(sigma[2:]) == pytest.approx(one_sigma, abs=rounding)
        # the history row of the ended run states its 3-D drift and rotation error
        page.locator("#run-history tr td", has_text="3-D").first.wait_for(timeout=60_000)
        # the start's message does not outlive the run: it ended by itself, and says so
        page.wait_for_selector(f"#message:text-is('run 1 finished after {steps} steps')")
        assert not page_errors


@pytest.mark.slow
def test_a_followed_ur_says_it_has_no_camera_and_no_rotation(browser: Browser) -> None:
    """A UR followed by its joint temperatures alone (config/ur5e-sim.toml without its tool
    cameras, the UR emulator on a loopback address of this test's own): the device badges say
    the camera and the IR reader are none (grey, not green), the camera panel says the tool is
    not watched, and the 3-D drift (the bench's truth) is plotted. (A followed run's rotation
    is the tool cameras', at the program's dwells: none here, its plot stays empty.)"""
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
        "THERMOCOMP_ROBOT__HOST": loopback_host(),  # UR's fixed ports, on an address of its own
        "THERMOCOMP_ARM__BENCH_CAMERAS": "false",
    }
    with running_server(["--config", "config/ur5e-sim.toml"], env=env) as base:
        started = httpx.post(
            f"{base}/api/v1/runs",
            json={"duration_s": 600},
            headers={"Authorization": f"Bearer {CONTROL}"},
            timeout=30,
        )
        assert started.status_code == 201, started.text
        page = new_page(browser)
        page.goto(base + "/")
        page.wait_for_selector("#device-badges .badge")
        page.wait_for_function(  # the health's devices in (the badges' first fill)
            "[...document.querySelectorAll('#device-badges .badge')]"
            ".some(b => b.textContent === 'camera: none')",
            timeout=60_000,
        )
        badges = {
            page.text_content(f"#device-badges .badge:nth-child({i})") or "" for i in (1, 2, 3)
        }
        assert {"camera: none", "ir: none"} <= badges, badges
        assert (
            page.locator("#device-badges .badge.device.good:text-is('camera: none')").count() == 0
        )
        assert "no camera" in (page.text_content("#frame-caption") or "")
        # the 3-D drift (the bench's truth) is plotted all the same
        page.wait_for_function(
            "(window.thermocomp.plots.drift3d.data[0] || []).length > 0", timeout=60_000
        )
        httpx.post(
            f"{base}/api/v1/runs/{started.json()['id']}/stop",
            headers={"Authorization": f"Bearer {CONTROL}"},
            timeout=30,
        )
