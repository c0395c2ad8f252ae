"""The arm bench's truth as a file (issue 29): the default is the bench's truth of before, the
shipped scenarios load and say whether they are plausible, a bad file is one line naming the
key, an arm config refuses the two-link bench's truth settings, and the bench follows a file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from config import ConfigError, load_settings
from config.arm_truth import (
    TRUTHS_DIR,
    ArmTruth,
    ArmTruthError,
    implausible,
    load_arm_truth,
    room_excursion_c,
)
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig, config_from_truth
from drivers.sim.arm_room import SimRoomSensor

ARM_SIM = Path(__file__).resolve().parent.parent / "config" / "arm-sim.toml"
SCENARIOS = sorted(path.stem for path in TRUTHS_DIR.glob("*.toml"))


def test_the_default_truth_is_the_bench_of_before() -> None:
    # every default of the file is ArmBenchConfig's: existing results reproduce to the bit
    assert config_from_truth(ArmTruth(), 3) == ArmBenchConfig(seed=3)
    assert load_arm_truth("default") == ArmTruth(description=load_arm_truth("default").description)


@pytest.mark.parametrize("name", SCENARIOS)
def test_every_shipped_scenario_loads_and_says_if_it_is_plausible(name: str) -> None:
    truth = load_arm_truth(name)
    assert truth.description
    problems = implausible(truth)
    assert bool(problems) == (name == "beyond-plausible"), problems


def test_a_scenario_of_the_issue_ranges_is_plausible_and_one_beyond_is_not() -> None:
    corner = ArmTruth.model_validate(
        {
            "motors": {"heat_scales": [0.5, 2.0, 1.0, 1.0, 1.0, 1.0]},
            "thermal": {"expansion_scale": 0.9, "capacity_scale": 1.3, "bending_share": 0.9},
            "room": {"drift_c_per_h": 0.375},
        }
    )
    assert implausible(corner) == []
    assert room_excursion_c(corner.room) == pytest.approx(3.0)
    hot = corner.model_copy(update={"room": corner.room.model_copy(update={"swing_c": 0.5})})
    assert any(problem.startswith("room") for problem in implausible(hot))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[thermal]\nbending_shar = 0.8\n", "thermal.bending_shar: unknown key"),
        ("[thermal]\nbending_share = 1.5\n", "thermal.bending_share: Input should be less"),
        ("[room]\nstart_c = nan\n", "room.start_c: Input should be a finite number"),
        ("[measurement]\njitter_px = inf\n", "measurement.jitter_px: Input should be a finite"),
        ("[motors]\nheat_scales = [1.0, -2.0]\n", "motors.heat_scales.1: Input should be greater"),
        ("seed = -1\n", "seed: Input should be greater than or equal to 0"),
        ("[room]\nswing_c = 1.0\nswing_period_h = 0.01\n", "swing_period_h: a room's swing"),
        ("[thermal\n", "not valid TOML"),
        ("colour = 'red'\n", "colour: unknown key"),
    ],
)
def test_a_bad_truth_file_is_one_line_naming_the_key(
    tmp_path: Path, text: str, expected: str
) -> None:
    path = tmp_path / "truth.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ArmTruthError) as caught:
        load_arm_truth(path)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message and expected in message


def test_a_missing_truth_file_is_one_line() -> None:
    with pytest.raises(ArmTruthError, match="no such file"):
        load_arm_truth("no-such-truth")


def _arm_settings(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "settings.toml"
    path.write_text(ARM_SIM.read_text(encoding="utf-8") + extra, encoding="utf-8")
    return path


def test_an_arm_config_refuses_the_two_link_bench_truth_in_one_line(tmp_path: Path) -> None:
    text = ARM_SIM.read_text(encoding="utf-8").replace(
        "seed = 1", "seed = 1\ntruth_heat_scale = 2.0\nambient_drift_c_per_h = 0.5"
    )
    path = tmp_path / "settings.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        load_settings(path, environ={})
    message = str(caught.value)
    assert "\n" not in message
    assert "bench.ambient_drift_c_per_h" in message and "truth_heat_scale" in message
    assert "bench.arm_truth" in message
    # the same settings on the two-link bench are its truth, as before
    two_link = text.replace("[arm]\nenabled = true", "[arm]\nenabled = false")
    path.write_text(two_link, encoding="utf-8")
    assert load_settings(path, environ={}).bench.truth_heat_scale == 2.0


def test_an_arm_config_takes_a_truth_preset_or_file_and_refuses_a_bad_one(
    tmp_path: Path,
) -> None:
    settings = load_settings(ARM_SIM, environ={"THERMOCOMP_BENCH__ARM_TRUTH": "hot-motors"})
    assert settings.bench.arm_truth == "hot-motors"
    bad = tmp_path / "bad.toml"
    bad.write_text("[thermal]\nexpansion_scale = 3.0\n", encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        load_settings(ARM_SIM, environ={"THERMOCOMP_BENCH__ARM_TRUTH": str(bad)})
    message = str(caught.value)
    assert "\n" not in message and "bench.arm_truth" in message
    assert "thermal.expansion_scale" in message


@pytest.mark.slow
def test_the_bench_follows_the_truth_file() -> None:
    truth = load_arm_truth("corner-high")
    bench = ArmBench(config_from_truth(truth, 1))
    assert bench.config.seed == 7  # the file's seed wins over the bench's
    assert bench.heat_scales.tolist() == list(truth.motors.heat_scales or ())
    assert bench.config.plus_share == 0.9 and bench.config.jitter_px == 0.045
    joints = bench.thermal.description.joints
    default = ArmBench(ArmBenchConfig(seed=7)).thermal.description.joints
    ratio = joints[1].capacitance_j_per_c / default[1].capacitance_j_per_c
    assert ratio == pytest.approx(1.3 / 1.1)
    room = truth.room
    for hours in (0.0, 2.5, 8.0):
        assert bench.ambient_c(hours * 3600.0) == pytest.approx(room.at_c(hours * 3600.0))
    assert bench.ambient_c(8 * 3600.0) == pytest.approx(
        20.0 + 0.3 * 8 + 0.6 * math.sin(2 * math.pi * 8 / 12)
    )


def test_the_room_thermometer_lags_rounds_and_is_seeded() -> None:
    def ramp(t_s: float) -> float:
        return 20.0 + t_s / 3600.0  # +1 degC an hour

    quiet = SimRoomSensor(ramp, np.random.default_rng(0), lag_s=600.0, noise_c=0.0,
                          resolution_c=0.0)  # fmt: skip
    quiet.advance_to(4 * 3600.0)
    # a first-order lag behind a ramp settles at rate x tau behind it: 600 s = 1/6 degC
    assert quiet.body_c == pytest.approx(24.0 - 1.0 / 6.0, abs=2e-3)
    rounded = SimRoomSensor(ramp, np.random.default_rng(0), lag_s=0.0, noise_c=0.0,
                            resolution_c=0.0625, offset_c=0.3)  # fmt: skip
    value = rounded.read(1800.0)
    assert value == pytest.approx(round(20.8 / 0.0625) * 0.0625)
    readings = [
        SimRoomSensor(ramp, np.random.default_rng(5), noise_c=0.1, resolution_c=0.0).read(60.0)
        for _ in range(2)
    ]
    assert readings[0] == readings[1]
    noisy = SimRoomSensor(ramp, np.random.default_rng(1), lag_s=0.0, noise_c=0.1,
                          resolution_c=0.0)  # fmt: skip
    spread = np.std([noisy.read(1.0 + k) - ramp(1.0 + k) for k in range(400)])
    assert 0.08 < spread < 0.12
