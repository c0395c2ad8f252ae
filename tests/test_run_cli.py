"""`thermocomp run` on the real simulated bench (C500C driver over a pty to the emulator),
including the crash test of issue 6: SIGKILL mid-run, restart, every committed step readable
and the run marked interrupted. What needs a process (``--help``, the signals) runs the real
command; the runs and refusals call its entry point in-process (tests.helpers.run_main: the
same status, stdout and stderr without a fresh interpreter's imports, issue 27)."""

import json
import os
import random
import re
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest

from daemon.analysis import SUMMARY_KEYS
from daemon.storage.recorder import DATABASE_NAME, Recorder
from tests.helpers import REPO_ROOT, cli_command, run_cli, run_main

SIM = "config/sim.toml"
KILLED_RUNS = 4


def test_run_help_lists_the_run_options() -> None:
    result = run_cli(["run", "--help"])
    assert result.returncode == 0
    for option in ("--config", "--procedure", "--compensation", "--duration", "--step", "--json"):
        assert option in result.stdout


@pytest.mark.slow
def test_bad_run_parameters_are_usage_errors(tmp_path: Path) -> None:
    result = run_main(["run", "--config", SIM, "--data-dir", str(tmp_path), "--step", "0.001"])
    assert result.returncode == 2
    assert "step_s" in result.stderr and "Traceback" not in result.stderr
    result = run_main(["run", "--config", SIM, "--data-dir", str(tmp_path), "--scale", "1000"])
    assert result.returncode == 2
    assert "largest admissible scale" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_a_heat_input_naming_no_node_is_refused_before_the_run(tmp_path: Path) -> None:
    """Issue 19: model.heat_w keys are checked against the run's network at its start (exit
    2), not at the first step after the goal was taught (a traceback)."""
    result = run_main(
        ["run", "--config", SIM, "--data-dir", str(tmp_path), "--duration", "5"],
        env={"THERMOCOMP_MODEL__HEAT_W": '{"99": 0.5}'},
    )
    assert result.returncode == 2
    assert "heat input '99' names no node of network 'thesis-two-link'" in result.stderr
    assert "heat from setting model.heat_w" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_heat_inputs_on_the_command_line_replace_the_settings(tmp_path: Path) -> None:
    """`--heat 2=0.7 9=0.3` replaces model.heat_w (issue 19: run had no --heat); a node the
    network lacks or a malformed value is a usage error."""
    options = ["--data-dir", str(tmp_path), "--duration", "5", "--json"]
    result = run_main(["run", "--config", SIM, *options, "--heat", "2=0.7", "9=0.3"])
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["parameters"]["heat_w"] == {"2": 0.7, "9": 0.3}
    for bad, message in (
        (["--heat", "17=1", "99=1"], "heat input '99' names no node"),
        (["--heat", "2=hot"], "NODE=WATTS"),
    ):
        refused = run_main(["run", "--config", SIM, *options, *bad])
        assert refused.returncode == 2 and message in refused.stderr, refused.stderr
        assert "Traceback" not in refused.stderr


@pytest.mark.slow
def test_incremental_moves_below_the_console_resolution_are_refused(tmp_path: Path) -> None:
    """Issue 19 / thesis 6.3: at a 1 s step every incremental move of the unscaled bench is
    under the console's 0.001 mm, so the run is refused before it starts, naming a scale that
    works; at that scale the run goes and the robot really moves."""
    options = ["--data-dir", str(tmp_path), "--duration", "60", "--compensation", "incremental"]
    refused = run_main(["run", "--config", SIM, *options])
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "would round to no motion" in refused.stderr
    match = re.search(r"deformation scale (\d+) would work", refused.stderr)
    assert match is not None, refused.stderr
    result = run_main(["run", "--config", SIM, *options, "--scale", match.group(1), "--json"])
    assert result.returncode == 0, result.stderr
    final = json.loads(result.stdout)
    assert final["id"] == 1  # the refused run was never recorded
    with Recorder(tmp_path) as recorder:
        poses = {s.pose_x_mm for s in recorder.steps(final["id"])}
    assert len(poses) > 10  # the robot followed the deformation, 0.001 mm at a time


