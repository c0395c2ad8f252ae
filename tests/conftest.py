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

REPO_ROOT = Path(__file__).resolve().parent.parent

#: Never looked in: version control, the environment and the tools' caches.
UNWATCHED_DIRS = frozenset(
    {".git", ".venv", "__pycache__", ".mypy_cache", ".ruff_cache", ".pytest_cache"}
)
#: Editors' working files: a developer editing during a run is not a test writing.
EDITOR_SUFFIXES = (".swp", ".swx", "~")
#: The runtime folders a developer's own daemon may be writing to while the suite runs
#: (config/*.toml's storage.data_dir, the docs build): watched only when the session started
#: without them, so that a test creating one fails, but `make run` beside the suite does not.
RUNTIME_DIRS = ("data", "build")

#: A test slower than this (s, setup and teardown included) belongs under @pytest.mark.slow:
#: `make test-fast` leaves those out and must stay within a few minutes on 2 cores.
SLOW_S = 5.0
#: The timeout of a slow test (pytest-timeout; the others keep pyproject's 120 s): a minute
#: of work on an idle machine takes several on a loaded one.
SLOW_TIMEOUT_S = 600.0

_watch: dict[str, frozenset[str]] = {}
_HYPOTHESIS_HOME = pytest.StashKey[str]()


def unwatched_runtime_dirs(root: Path = REPO_ROOT) -> tuple[str, ...]:
    return tuple(
        entry.name
        for entry in os.scandir(root)
        if entry.is_dir() and entry.name.startswith(RUNTIME_DIRS)
    )


def repository_paths(skip_top: tuple[str, ...] = (), root: Path = REPO_ROOT) -> frozenset[str]:
    """Every file and folder in the repository tree (relative), but the unwatched ones."""
    paths: set[str] = set()
    for folder, dirs, files in os.walk(root):
        relative = os.path.relpath(folder, root)
        at_top = relative == "."
        dirs[:] = [d for d in dirs if d not in UNWATCHED_DIRS and not (at_top and d in skip_top)]
        prefix = "" if at_top else relative + os.sep
        paths.update(prefix + name for name in dirs)
        paths.update(prefix + name for name in files if not name.endswith(EDITOR_SUFFIXES))
    return frozenset(paths)


def pytest_configure(config: pytest.Config) -> None:
    """Hypothesis keeps its example database and constants cache under the working directory
    (.hypothesis/): send them to a temporary folder of the session instead."""
    home = tempfile.mkdtemp(prefix="thermocomp-hypothesis-")
    config.stash[_HYPOTHESIS_HOME] = home
    os.environ["HYPOTHESIS_STORAGE_DIRECTORY"] = home
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


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _seconds[report.nodeid] = _seconds.get(report.nodeid, 0.0) + report.duration
    if "slow" in report.keywords:
        _marked_slow.add(report.nodeid)


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


@pytest.fixture(autouse=True)
def stays_in_its_temporary_directory() -> Iterator[None]:
    """Fail a test that creates a file or folder in the repository tree: a test's files go to
    its tmp_path (a server on the checkout's data/ writes into the user's run database and
    fails while `make run` is up). The paths after one test are the next one's before."""
    if "skip" not in _watch:
        _watch["skip"] = frozenset(unwatched_runtime_dirs())
    skip = tuple(_watch["skip"])
    before = _watch.get("paths") or repository_paths(skip)
    yield
    after = repository_paths(skip)
    _watch["paths"] = after
    created = sorted(after - before)
    if created:
        shown = ", ".join(created[:8]) + (
            f" and {len(created) - 8} more" if len(created) > 8 else ""
        )
        pytest.fail(
            f"the test created {len(created)} path(s) in the repository tree: {shown} "
            "(write to tmp_path; a server or CLI gets THERMOCOMP_STORAGE__DATA_DIR or --data-dir)",
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
