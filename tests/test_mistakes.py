"""One line for every mistake (issue 28): a test per row of the mistakes table in
docs/reference/errors.md (the table's first column names the row's test here). Each mistake
is made through the real command line in a child process bounded in time and memory
(tests/hostile/runner.py): one line on stderr that says what is wrong, no traceback, the
right exit status."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from daemon.commands.run import _print_result
from tests.helpers import REPO_ROOT
from tests.hostile.corpus import ARM_SIM, CYCLE, URDF_CONFIG, Case, matches
from tests.hostile.runner import Outcome, run_bounded

ERRORS_PAGE = REPO_ROOT / "docs" / "reference" / "errors.md"
SIM = (REPO_ROOT / "config" / "sim.toml").read_text("utf-8")
#: the two-link bench's settings with their data directory in the case's folder
TWO_LINK = re.sub(r'^data_dir = ".*"$', 'data_dir = "{t}/data"', SIM, flags=re.M)


def port_0(text: str) -> str:
    """``text`` with api.port = 0 (any free port: serve's checks bind it)."""
    if "[api]\n" in text:
        return re.sub(r"^port = \d+$", "port = 0", text, count=1, flags=re.M)
    return text + "\n[api]\nport = 0\n"


def one_line(outcome: Outcome, says: str, status: int) -> str:
    """The one line of ``outcome``, checked: exit ``status``, no traceback, says ``says``."""
    assert outcome.status is not None, f"still running after {outcome.seconds:.0f} s"
    assert "Traceback" not in outcome.err, outcome.err[-2000:]
    lines = outcome.err_lines
    assert len(lines) == 1, "\n".join(lines[:20])
    assert re.search(says, lines[0], re.IGNORECASE), f"{lines[0]!r} does not say {says!r}"
    assert outcome.status == status, (outcome.status, lines[0])
    return lines[0]


def made(case: Case, folder: Path) -> Outcome:
    case.write(folder)
    return run_bounded(case.command(folder), folder, case.env)


#: (row, the mistake made, what the one line says, exit status) of the table's simple rows
ROWS = [
    Case(
        "network-typo",
        "mistake",
        ("run", "--network", "thesis-two-lnk", "--data-dir", "{t}/data"),
        r"^thermocomp run: no network preset or saved network 'thesis-two-lnk' \(did you mean "
        r"'thesis-two-link'( or '[a-z-]*')?\?; presets: .*thesis-two-link",
    ),
    Case(
        "duty-cycle-typo",
        "mistake",
        ("run", "--config", "{t}/c.toml", "--duty-cycle", "pick-and-plce"),
        r"^thermocomp run: no duty cycle 'pick-and-plce' \(did you mean .*'a465-pick-and-place'",
        {"c.toml": ARM_SIM},
    ),
    Case(
        "arm-model-unknown",
        "mistake",
        (
            "run",
            "--config",
            "{t}/c.toml",
            "--duty-cycle",
            "a465-pick-and-place",
            "--arm-model",
            "nosuch",
        ),
        r"^thermocomp run: no saved arm model 'nosuch' \(saved in .*arm-models: none\)",
        {"c.toml": ARM_SIM},
    ),
    Case(
        "arm-file-typo",
        "mistake",
        ("run", "--config", "{t}/c.toml"),
        r"no arm 'crs-a456' \(did you mean 'crs-a465'\?; presets: crs-a465",
        {"c.toml": ARM_SIM.replace('arm_file = "crs-a465"', 'arm_file = "crs-a456"')},
    ),
    Case(
        "camera-file-missing",
        "mistake",
        ("run", "--config", "{t}/c.toml"),
        r"cams\.toml: no such file",
        {"c.toml": ARM_SIM.replace("[arm]\n", '[arm]\ncameras_file = "{t}/cams.toml"\n')},
    ),
    Case(
        "duty-cycle-other-arm",
        "mistake",
        ("run", "--config", "{t}/c.toml", "--duty-cycle", "ur5e-pick-and-place"),
        r"duty cycle 'ur5e-pick-and-place' was taught on arm 'ur5e', this arm is 'crs-a465'",
        {"c.toml": ARM_SIM},
    ),
    Case(
        "serve-network-typo",
        "mistake",
        ("serve", "--config", "{t}/c.toml"),
        r"^thermocomp serve: no network preset or saved network 'thesis-two-lnk' \(did you mean",
        {
            "c.toml": port_0(
                TWO_LINK.replace('network = "thesis-two-link"', 'network = "thesis-two-lnk"')
            )
        },
    ),
    Case(
        "serve-duty-cycle-typo",
        "mistake",
        ("serve", "--config", "{t}/c.toml"),
        r"^thermocomp serve: no duty cycle 'pick-and-plce' \(did you mean .*'a465-pick-and-place'",
        {"c.toml": port_0(ARM_SIM.replace('"a465-pick-and-place"', '"pick-and-plce"'))},
    ),
    Case(
        "serve-arm-file-bad",
        "mistake",
        ("serve", "--config", "{t}/c.toml"),
        r"^thermocomp serve: .*arm\.urdf: link 'l1' has more than one parent joint",
        {"c.toml": port_0(URDF_CONFIG), "arm.urdf": CYCLE},
    ),
    Case(
        "bool-yes",
        "mistake",
        ("run", "--config", "{t}/c.toml"),
        r"^thermocomp run: invalid configuration: .*c\.toml: bench\.enabled: Input should be a "
        r"valid boolean",
        {"c.toml": TWO_LINK.replace("enabled = true", 'enabled = "yes"', 1)},
    ),
    Case(
        "reference-run-overflow",
        "mistake",
        ("run", "--reference-run", str(2**63), "--data-dir", "{t}/data"),
        r"^thermocomp run: invalid run parameters: reference_run: Input should be less than or "
        r"equal to 9223372036854775807",
    ),
    Case(
        "toml-nested",
        "mistake",
        ("run", "--config", "{t}/c.toml"),
        r"c\.toml: arrays or tables nested over 16 deep",
        {"c.toml": "a = " + "[" * 5000 + "]" * 5000},
    ),
    Case(
        "urdf-cycle",
        "mistake",
        ("run", "--config", "{t}/c.toml"),
        r"arm\.urdf: link 'l1' has more than one parent joint \('j1' and 'back'\)",
        {"c.toml": URDF_CONFIG, "arm.urdf": CYCLE},
    ),
    Case(
        "centroid-fifo",
        "mistake",
        ("centroid", "{t}/frame.png"),
        r"^thermocomp centroid: .*frame\.png: not a regular file",
        {"frame.png": b"<fifo>"},
    ),
    Case(
        "serve-data-dir",
        "mistake",
        ("serve", "--config", "{t}/c.toml", "--data-dir", "/proc/thermocomp-data"),
        r"^thermocomp serve: .*/proc/thermocomp-data",
        {"c.toml": port_0(TWO_LINK)},
        status=4,
    ),
]


@pytest.mark.parametrize("case", ROWS, ids=[case.id for case in ROWS])
def test_a_mistake_is_one_line(case: Case, tmp_path: Path) -> None:
    line = one_line(made(case, tmp_path), case.says, case.status)
    assert matches(case, line)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Outcome]]:
    """A short uncompensated two-link run recorded in a data directory of its own."""
    folder = tmp_path_factory.mktemp("recorded")
    (folder / "c.toml").write_text(TWO_LINK.replace("{t}", str(folder)))
    argv = ["run", "--config", str(folder / "c.toml"), "--compensation", "off"]
    outcome = run_bounded([*argv, "--duration", "20", "--step", "10"], folder, timeout_s=120)
    assert outcome.status == 0, outcome.err[-2000:]
    yield folder, outcome