@pytest.mark.slow
def test_a_short_compensated_bench_run_prints_its_summary(tmp_path: Path) -> None:
    csv_path = tmp_path / "steps.csv"
    options = ["--data-dir", str(tmp_path), "--duration", "20", "--json", "--csv", str(csv_path)]
    result = run_main(["run", "--config", SIM, *options])
    assert result.returncode == 0, result.stderr
    final = json.loads(result.stdout)
    assert final["state"] == "finished"
    summary = final["summary"]
    assert set(SUMMARY_KEYS) <= set(summary)
    assert summary["n"] == 20 and summary["overruns"] == 0
    assert len(csv_path.read_text().splitlines()) == 21  # header + 20 steps
    with Recorder(tmp_path) as recorder:
        steps = recorder.steps(final["id"])
    # the real C500C driver read the pose back at every step, at the 0.001 mm console grain
    assert all(s.pose_x_mm is not None and s.centroid_x_px is not None for s in steps)


@pytest.mark.slow
def test_reduction_is_measured_against_a_named_uncompensated_run(tmp_path: Path) -> None:
    """Issue 19: an off run states its drift; a compensated run naming it as its reference
    gets a measured reduction over the time both cover; a compensated run is no reference."""
    options = ["--data-dir", str(tmp_path), "--duration", "30", "--json"]
    off = run_main(["run", "--config", SIM, *options, "--compensation", "off"])
    assert off.returncode == 0, off.stderr
    off_final = json.loads(off.stdout)
    drift = off_final["summary"]
    assert drift["reduction_basis"] == "drift" and drift["reduction_percent"] is None
    assert drift["measured_drift_max_um"] == drift["residual_max_um"] > 0

    reference = str(off_final["id"])
    compensated = run_main(
        [
            "run",
            "--config",
            SIM,
            *options[:-1],
            "--duration",
            "20",
            "--json",
            "--reference-run",
            reference,
        ]
    )
    assert compensated.returncode == 0, compensated.stderr
    final = json.loads(compensated.stdout)
    summary = final["summary"]
    assert summary["reduction_basis"] == "reference"
    assert summary["reference_run"] == off_final["id"]
    with Recorder(tmp_path) as recorder:
        drift_steps = recorder.steps(off_final["id"])
        steps = recorder.steps(final["id"])
    span = steps[-1].scheduled_s  # the shorter run's end
    assert summary["reference_span_s"] == span
    reference_max = max(abs(s.residual_um) for s in drift_steps if s.scheduled_s <= span)
    residual_max = max(abs(s.residual_um) for s in steps)
    assert summary["reference_max_um"] == reference_max
    assert abs(summary["reduction_percent"] - 100 * (1 - residual_max / reference_max)) < 1e-9

    refused = run_main(["run", "--config", SIM, *options, "--reference-run", str(final["id"])])
    assert refused.returncode == 2
    assert "must be an uncompensated run" in refused.stderr and "Traceback" not in refused.stderr


def _committed_steps(database: Path) -> int:
    if not database.exists():
        return 0
    db = sqlite3.connect(f"file:{database}?mode=ro", uri=True, timeout=5.0)
    try:
        return int(db.execute("SELECT COUNT(*) FROM steps").fetchone()[0])
    except sqlite3.OperationalError:  # tables not created yet
        return 0
    finally:
        db.close()


def _start_long_run(data_dir: Path, *, json_summary: bool = False) -> subprocess.Popen[str]:
    """A ten-hour bench run (virtual clock: as fast as the pty allows) to be stopped by a
    signal; with ``json_summary`` it prints its final state as JSON on the piped stdout."""
    return subprocess.Popen(
        cli_command(
            "--log-level",
            "WARNING",
            "run",
            "--config",
            SIM,
            "--data-dir",
            str(data_dir),
            "--duration",
            "36000",
            *(["--json"] if json_summary else []),
        ),
        cwd=REPO_ROOT,
        env=dict(os.environ),
        stdout=subprocess.PIPE if json_summary else subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        text=True,
    )


