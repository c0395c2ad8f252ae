"""Arms from URDF (ROS Unified Robot Description Format), parsed with yourdfpy.

Why yourdfpy (https://github.com/clemense/yourdfpy): maintained (releases through 2024-25),
MIT, pure Python on lxml, and it parses a URDF into plain dataclasses without loading meshes or
building a scene graph (``build_scene_graph=False, load_meshes=False``), which is all the
kinematics need. urchin (the maintained urdfpy fork) pulls in a renderer (pyribbit/PyOpenGL)
and loads meshes by default. yourdfpy is an optional dependency (``pip install
thermocomp[urdf]``); DH arms need nothing beyond NumPy/SciPy.

The chain from ``base_link`` (default: the URDF's root) to ``tip_link`` (default: the only leaf)
becomes ``Joint`` rows with ``origin`` (mm) and ``axis``: fixed joints are folded into the next
moving joint's origin (or into ``base``/``tool`` at the ends); revolute and continuous joints
are the arm's joints; prismatic, planar and floating joints are refused.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from daemon.arm.arm_file import (
    ArmFileSpec,
    build_links,
    build_motor,
    check_links_named,
    limit_rad,
)
from daemon.arm.description import MM_PER_M, Arm, ArmError, FloatArray, Joint

#: Joint types that move by rotation (URDF ``<joint type>``); "continuous" has no limits.
_REVOLUTE = ("revolute", "continuous")
_FIXED = "fixed"


def _load_urdf(path: Path) -> Any:
    try:
        import yourdfpy
    except ImportError as err:
        raise ArmError(
            f"{path}: reading URDF needs yourdfpy (pip install 'thermocomp[urdf]')"
        ) from err
    if not path.is_file():
        raise ArmError(f"{path}: no such file")
    try:
        return yourdfpy.URDF.load(
            str(path),
            build_scene_graph=False,
            build_collision_scene_graph=False,
            load_meshes=False,
            load_collision_meshes=False,
        )
    except Exception as err:  # yourdfpy raises lxml, Value and Attribute errors alike
        raise ArmError(f"{path}: not a readable URDF: {err}") from err


def _origin_mm(origin: Any) -> FloatArray:
    out = np.eye(4) if origin is None else np.array(origin, dtype=np.float64)
    out[:3, 3] *= MM_PER_M
    return out


def arm_from_urdf(
    path: Path,
    *,
    name: str,
    description: str = "",
    base_link: str | None = None,
    tip_link: str | None = None,
    base: FloatArray | None = None,
    tool: FloatArray | None = None,
    companion: ArmFileSpec | None = None,
) -> Arm:
    """The arm of the URDF at ``path`` (see the module docstring); ``companion`` is the arm TOML
    that named it (materials, motors, limits overrides by joint and link name)."""
    model = _load_urdf(path)
    robot = model.robot
    joints_by_child = {joint.child: joint for joint in robot.joints}
    children: dict[str, list[str]] = {}
    for joint in robot.joints:
        children.setdefault(joint.parent, []).append(joint.child)
    link_names = [link.name for link in robot.links]
    roots = [link for link in link_names if link not in joints_by_child]
    if len(roots) != 1:
        raise ArmError(f"{path}: a URDF needs one root link, found {roots}")
    root = base_link or roots[0]
    if root not in link_names:
        raise ArmError(f"{path}: base_link {root!r} is no link of the URDF")
    if tip_link is None:
        # The deepest leaf below the root (a UR URDF also has the one-joint "base" leaf).
        depth = {root: 0}
        stack = [root]
        while stack:
            link = stack.pop()
            for child in children.get(link, []):
                depth[child] = depth[link] + 1
                stack.append(child)
        leaves = [link for link in depth if not children.get(link)]
        deepest = max(depth[link] for link in leaves)
        candidates = sorted(link for link in leaves if depth[link] == deepest)
        if len(candidates) != 1:
            raise ArmError(
                f"{path}: the URDF branches below {root!r} into {candidates}: "
                "give tip_link in the arm file"
            )
        tip_link = candidates[0]
    if tip_link not in link_names:
        raise ArmError(f"{path}: tip_link {tip_link!r} is no link of the URDF")
    chain = []
    link = tip_link
    while link != root:
        joint = joints_by_child.get(link)
        if joint is None:
            raise ArmError(f"{path}: tip_link {tip_link!r} is not below base_link {root!r}")
        chain.append(joint)
        link = joint.parent
    chain.reverse()

    overrides = {row.name: row for row in (companion.joints if companion else ())}
    pending = np.eye(4)
    base_fixed = np.eye(4)
    moving: list[Any] = []
    origins: list[FloatArray] = []
    for joint in chain:
        origin = _origin_mm(joint.origin)
        if joint.type == _FIXED:
            pending = pending @ origin
            continue
        if joint.type not in _REVOLUTE:
            raise ArmError(
                f"{path}: joint {joint.name!r} is {joint.type}: only revolute, continuous and "
                "fixed joints are supported"
            )
        if not moving:
            base_fixed, pending = pending, np.eye(4)
        origins.append(pending @ origin)
        pending = np.eye(4)
        moving.append(joint)
    if not moving:
        raise ArmError(f"{path}: no revolute joint between {root!r} and {tip_link!r}")
    unknown = set(overrides) - {joint.name for joint in moving}
    if unknown:
        raise ArmError(f"joint {sorted(unknown)[0]!r}: no moving joint of that name in {path}")
    child_links = [joint.child for joint in moving]
    joints = []
    for joint, origin in zip(moving, origins, strict=True):
        row = overrides.get(joint.name)
        limit = joint.limit
        lower = -math.pi if limit is None or limit.lower is None else float(limit.lower)
        upper = math.pi if limit is None or limit.upper is None else float(limit.upper)
        if joint.type == "continuous":
            lower, upper = -math.inf, math.inf
        axis = np.array([0.0, 0.0, 1.0] if joint.axis is None else joint.axis, dtype=np.float64)
        joints.append(
            Joint(
                name=joint.name,
                lower_rad=limit_rad(row.lower_deg if row else None, lower),
                upper_rad=limit_rad(row.upper_deg if row else None, upper),
                motor=build_motor(row.motor if row else None, joint.child),
                grows_with=row.grows_with if row else None,
                origin=origin,
                axis=axis,
            )
        )
    base_transform = np.eye(4) if base is None else base
    tool_transform = pending if tool is None else pending @ tool
    arm = Arm(
        name=name,
        convention="urdf",
        joints=tuple(joints),
        links=build_links(companion.links if companion else (), child_links),
        base=base_transform @ base_fixed,
        tool=tool_transform,
        description=description,
    )
    check_links_named(arm)
    return arm