@pytest.mark.slow
def test_quiet_unless_asked(recorded: tuple[Path, Outcome]) -> None:
    """Row quiet-logs: the summary on stdout, nothing on stderr (no INFO lines between the
    summary's); -v brings the progress back, on stderr."""
    folder, outcome = recorded
    assert outcome.err_lines == [], outcome.err
    assert re.search(r"^run 1 finished", outcome.out, re.M), outcome.out
    argv = ["run", "--config", str(folder / "c.toml"), "--duration", "10", "--step", "10", "-v"]
    verbose = run_bounded(argv, folder, timeout_s=120)
    assert verbose.status == 0, verbose.err[-2000:]
    assert any(" INFO " in line for line in verbose.err_lines), verbose.err
    assert not any(" INFO " in line for line in verbose.out.splitlines())


@pytest.mark.slow
def test_an_arm_run_refuses_a_two_link_reference(recorded: tuple[Path, Outcome]) -> None:
    """Row reference-wrong-kind: before, the arm run ran and its reduction was null."""
    folder, _ = recorded
    (folder / "arm.toml").write_text(ARM_SIM.replace("{t}", str(folder)))
    argv = ["run", "--config", str(folder / "arm.toml"), "--reference-run", "1"]
    line = one_line(
        run_bounded(argv, folder, timeout_s=120),
        r"^thermocomp run: reference_run 1 is a two-link run, this run is an arm run",
        2,
    )
    assert "a465-pick-and-place" in line