def _wait_for_steps(
    process: subprocess.Popen[str], database: Path, count: int, poll_s: float = 0.05
) -> None:
    """Until ``database`` holds ``count`` committed steps, the run still going (60 s at most)."""
    deadline = time.monotonic() + 60.0
    while _committed_steps(database) < count:
        assert process.poll() is None, "the run ended before it could be stopped"
        assert time.monotonic() < deadline, "no steps were committed in time"
        time.sleep(poll_s)


@pytest.mark.slow
def test_sigkill_mid_run_leaves_every_committed_step_and_an_interrupted_run(
    tmp_path: Path,
) -> None:
    database = tmp_path / DATABASE_NAME
    process = _start_long_run(tmp_path)
    try:
        _wait_for_steps(process, database, 30)
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == -signal.SIGKILL
    committed = _committed_steps(database)

    with Recorder(tmp_path) as recorder:  # what the daemon does when it starts again
        (run,) = recorder.runs()
        assert recorder.interrupted_runs == [run.id]
        assert run.state == "interrupted" and run.step_count == committed >= 30
        steps = recorder.steps(run.id)
    assert [s.step for s in steps] == list(range(committed))  # no gap, no partial step
    assert all(s.scheduled_s == float(s.step) and s.residual_um is not None for s in steps)
    check = sqlite3.connect(database)
    assert check.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    check.close()


@pytest.mark.slow
def test_sigterm_stops_the_run_cleanly(tmp_path: Path) -> None:
    database = tmp_path / DATABASE_NAME
    process = _start_long_run(tmp_path, json_summary=True)
    try:
        _wait_for_steps(process, database, 5)
        process.send_signal(signal.SIGTERM)
        output, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 1  # the run did not finish: it was stopped
    final = json.loads(output)
    assert final["state"] == "stopped" and final["reason"] == "stopped by a signal"
    with Recorder(tmp_path) as recorder:
        assert recorder.interrupted_runs == []  # ended properly, nothing to mark
        (run,) = recorder.runs()
        assert run.state == "stopped" and run.step_count == final["step"] + 1


@pytest.mark.slow
def test_sigkill_at_random_points_of_successive_runs_loses_no_committed_step(
    tmp_path: Path,
) -> None:
    """Several runs in one data directory, each killed at a random point (after a random number
    of committed steps plus a random fraction of a step, so some kills land mid-step); each
    restart marks the previous run interrupted; nothing committed is lost or torn."""
    database = tmp_path / DATABASE_NAME
    rng = random.Random(10)  # seeded: a failure names its kill points
    committed: list[int] = []
    for _ in range(KILLED_RUNS):
        at_least = rng.randint(1, 40)
        before = sum(committed)
        process = _start_long_run(tmp_path)
        try:
            _wait_for_steps(process, database, before + at_least, poll_s=0.005)
            time.sleep(rng.uniform(0.0, 0.03))
            process.send_signal(signal.SIGKILL)
            process.wait(timeout=10)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        committed.append(_committed_steps(database) - before)

    with Recorder(tmp_path) as recorder:
        runs = sorted(recorder.runs(), key=lambda run: run.id)
        assert [run.state for run in runs] == ["interrupted"] * KILLED_RUNS
        for run, count in zip(runs, committed, strict=True):
            steps = recorder.steps(run.id)
            assert run.step_count == count == len(steps) >= 1
            assert [s.step for s in steps] == list(range(count))  # no gap, no partial step
            assert all(s.residual_um is not None and s.pose_x_mm is not None for s in steps)
    check = sqlite3.connect(database)
    assert check.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    check.close()
