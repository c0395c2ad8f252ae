"""The suite's own rules (tests/conftest.py): what the repository guard sees."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import repository_paths, unwatched_runtime_dirs


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
