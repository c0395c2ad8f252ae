"""What the suite's "nothing written in the checkout" guard sees (tests/conftest.py).

A test's files go to its tmp_path: a server on the checkout's data/ writes into the user's run
database and fails while `make run` is up. Walking the whole tree after every test costs a few
milliseconds a test, a minute of a loaded run; this watch stats the tree's folders instead
(about fifty `stat` calls) and walks only when one of them changed: creating, removing or
renaming an entry changes its folder's modification time, nothing else a test does to the
tree goes unseen by it. Files only rewritten in place are not "created" and are not watched
(the guard never did).
"""

from __future__ import annotations

import os
from pathlib import Path

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
#: A walk that saw a folder change while it ran is taken again, at most this many times: a
#: test on another xdist worker may be writing while this one looks.
WALK_TRIES = 5


def unwatched_runtime_dirs(root: Path) -> tuple[str, ...]:
    return tuple(
        sorted(
            entry.name
            for entry in os.scandir(root)
            if entry.is_dir() and entry.name.startswith(RUNTIME_DIRS)
        )
    )


def _walk(root: Path, skip_top: tuple[str, ...]) -> tuple[frozenset[str], tuple[str, ...]]:
    """Every watched file and folder of the tree (relative), and the watched folders."""
    paths: set[str] = set()
    folders: list[str] = []
    for folder, dirs, files in os.walk(root):
        folders.append(folder)
        relative = os.path.relpath(folder, root)
        at_top = relative == "."
        dirs[:] = [d for d in dirs if d not in UNWATCHED_DIRS and not (at_top and d in skip_top)]
        prefix = "" if at_top else relative + os.sep
        paths.update(prefix + name for name in dirs)
        paths.update(prefix + name for name in files if not name.endswith(EDITOR_SUFFIXES))
    return frozenset(paths), tuple(folders)


def repository_paths(skip_top: tuple[str, ...] = (), *, root: Path) -> frozenset[str]:
    """Every file and folder in the tree (relative), but the unwatched ones."""
    return _walk(root, skip_top)[0]


def _stamps(folders: tuple[str, ...]) -> tuple[int, ...]:
    stamps = []
    for folder in folders:
        try:
            stamps.append(os.stat(folder).st_mtime_ns)
        except FileNotFoundError:  # removed: a change like any other
            stamps.append(-1)
    return tuple(stamps)


class TreeWatch:
    """The tree's watched paths, and the folders' modification times that say when to look
    again. ``created()`` names the paths that appeared since the last call (or since it was
    made)."""

    def __init__(self, root: Path, skip_top: tuple[str, ...] = ()) -> None:
        self.root = root
        self.skip_top = skip_top
        self.walks = 0
        self._paths, self._folders, self._seen = self._snapshot()

    def _snapshot(self) -> tuple[frozenset[str], tuple[str, ...], tuple[int, ...]]:
        """Stamps taken before and after the walk agree, or the walk is taken again: a path
        created while it ran is either in it, or changes a stamp the next call sees."""
        for _ in range(WALK_TRIES):
            self.walks += 1
            paths, folders = _walk(self.root, self.skip_top)
            before = _stamps(folders)
            again, folders_again = _walk(self.root, self.skip_top)
            if again == paths and folders_again == folders and _stamps(folders) == before:
                return paths, folders, before
        # Still changing (another worker writing in the tree): stamps older than the paths
        # make the next call look again rather than miss anything.
        return again, folders_again, tuple(-1 for _ in folders_again)

    @property
    def paths(self) -> frozenset[str]:
        return self._paths

    def created(self) -> list[str]:
        if _stamps(self._folders) == self._seen:
            return []
        before = self._paths
        self._paths, self._folders, self._seen = self._snapshot()
        return sorted(self._paths - before)


def describe(created: list[str], limit: int = 8) -> str:
    shown = ", ".join(created[:limit])
    more = f" and {len(created) - limit} more" if len(created) > limit else ""
    return f"{len(created)} path(s) in the repository tree: {shown}{more}"
