"""Every input file is bounded and gets one line (issue 26 "Bad files"): the hostile corpus of
tests/hostile/corpus.py fed to the real ``thermocomp`` command, each case in its own process
with a time limit and a memory limit (tests/hostile/runner.py). Each must end with its exit
status (2: the input is refused; 1: an image that is no measurable frame), ONE line on stderr
that names the problem, and no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.hostile.corpus import FILE_CASES, Case, matches
from tests.hostile.runner import TIME_LIMIT_S, run_bounded


@pytest.mark.parametrize("case", FILE_CASES, ids=[case.id for case in FILE_CASES])
def test_a_hostile_file_gets_one_line(case: Case, tmp_path: Path) -> None:
    case.write(tmp_path)
    outcome = run_bounded(case.command(tmp_path), tmp_path, case.env)
    assert outcome.status is not None, f"still running after {TIME_LIMIT_S} s: {outcome.err}"
    assert "Traceback" not in outcome.err, outcome.err[-3000:]
    lines = outcome.err_lines
    assert len(lines) == 1, f"expected one line, got {len(lines)}:\n" + "\n".join(lines[:20])
    assert lines[0].startswith("thermocomp"), lines[0]
    assert matches(case, lines[0]), f"{lines[0]!r} does not say {case.says!r}"
    assert outcome.status == case.status, (outcome.status, lines[0])
