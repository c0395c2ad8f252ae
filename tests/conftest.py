"""Suite-wide fixtures: every test leaves no asyncio task running behind it and writes nothing
in the repository tree (its files go to its temporary directory)."""

from __future__ import annotations

import asyncio
import os
import shutil
import tempfile
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from tests.tree_guard import TreeWatch, describe, unwatched_runtime_dirs

REPO_ROOT = Path(__file__).resolve().parent.parent

#: A test slower than this (s, setup and teardown included) belongs under @pytest.mark.slow:
#: `make test-fast` leaves those out and must stay within a few minutes on 2 cores.
SLOW_S = 5.0
#: The timeout of a slow test (pytest-timeout; the others keep pyproject's 120 s): a minute
#: of work on an idle machine takes several on a loaded one.
SLOW_TIMEOUT_S = 600.0

_HYPOTHESIS_HOME = pytest.StashKey[str]()
#: Each process's watch of the tree: a test's (each xdist worker's), and the session's (the
#: controller's, or the only process), which a write no test was blamed for still fails.
_TEST_WATCH = pytest.StashKey[TreeWatch]()
_SESSION_WATCH = pytest.StashKey[TreeWatch]()
#: The user property a test that wrote in the tree carries: its paths, to the controller.
TREE_CREATED = "tree_created"


def pytest_configure(config: pytest.Config) -> None:
    """Hypothesis keeps its example database and constants cache under the working directory
    (.hypothesis/): send them to a temporary folder of the session instead."""
    home = tempfile.mkdtemp(prefix="thermocomp-hypothesis-")
    config.stash[_HYPOTHESIS_HOME] = home
    os.environ["HYPOTHESIS_STORAGE_DIRECTORY"] = home
    # The daemons the suite starts (servers and CLI runs in subprocesses; in-process ones get it
    # from tests.fakes.make_settings) ask for no real-time scheduling: where the host grants it
    # (CI as root), dozens of daemons at SCHED_FIFO on two cores would preempt each other's
    # steps and the test clients waiting for them. What real-time scheduling does is tested
    # with explicit priorities (tests/test_control_loop.py, tests/test_realtime_priorities.py).
    os.environ.setdefault("THERMOCOMP_SCHEDULER__REALTIME_PRIORITY", "0")
    try:
        from hypothesis.configuration import set_hypothesis_home_dir
    except ImportError:  # the dev extra is not installed: nothing to redirect
        return
    set_hypothesis_home_dir(home)


def pytest_unconfigure(config: pytest.Config) -> None:
    home = config.stash.get(_HYPOTHESIS_HOME, None)
    if home is not None:
        shutil.rmtree(home, ignore_errors=True)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A slow test without its own timeout gets SLOW_TIMEOUT_S."""
    for item in items:
        if item.get_closest_marker("slow") and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))


_seconds: dict[str, float] = {}  # each test's setup + call + teardown this session
_marked_slow: set[str] = set()
_blamed: set[str] = set()  # the paths a test was failed for creating in the tree


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _seconds[report.nodeid] = _seconds.get(report.nodeid, 0.0) + report.duration
    if "slow" in report.keywords:
        _marked_slow.add(report.nodeid)
    for name, value in report.user_properties:  # an xdist worker's, on the controller too
        if name == TREE_CREATED:
            _blamed.update(value)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Name the tests that took over SLOW_S without the slow marker (`make test-fast` runs
    them): mark them, or make them faster. A loaded machine inflates every figure: read
    them beside the load."""
    over = sorted(
        ((seconds, nodeid) for nodeid, seconds in _seconds.items() if nodeid not in _marked_slow),
        reverse=True,
    )
    over = [(seconds, nodeid) for seconds, nodeid in over if seconds > SLOW_S]
    if over:
        terminalreporter.write_sep("-", f"over {SLOW_S:g} s without @pytest.mark.slow")
        for seconds, nodeid in over:
            terminalreporter.write_line(f"{seconds:7.1f} s  {nodeid}")


def pytest_sessionstart(session: pytest.Session) -> None:
    """The tree as the session found it (a data/ or build/ already there is not watched:
    `make run` and `make docs` write there). Every xdist worker watches it for its own tests;
    the controller (or the only process) checks it again at the end."""
    skip = unwatched_runtime_dirs(REPO_ROOT)
    if not _is_xdist_worker(session.config):
        session.config.stash[_SESSION_WATCH] = TreeWatch(REPO_ROOT, skip)
    if not _is_xdist_controller(session.config):
        session.config.stash[_TEST_WATCH] = TreeWatch(REPO_ROOT, skip)


def _is_xdist_worker(config: pytest.Config) -> bool:
    """A process xdist started to run tests (not its environment: a test's own pytest
    subprocess inherits PYTEST_XDIST_WORKER)."""
    return hasattr(config, "workerinput")


def _is_xdist_controller(config: pytest.Config) -> bool:
    """The process that hands tests to xdist workers and runs none itself."""
    return config.pluginmanager.has_plugin("dsession")


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Whatever appeared in the tree and no test was failed for (a module fixture's teardown
    after the last test, a write another worker's test was not blamed for) fails the run."""
    watch = session.config.stash.get(_SESSION_WATCH, None)
    if watch is None:
        return
    created = [path for path in watch.created() if not _was_blamed(path)]
    if created:
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        line = f"the session created {describe(created)} (no test was failed for them)"
        if reporter is not None:
            reporter.write_line(f"ERROR {line}", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def _was_blamed(path: str) -> bool:
    return any(path == b or path.startswith(b + os.sep) for b in _blamed)


@pytest.fixture(autouse=True)
def stays_in_its_temporary_directory(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail a test that creates a file or folder in the repository tree: a test's files go to
    its tmp_path (a server on the checkout's data/ writes into the user's run database and
    fails while `make run` is up). The paths after one test are the next one's before."""
    watch = request.config.stash[_TEST_WATCH]
    watch.created()  # whatever a module fixture made before this test is not this test's
    yield
    created = watch.created()
    if created:
        request.node.user_properties.append((TREE_CREATED, created))
        beside = (
            " (or a test running at the same time on another xdist worker: the one that wrote"
            " them fails too)"
            if _is_xdist_worker(request.config)
            else ""
        )
        pytest.fail(
            f"the test created {describe(created)}{beside}: write to tmp_path (a server or CLI"
            " gets THERMOCOMP_STORAGE__DATA_DIR or --data-dir)",
            pytrace=False,
        )


@pytest.fixture(autouse=True)
async def fail_on_leaked_tasks() -> AsyncIterator[None]:
    """Fail a test that leaves tasks running (as ophyd-async does): a leaked task is a
    device loop or a reader that nobody will ever stop."""
    before = asyncio.all_tasks()
    yield
    for _ in range(3):  # let tasks that are just finishing finish
        await asyncio.sleep(0)
    current = asyncio.current_task()
    leaked = [t for t in asyncio.all_tasks() - before if t is not current and not t.done()]
    for task in leaked:
        task.cancel()
    if leaked:
        await asyncio.gather(*leaked, return_exceptions=True)
        pytest.fail(f"test left {len(leaked)} asyncio task(s) running: {leaked!r}")