@pytest.mark.slow
def test_report_takes_the_data_directory(recorded: tuple[Path, Outcome]) -> None:
    """Row report-data-dir: ``report --data-dir`` (before: "unrecognized arguments")."""
    folder, _ = recorded
    out = folder / "report-1"
    argv = ["report", "1", "--data-dir", str(folder / "data"), "--out", str(out)]
    outcome = run_bounded(argv, folder, timeout_s=120)
    assert outcome.status == 0, outcome.err[-2000:]
    assert outcome.err_lines == [] and (out / "report.html").is_file()


def test_a_negative_reduction_is_said_to_be_an_increase(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Row negative-reduction: a short run's residual above the prediction (the summary's
    -186.858 %) is printed as the increase it is, never as a negative reduction."""
    summary = {
        "kind": "two-link",  # as every two-link summary says (daemon/run/two_link/summary.py)
        "n": 3,
        "residual_max_um": 2.0,
        "reduction_basis": "reference",
        "reference_run": 1,
        "reduction_percent": 40.0,
        "reduction_vs_prediction_percent": -186.858,
    }
    _print_result({"id": 2, "state": "finished", "reason": None, "summary": summary}, False)
    out = capsys.readouterr().out
    assert re.search(r"vs the prediction +not reduced: 186\.858 % larger$", out, re.M), out
    assert re.search(r"reduction \(measured\) +40\.000 %$", out, re.M), out
    assert "-186" not in out
    _print_result({"id": 2, "state": "finished", "reason": None, "summary": summary}, True)
    assert json.loads(capsys.readouterr().out)["summary"]["reduction_vs_prediction_percent"] < 0


#: Rows tested elsewhere (the table's first column -> the test that checks the row).
ELSEWHERE = {
    "devices-check-every-device": "tests/test_devices_check.py::"
    "test_a_robot_that_does_not_answer_leaves_the_cameras_checked",
    "bad-file-in-data-dir": "tests/test_hostile_api.py::test_the_listings_name_each_bad_file_once",
    "api-reference-run-overflow": "tests/test_hostile_api.py::test_a_hostile_request_gets_one_line",
}
TESTED_HERE = {
    *(case.id for case in ROWS),
    "quiet-logs",
    "reference-wrong-kind",
    "report-data-dir",
    "negative-reduction",
}


def test_every_row_of_the_mistakes_table_has_its_test() -> None:
    rows = re.findall(r"^\| `([a-z0-9-]+)` \|", ERRORS_PAGE.read_text("utf-8"), re.M)
    assert len(rows) == len(set(rows)), "a row twice"
    assert set(rows) == TESTED_HERE | set(ELSEWHERE)
    for test in ELSEWHERE.values():
        path, _, name = test.partition("::")
        assert f"def {name}(" in (REPO_ROOT / path).read_text("utf-8"), test
