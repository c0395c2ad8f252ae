"""Issue 29: an arm model that is not calibrated never passes for one: the file keeps its
warning, what was not identified and what was saved against its physical range; the API serves
them; a value outside its range refuses the save unless forced."""

from __future__ import annotations

from pathlib import Path

import pytest

from api.routers.arm_models import _info
from daemon.arm.arm_model import ArmModel, arm_model_toml, load_arm_model
from daemon.commands.arm_identify import ImplausibleModelError, checked_for_save
from daemon.model.calibration import CalibratedParameter


def model(**changes: object) -> ArmModel:
    values: dict[str, object] = {
        "name": "m",
        "arm": "CRS A465",
        "heat_scales": (1.0, 0.8, 1.2, 1.0, 1.0, 1.0),
        "convection_scale": 0.9,
        "alpha_scale": 1.05,
        "capacity_scale": 1.2,
        "bending_shares": (0.7,) * 6,
        "parameters": (
            CalibratedParameter("alpha", 1.05, 0.001, 0.001, True, ""),
            CalibratedParameter("heat:4", 1.0, None, None, False, "no heat in joint 4"),
        ),
        "warning": "NOT FULLY CALIBRATED: heat:4 ...",
        "not_identified": ("heat:4",),
    }
    values.update(changes)
    return ArmModel(**values)  # type: ignore[arg-type]


def test_the_file_keeps_the_warning_and_the_new_factors(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text(arm_model_toml(model(implausible=("alpha = 1.9 is outside",))), "utf-8")
    text = path.read_text("utf-8")
    assert "calibrated = false" in text and "NOT FULLY CALIBRATED" in text
    loaded = load_arm_model(path)
    assert loaded.warning.startswith("NOT FULLY CALIBRATED") and not loaded.calibrated
    assert loaded.not_identified == ("heat:4",)
    assert loaded.implausible == ("alpha = 1.9 is outside",)
    assert loaded.capacity_scale == 1.2 and loaded.bending_shares == (0.7,) * 6
    served = _info(loaded, "m")
    assert served.calibrated is False and served.warning == loaded.warning
    assert served.not_identified == ["heat:4"] and served.capacity_scale == 1.2
    clean = model(warning="", not_identified=())
    assert clean.calibrated and _info(clean, "m").warning == ""


def test_a_file_without_the_new_fields_still_loads(tmp_path: Path) -> None:
    path = tmp_path / "old.toml"
    path.write_text(
        'format = 1\nname = "old"\narm = "CRS A465"\nheat_scales = [1.0, 1.0]\n', "utf-8"
    )
    loaded = load_arm_model(path)
    assert loaded.capacity_scale == 1.0 and loaded.bending_shares == () and loaded.calibrated


def test_a_value_outside_its_physical_range_refuses_the_save_unless_forced() -> None:
    wild = model(
        parameters=(
            CalibratedParameter("alpha", 1.9, 0.01, 0.005, True, ""),
            CalibratedParameter("convection", 0.1, 0.01, 0.1, False, "at its bound"),
        )
    )
    with pytest.raises(ImplausibleModelError, match=r"alpha = 1\.9 is outside its physical"):
        checked_for_save(wild, force=False)
    forced = checked_for_save(wild, force=True)
    assert len(forced.implausible) == 1 and "alpha" in forced.implausible[0]
    assert not forced.calibrated
    # a parameter the final fit did not identify keeps its prior: not checked
    assert checked_for_save(model(), force=False).implausible == ()


def test_a_parameter_never_fitted_is_saved_without_a_value(tmp_path: Path) -> None:
    """A joint the calibration cycle never heats has no fitted value (NaN): the model is still
    saved (the cycle that leaves the wrist's roll still, a465-machine-tending), the parameter
    without a value and with its reason, and loads back not identified."""
    silent = CalibratedParameter(
        "heat:6", float("nan"), None, None, False, "this cycle releases no heat in joint 6"
    )
    path = tmp_path / "m.toml"
    path.write_text(arm_model_toml(model(parameters=(silent,), not_identified=("heat:6",))))
    loaded = load_arm_model(path)
    (parameter,) = loaded.parameters
    assert parameter.name == "heat:6" and parameter.value != parameter.value
    assert not parameter.identifiable and "no heat in joint 6" in parameter.reason
    assert not loaded.calibrated and _info(loaded, "m").parameters == []
