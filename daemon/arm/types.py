"""Values passed between the arm's pieces: kinematics, thermal model, duty cycle, vision, bench.

Conventions (every module of ``daemon.arm`` and ``daemon.vision.multiview`` follows them):

- Lengths in mm, angles in rad inside the core (degrees only at the console,
docs/reference/c500c-console.md
  ``wshift <loc>,<dx>,<dy>,<dz>,<zrot>,<yrot>,<xrot>`` in mm / degrees), time in s,
  temperatures in °C, power in W.
- A pose is a 4×4 homogeneous transform (numpy float64) of the tool in the arm's base (world)
  frame.
- A 6-DOF error or correction is ``Pose6``: translation (mm, base frame) and a rotation vector
  (rad, base frame; axis × angle, as ``cv2.Rodrigues`` / ``scipy.spatial.transform.Rotation.
  as_rotvec``). For the console it is converted to the C500C's z-y-x angles with
  ``Pose6.zyx_deg``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

FloatArray = NDArray[np.float64]


def _vector3(values: object, what: str) -> FloatArray:
    array = np.array(values, dtype=np.float64).reshape(-1)
    if array.shape != (3,) or not np.all(np.isfinite(array)):
        raise ValueError(f"{what}: expected three finite numbers, got {values!r}")
    array.setflags(write=False)
    return array


#: SciPy's warning at y = +-90 deg (z-y-x gimbal lock): "Gimbal lock detected. Setting third
#: angle to zero since it is not possible to uniquely determine all angles."
GIMBAL_LOCK_WARNING = "Gimbal lock detected"


def zyx_deg_of(rotation: Rotation) -> tuple[float, float, float]:
    """Intrinsic z-y-x angles (degrees) of ``rotation``: the C500C's world angles (``wshift``'s
    zrot, yrot, xrot; ``w2``'s WORLD row). At y = +-90 deg (a tool pointing straight down or
    up: the A465's camera station) only z -+ x is determined; SciPy then sets x to 0 and warns.
    Any split of z and x is the same rotation (the console and the emulator rebuild the same
    matrix from it), so that warning, and only it, is silenced."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=GIMBAL_LOCK_WARNING, category=UserWarning)
        z, y, x = rotation.as_euler("ZYX", degrees=True)
    return float(z), float(y), float(x)


@dataclass(frozen=True, eq=False)
class Pose6:
    """A small rigid displacement: ``translation_mm`` then ``rotation_rad`` (rotation vector),
    both in the base frame. The tool error of a warm arm and the correction that cancels it
    (``-error``) are both Pose6."""

    translation_mm: FloatArray
    rotation_rad: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "translation_mm", _vector3(self.translation_mm, "translation"))
        object.__setattr__(self, "rotation_rad", _vector3(self.rotation_rad, "rotation"))

    @classmethod
    def zero(cls) -> Pose6:
        return cls(np.zeros(3), np.zeros(3))

    def __neg__(self) -> Pose6:
        return Pose6(-self.translation_mm, -self.rotation_rad)

    def as_array(self) -> FloatArray:
        """``[dx, dy, dz, rx, ry, rz]`` (mm, rad)."""
        return np.concatenate([self.translation_mm, self.rotation_rad])

    @property
    def translation_norm_mm(self) -> float:
        return float(np.linalg.norm(self.translation_mm))

    @property
    def rotation_angle_rad(self) -> float:
        return float(np.linalg.norm(self.rotation_rad))

    def zyx_deg(self) -> tuple[float, float, float]:
        """The rotation as the C500C's ``wshift`` angles (zrot, yrot, xrot), degrees: intrinsic
        z-y-x Euler angles of the same rotation."""
        from scipy.spatial.transform import Rotation

        # a copy: SciPy's Cython rotations refuse the read-only arrays Pose6 holds
        return zyx_deg_of(Rotation.from_rotvec(np.array(self.rotation_rad)))


@dataclass(frozen=True, slots=True)
class LinkThermalState:
    """What a link's temperatures do to its geometry (input of ``kinematics.warm_arm``).

    ``mean_rise_c``: mean temperature rise over the link's length above the temperature its
    kinematic parameters were measured at; the link grows ``alpha_per_c * mean_rise_c`` per
    unit length along its geometry (thesis Eq. 5.x, DESIGN.md "Deformation", generalised).
    ``gradient_c_per_mm``: the mean temperature difference across the link per mm of
    thickness, in the link frame's (y, z) (0, 0 when unknown); bends the link when the
    arm description enables bending.
    """

    link: str
    mean_rise_c: float
    alpha_per_c: float
    gradient_c_per_mm: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True, eq=False)
class JointSample:
    """The arm's motion at one instant: joint positions (rad), speeds (rad/s), accelerations
    (rad/s²), one value per joint. A duty cycle is a sequence of these on a fixed time step."""

    time_s: float
    q_rad: FloatArray
    qd_rad_s: FloatArray
    qdd_rad_s2: FloatArray


def pose_difference(reference: object, current: object) -> Pose6:
    """``current`` relative to ``reference`` (both 4×4 poses in the base frame): the tool
    point's displacement ``t_cur - t_ref`` (mm) and the rotation vector of ``R_cur R_ref^T``
    (rad). A tool error is ``pose_difference(cold, warm)``; the correction that cancels it is its
    negative. The one implementation for kinematics and vision (reference first, always)."""
    from scipy.spatial.transform import Rotation

    poses = []
    for pose, what in ((reference, "reference"), (current, "current")):
        transform = np.asarray(pose, dtype=np.float64)
        if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
            raise ValueError(
                f"{what} pose: expected a finite 4x4 pose, got shape {transform.shape}"
            )
        poses.append(transform)
    ref, cur = poses
    rotvec = Rotation.from_matrix(cur[:3, :3] @ ref[:3, :3].T).as_rotvec()
    return Pose6(cur[:3, 3] - ref[:3, 3], rotvec)
