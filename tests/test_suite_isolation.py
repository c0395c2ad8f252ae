"""The suite's own rules (tests/conftest.py, tests/tree_guard.py): what the repository guard
sees, and that a test writing into the checkout fails, alone and under xdist."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.helpers import REPO_ROOT
from tests.tree_guard import TreeWatch, repository_paths, unwatched_runtime_dirs


def test_the_guard_sees_a_new_file_anywhere_but_caches_and_editor_files(tmp_path: Path) -> None:
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "sim.toml").write_text("")
    before = repository_paths(root=tmp_path)
    (tmp_path / "config" / "written.toml").write_text("")
    (tmp_path / "data" / "reports").mkdir(parents=True)
    (tmp_path / "config" / "__pycache__").mkdir()
    (tmp_path / "config" / "__pycache__" / "x.pyc").write_text("")
    (tmp_path / ".venv").mkdir()
    (tmp_path / "config" / ".sim.toml.swp").write_text("")
    created = repository_paths(root=tmp_path) - before
    assert created == {"config/written.toml", "data", "data/reports"}


def test_a_runtime_folder_there_before_the_session_is_not_watched(tmp_path: Path) -> None:
    """`make run` beside the suite writes into data/: the guard leaves a data/ that existed
    when the session started alone, and fails a test that creates one."""
    (tmp_path / "data-arm").mkdir()
    (tmp_path / "docs").mkdir()
    skip = unwatched_runtime_dirs(tmp_path)
    assert skip == ("data-arm",)
    before = repository_paths(skip, root=tmp_path)
    (tmp_path / "data-arm" / "thermocomp.sqlite3").write_text("")
    (tmp_path / "data").mkdir()
    assert repository_paths(skip, root=tmp_path) - before == {"data"}


def test_the_watch_walks_only_when_a_folder_changed(tmp_path: Path) -> None:
    """The cheap path: nothing changed, no walk (stat calls only); a file created deep down,
    or a folder with files in it, is named once, by the first call after it appeared."""
    (tmp_path / "daemon" / "run").mkdir(parents=True)
    (tmp_path / "data").mkdir()
    watch = TreeWatch(tmp_path, skip_top=("data",))
    walks = watch.walks
    assert watch.created() == []
    (tmp_path / "data" / "run.sqlite3").write_text("")  # the unwatched runtime folder
    assert watch.created() == []
    assert watch.walks == walks
    (tmp_path / "daemon" / "run" / "x.json").write_text("")
    (tmp_path / "reports" / "a").mkdir(parents=True)
    (tmp_path / "reports" / "a" / "b.html").write_text("")
    assert watch.created() == ["daemon/run/x.json", "reports", "reports/a", "reports/a/b.html"]
    assert watch.created() == []
    (tmp_path / "reports" / "a" / "c.html").write_text("")  # in a folder that is new too
    assert watch.created() == ["reports/a/c.html"]
    (tmp_path / "daemon" / "run" / "x.json").unlink()
    assert watch.created() == []


def _inner_session(folder: Path, tests: str, *options: str) -> subprocess.CompletedProcess[str]:
    """A pytest session with the suite's own conftest, watching ``folder``/tree as its
    checkout (its own temporary files beside it, not in it)."""
    tree = folder / "tree"
    tree.mkdir()
    (tree / "conftest.py").write_text(
        textwrap.dedent(
            """
            from pathlib import Path

            import tests.conftest as suite

            suite.REPO_ROOT = Path(__file__).resolve().parent
            from tests.conftest import *  # noqa: E402,F403 - the suite's hooks and fixtures
            """
        )
    )
    (tree / "config").mkdir(exist_ok=True)
    (tree / "test_inner.py").write_text(textwrap.dedent(tests))
    command = [
        *(sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", str(tree)),
        *("-p", "xdist.plugin", "-p", "pytest_asyncio.plugin", "-o", "asyncio_mode=auto"),
        *("-o", "asyncio_default_fixture_loop_scope=function"),
        *("--basetemp", str(folder / "basetemp"), *options, str(tree)),
    ]
    return subprocess.run(
        command,
        cwd=tree,
        env={
            **os.environ,
            "PYTHONPATH": str(REPO_ROOT),
            "PYTHONDONTWRITEBYTECODE": "1",
            # the plugins the guard needs only: the others' imports took seconds a session
            "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1",
        },
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


WRITER_AND_BYSTANDER = """
    from pathlib import Path

    def test_writes_into_the_checkout():
        (Path(__file__).parent / "config" / "written.toml").write_text("")

    def test_writes_in_its_tmp_path(tmp_path):
        (tmp_path / "fine.toml").write_text("")
"""


XDIST = pytest.param(["-n", "2"], id="xdist -n 2", marks=pytest.mark.slow)  # 3 processes


@pytest.mark.parametrize("workers", [pytest.param([], id="one process"), XDIST])
def test_a_test_writing_into_the_checkout_fails(tmp_path: Path, workers: list[str]) -> None:
    result = _inner_session(tmp_path, WRITER_AND_BYSTANDER, *workers)
    output = result.stdout + result.stderr
    assert result.returncode == 1, output
    assert "ERROR test_inner.py::test_writes_into_the_checkout" in output, output
    assert "the test created 1 path(s) in the repository tree: config/written.toml" in output
    assert "the session created" not in output  # blamed on the test, not again on the run


def test_a_write_no_test_is_blamed_for_still_fails_the_run(tmp_path: Path) -> None:
    """A module fixture's teardown after the module's last test writes outside every test's
    watch: the session's own check at the end fails the run, though every test passed."""
    result = _inner_session(
        tmp_path,
        """
        from pathlib import Path

        import pytest

        @pytest.fixture(scope="module")
        def leaves_a_file():
            yield
            (Path(__file__).parent / "left.db").write_text("")

        def test_passes(leaves_a_file):
            pass
        """,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 1, output
    assert "1 passed" in output, output
    assert "the session created 1 path(s) in the repository tree: left.db" in output, output


@pytest.mark.slow  # three processes
def test_a_clean_session_passes(tmp_path: Path) -> None:
    """The inner session itself (its conftest, the interpreter's caches) is not a write."""
    result = _inner_session(tmp_path, "def test_nothing():\n    pass\n", "-n", "2")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.slow  # three processes
def test_the_timeouts_hold_under_xdist(tmp_path: Path) -> None:
    """pytest-timeout in a worker: a test over the default timeout is stopped and fails; a
    slow-marked one gets SLOW_TIMEOUT_S instead (tests/conftest.py), so it passes."""
    result = _inner_session(
        tmp_path,
        """
        import time

        import pytest

        def test_hangs():
            time.sleep(30)

        @pytest.mark.slow
        def test_slow_but_within_its_own_timeout():
            time.sleep(2)
        """,
        *("-p", "pytest_timeout", "-o", "timeout=1", "-o", "markers=slow: over ~5 s"),
        *("-n", "2"),
    )
    output = result.stdout + result.stderr
    assert result.returncode == 1, output
    assert "1 failed, 1 passed" in output, output
    assert "FAILED test_inner.py::test_hangs - Failed: Timeout" in output, output
