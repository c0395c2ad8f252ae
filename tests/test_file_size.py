"""No product module over MAX_LINES lines (issue 27: "files with one job, split past ~500
lines"): a file that grows past it is split at its seams, not trimmed of its comments."""

from __future__ import annotations

from pathlib import Path

from tests.helpers import REPO_ROOT

PRODUCT = ("api", "daemon", "drivers", "config")
MAX_LINES = 500


def oversized(root: Path = REPO_ROOT) -> dict[str, int]:
    """Each product .py file over MAX_LINES lines, with its length."""
    found: dict[str, int] = {}
    for top in PRODUCT:
        for path in sorted((root / top).rglob("*.py")):
            lines = len(path.read_text(encoding="utf-8").splitlines())
            if lines > MAX_LINES:
                found[str(path.relative_to(root))] = lines
    return found


def test_no_product_file_is_over_the_limit() -> None:
    assert oversized() == {}, f"split these at their seams (over {MAX_LINES} lines)"


def test_the_check_sees_a_long_file(tmp_path: Path) -> None:
    (tmp_path / "daemon").mkdir()
    (tmp_path / "daemon" / "long.py").write_text("x = 1\n" * (MAX_LINES + 1), encoding="utf-8")
    (tmp_path / "daemon" / "short.py").write_text("x = 1\n" * MAX_LINES, encoding="utf-8")
    assert oversized(tmp_path) == {"daemon/long.py": MAX_LINES + 1}
