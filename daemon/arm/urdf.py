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

import io
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from config.inputs import read_regular_file
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


#: Largest URDF read (bytes): a robot's kinematic URDF is tens of KiB (ur5e.urdf: 5 KiB).
MAX_URDF_BYTES = 4 * 1024 * 1024
#: Most links (and joints) a URDF may have: a robot hand has ~50.
MAX_URDF_LINKS = 1_000


def _load_urdf(path: Path) -> Any:
    try:
        import yourdfpy
        from lxml import etree
    except ImportError as err:
        raise ArmError(
            f"{path}: reading URDF needs yourdfpy (pip install 'thermocomp[urdf]')"
        ) from err
    data = read_regular_file(path, MAX_URDF_BYTES, "a URDF file", ArmError)
    # Parsed once here with a parser that expands no entity and fetches nothing, so that a
    # "billion laughs" DOCTYPE or a malformed file is one line (yourdfpy would log and retry
    # in recover mode); yourdfpy then reads the same bytes.
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False)
    try:
        tree = etree.fromstring(data, parser=parser).getroottree()
    except etree.XMLSyntaxError as err:
        raise ArmError(f"{path}: not a readable URDF: {err}") from err
    if tree.docinfo.internalDTD is not None:
        raise ArmError(f"{path}: not a readable URDF: a DOCTYPE with entities is not read")
    links = len(tree.getroot().findall("link"))
    joints = len(tree.getroot().findall("joint"))
    if max(links, joints) > MAX_URDF_LINKS:
        raise ArmError(
            f"{path}: {links} links and {joints} joints: a URDF has at most {MAX_URDF_LINKS}"
        )
    quiet = logging.getLogger("yourdfpy")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # its parse errors become our one line below
    try:
        return yourdfpy.URDF.load(
            io.BytesIO(data),
            build_scene_graph=False,
            build_collision_scene_graph=False,
            load_meshes=False,
            load_collision_meshes=False,
        )
    except Exception as err:  # yourdfpy raises lxml, Value and Attribute errors alike
        raise ArmError(f"{path}: not a readable URDF: {err}") from err
    finally:
        quiet.setLevel(level)


def _tree(path: Path, robot: Any) -> tuple[dict[str, Any], dict[str, list[str]], list[str]]:
    """The URDF's joints by child link, children by parent link, and link names, checked to be
    a tree (issue 26: a cycle made the walk below loop forever): every joint joins two
    declared links, no link is the child of two joints or of itself, and no joint leads back
    to a link above it."""
    link_names = [link.name for link in robot.links]
    known = set(link_names)
    joints_by_child: dict[str, Any] = {}
    children: dict[str, list[str]] = {}
    for joint in robot.joints:
        for end in (joint.parent, joint.child):
            if end not in known:
                raise ArmError(f"{path}: joint {joint.name!r} names link {end!r}, which is no link")
        if joint.parent == joint.child:
            raise ArmError(f"{path}: joint {joint.name!r} joins link {joint.child!r} to itself")
        if joint.child in joints_by_child:
            raise ArmError(
                f"{path}: link {joint.child!r} has more than one parent joint "
                f"({joints_by_child[joint.child].name!r} and {joint.name!r}): a URDF is a tree"
            )
        joints_by_child[joint.child] = joint
        children.setdefault(joint.parent, []).append(joint.child)
    for start in link_names:  # walk up from each link: a cycle comes back to a link seen
        seen = {start}
        link = start
        while link in joints_by_child:
            link = joints_by_child[link].parent
            if link in seen:
                raise ArmError(f"{path}: the joints form a cycle through link {link!r}")
            seen.add(link)
    return joints_by_child, children, link_names


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
    joints_by_child, children, link_names = _tree(path, robot)
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
