"""Loading an arm: by preset name or file, a DH table (``daemon.arm.arm_file``) or a URDF
(``daemon.arm.urdf``); the presets in ``config/arms``."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from config.inputs import no_such_name
from config.settings import read_toml
from daemon.arm.arm_file import ArmFileSpec, describe_error, dh_arm, placement
from daemon.arm.description import MAX_ARM_JOINTS, MIN_ARM_JOINTS, Arm, ArmError
from daemon.arm.urdf import arm_from_urdf


def arm_from_mapping(
    data: dict[str, Any], default_name: str = "arm", folder: Path | None = None
) -> Arm:
    """The arm a parsed TOML document describes (``folder``: where a named URDF is looked for)."""
    rows = data.get("joints")
    if isinstance(rows, list) and len(rows) > MAX_ARM_JOINTS:  # said before 3,000 are checked
        raise ArmError(
            f"joints: {len(rows)} joints: an arm has {MIN_ARM_JOINTS} to {MAX_ARM_JOINTS}"
        )
    try:
        spec = ArmFileSpec.model_validate(data)
    except ValidationError as err:
        raise ArmError(describe_error(err, data)) from err
    name = spec.name or default_name
    if spec.urdf is None:
        return dh_arm(spec, name)
    if spec.convention is not None:
        raise ArmError("convention: a URDF arm takes its kinematics from the URDF; drop it")
    urdf_path = Path(spec.urdf)
    if not urdf_path.is_absolute() and folder is not None:
        urdf_path = folder / urdf_path
    for row in spec.joints:
        if row.a_mm or row.alpha_deg or row.d_mm or row.theta_offset_deg:
            raise ArmError(f"joint {row.name!r}: a URDF arm takes no DH values")
    return arm_from_urdf(
        urdf_path,
        name=name,
        description=spec.description,
        base_link=spec.base_link,
        tip_link=spec.tip_link,
        base=placement(spec.base),
        tool=placement(spec.tool),
        companion=spec,
    )


def arms_dir() -> Path:
    """Where the presets live (``config/arms``)."""
    return Path(str(resources.files("config").joinpath("arms")))


def available_arms() -> list[str]:
    return sorted(path.stem for path in arms_dir().glob("*.toml"))


def load_arm(name_or_path: str | Path) -> Arm:
    """An arm by preset name (``"crs-a465"``) or file: a TOML arm file (DH table, or ``urdf =``
    naming a URDF plus materials and motors) or a bare ``.urdf`` (kinematics only). Raises
    :class:`ArmError` with a one-line message naming the file and the field."""
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith((".toml", ".urdf")) or path.is_file()):
        path = arms_dir() / f"{text}.toml"
        if not path.is_file():
            presets = available_arms()
            listed = f"presets: {', '.join(presets)}; or a TOML or URDF file"
            raise ArmError(no_such_name("arm", text, presets, listed))
    if path.suffix.lower() == ".urdf":
        return arm_from_urdf(path, name=path.stem)
    data = read_toml(path, ArmError)
    try:
        return arm_from_mapping(data, default_name=path.stem, folder=path.parent)
    except ArmError as err:
        message = str(err)
        if message.startswith(str(path)):
            raise
        raise ArmError(f"{path}: {message}") from err
