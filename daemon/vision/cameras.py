"""Camera models for 3-D measurement (issue 20): OpenCV's pinhole camera with distortion, a pose in
the world (the arm's base frame), and the TOML camera file that lists them.

The model is OpenCV's (``cv2.projectPoints``; docs.opencv.org, "Camera Calibration and 3D
Reconstruction"): a world point X (mm) goes to the camera frame as ``Xc = R X + t`` (``R`` from
the rotation vector ``rotation_rad``, ``t = translation_mm``: the pose *world -> camera*), is
divided by its depth, distorted by the coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``
and mapped to pixels by ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``. Pixel centres are at
integer coordinates, x to the right and y down: the convention of the centroid
(DESIGN.md "Centroid"), which is OpenCV's.

A camera file::

    [[cameras]]
    name = "front"
    width_px = 752
    height_px = 582
    focal_px = [2400.0, 2400.0]         # fx, fy
    principal_px = [375.5, 290.5]       # cx, cy
    distortion = [0.0, 0.0, 0.0, 0.0, 0.0]
    pixel_sigma_px = 0.02               # 1-sigma centroid noise, when a frame gives none
    # the pose, world -> camera, either as OpenCV's rvec / tvec ...
    rotation_rad = [1.5708, 0.0, 0.0]
    translation_mm = [0.0, 0.0, 800.0]
    # ... or as where the camera stands and what it looks at (optical axis = camera +z,
    # image rows = camera +y, chosen so that `up` points up the image):
    # position_mm = [0.0, -800.0, 300.0]
    # look_at_mm = [0.0, 0.0, 300.0]
    # up = [0.0, 0.0, 1.0]

``thermocomp calibrate cameras`` writes the rvec / tvec form, with the standard errors of the
fit as ``rotation_se_rad`` / ``translation_se_mm`` (kept, not used by the measurement).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from config.inputs import InputError
from config.settings import read_toml

FloatArray = NDArray[np.float64]

#: OpenCV's distortion vectors have 4, 5, 8, 12 or 14 coefficients (k1, k2, p1, p2, k3, ...).
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
#: Smallest angle between the optical axis and `up` for a look-at pose to be defined (rad).
_MIN_UP_ANGLE_RAD = 1e-3


class CameraFileError(InputError):
    """A camera file or camera definition is unusable; ``str()`` is the one line for the user
    (it names the file, the camera and the field)."""


def _vector(values: object, length: int, what: str) -> FloatArray:
    array = np.array(values, dtype=np.float64).reshape(-1)
    if array.shape != (length,) or not np.all(np.isfinite(array)):
        raise CameraFileError(f"{what}: expected {length} finite numbers, got {values!r}")
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class CameraModel:
    """One calibrated camera: intrinsics, distortion, pose world -> camera, image size, noise.

    ``rotation_rad`` is OpenCV's rotation vector (Rodrigues) and ``translation_mm`` its tvec:
    a world point X is ``R X + t`` in the camera frame. ``pixel_sigma_px`` is the 1-sigma noise
    of one centroid on this camera (each axis), used when a measurement brings none of its own.
    ``rotation_se_rad`` / ``translation_se_mm`` are the standard errors of a pose calibration
    (zeros when the pose was given, not fitted).
    """

    name: str
    matrix: FloatArray  # K, 3x3
    distortion: FloatArray  # OpenCV order (k1, k2, p1, p2[, k3[, ...]])
    rotation_rad: FloatArray
    translation_mm: FloatArray
    image_size_px: tuple[int, int]  # (width, height)
    pixel_sigma_px: float = 0.05
    rotation_se_rad: FloatArray = field(default_factory=lambda: np.zeros(3))
    translation_se_mm: FloatArray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        matrix = np.array(self.matrix, dtype=np.float64)
        if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
            raise CameraFileError(f"camera {self.name!r}: matrix: expected a finite 3x3 K")
        if matrix[0, 0] <= 0 or matrix[1, 1] <= 0:
            raise CameraFileError(f"camera {self.name!r}: focal lengths must be positive")
        if not np.allclose(matrix[2], [0.0, 0.0, 1.0]) or matrix[1, 0] != 0.0:
            raise CameraFileError(
                f"camera {self.name!r}: matrix: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]"
            )
        matrix.setflags(write=False)
        object.__setattr__(self, "matrix", matrix)
        distortion = np.array(self.distortion, dtype=np.float64).reshape(-1)
        if distortion.size not in DISTORTION_LENGTHS or not np.all(np.isfinite(distortion)):
            raise CameraFileError(
                f"camera {self.name!r}: distortion: OpenCV takes 4, 5, 8, 12 or 14 finite "
                f"coefficients (k1, k2, p1, p2[, k3, ...]), got {distortion.size}"
            )
        distortion.setflags(write=False)
        object.__setattr__(self, "distortion", distortion)
        for name, what in (
            ("rotation_rad", "rotation_rad"),
            ("translation_mm", "translation_mm"),
            ("rotation_se_rad", "rotation_se_rad"),
            ("translation_se_mm", "translation_se_mm"),
        ):
            try:
                value = _vector(getattr(self, name), 3, what)
            except CameraFileError as err:
                raise CameraFileError(f"camera {self.name!r}: {err}") from err
            object.__setattr__(self, name, value)
        width, height = self.image_size_px
        if width <= 0 or height <= 0:
            raise CameraFileError(f"camera {self.name!r}: the image size must be positive")
        object.__setattr__(self, "image_size_px", (int(width), int(height)))
        if not (np.isfinite(self.pixel_sigma_px) and self.pixel_sigma_px > 0):
            raise CameraFileError(f"camera {self.name!r}: pixel_sigma_px must be positive")

    @property
    def rotation_matrix(self) -> FloatArray:
        """R of the pose world -> camera."""
        rotation, _ = cv2.Rodrigues(self.rotation_rad)
        return np.asarray(rotation, dtype=np.float64)

    @property
    def centre_mm(self) -> FloatArray:
        """The projection centre in the world: ``-R^T t``."""
        return np.asarray(-self.rotation_matrix.T @ self.translation_mm, dtype=np.float64)

    @property
    def world_to_camera(self) -> FloatArray:
        """The pose world -> camera as a 4x4 transform."""
        transform = np.eye(4)
        transform[:3, :3] = self.rotation_matrix
        transform[:3, 3] = self.translation_mm
        return transform

    def with_pose(
        self,
        rotation_rad: Sequence[float] | FloatArray,
        translation_mm: Sequence[float] | FloatArray,
        *,
        rotation_se_rad: Sequence[float] | FloatArray | None = None,
        translation_se_mm: Sequence[float] | FloatArray | None = None,
    ) -> CameraModel:
        """The same camera at another pose (standard errors zero unless given)."""
        return CameraModel(
            name=self.name,
            matrix=self.matrix,
            distortion=self.distortion,
            rotation_rad=np.asarray(rotation_rad, dtype=np.float64),
            translation_mm=np.asarray(translation_mm, dtype=np.float64),
            image_size_px=self.image_size_px,
            pixel_sigma_px=self.pixel_sigma_px,
            rotation_se_rad=np.zeros(3) if rotation_se_rad is None else np.asarray(rotation_se_rad),
            translation_se_mm=(
                np.zeros(3) if translation_se_mm is None else np.asarray(translation_se_mm)
            ),
        )


def intrinsic_matrix(
    focal_px: tuple[float, float], principal_px: tuple[float, float], skew: float = 0.0
) -> FloatArray:
    """K from the focal lengths and the principal point (px)."""
    (fx, fy), (cx, cy) = focal_px, principal_px
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def look_at(
    position_mm: Sequence[float] | FloatArray,
    target_mm: Sequence[float] | FloatArray,
    up: Sequence[float] | FloatArray = (0.0, 0.0, 1.0),
) -> tuple[FloatArray, FloatArray]:
    """OpenCV's (rvec, tvec) of a camera at ``position_mm`` whose optical axis (camera +z)
    points at ``target_mm``, turned so that ``up`` points up the image (camera -y)."""
    centre = _vector(position_mm, 3, "position_mm")
    target = _vector(target_mm, 3, "look_at_mm")
    up_vector = _vector(up, 3, "up")
    forward = target - centre
    distance = float(np.linalg.norm(forward))
    if distance == 0.0:
        raise CameraFileError("look_at_mm: the camera cannot look at its own position")
    forward /= distance
    right = np.cross(forward, up_vector)
    norm = float(np.linalg.norm(right))
    if norm < _MIN_UP_ANGLE_RAD * float(np.linalg.norm(up_vector)):
        raise CameraFileError("up: parallel to the optical axis; choose another up vector")
    right /= norm
    down = np.cross(forward, right)
    rotation = np.vstack([right, down, forward])  # rows: camera x, y, z in world coordinates
    rvec, _ = cv2.Rodrigues(rotation)
    return np.asarray(rvec, dtype=np.float64).reshape(3), -rotation @ centre


#: Largest image side of a camera file (px): a 16k sensor; a bigger one would allocate
#: gigabytes per frame on the bench (issue 26).
MAX_IMAGE_SIDE_PX = 16_384
#: Most cameras in one camera file.
MAX_CAMERAS = 64


class _Strict(BaseModel):
    # allow_inf_nan=False: TOML's nan and inf are refused naming the field
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _CameraEntry(_Strict):
    name: str = Field(min_length=1)
    width_px: int = Field(gt=0, le=MAX_IMAGE_SIDE_PX)
    height_px: int = Field(gt=0, le=MAX_IMAGE_SIDE_PX)
    focal_px: tuple[float, float]
    principal_px: tuple[float, float]
    skew: float = 0.0
    distortion: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0])
    pixel_sigma_px: float = Field(0.05, gt=0)
    rotation_rad: tuple[float, float, float] | None = None
    translation_mm: tuple[float, float, float] | None = None
    position_mm: tuple[float, float, float] | None = None
    look_at_mm: tuple[float, float, float] | None = None
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    rotation_se_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation_se_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @model_validator(mode="after")
    def _one_pose(self) -> _CameraEntry:
        explicit = self.rotation_rad is not None or self.translation_mm is not None
        aimed = self.position_mm is not None or self.look_at_mm is not None
        if explicit == aimed:
            raise ValueError(
                "give the pose either as rotation_rad + translation_mm or as position_mm + "
                "look_at_mm (exactly one of the two)"
            )
        if explicit and (self.rotation_rad is None or self.translation_mm is None):
            raise ValueError("rotation_rad and translation_mm go together")
        if aimed and (self.position_mm is None or self.look_at_mm is None):
            raise ValueError("position_mm and look_at_mm go together")
        return self


class _CameraFile(_Strict):
    cameras: list[_CameraEntry] = Field(min_length=1, max_length=MAX_CAMERAS)


def _describe(err: ValidationError, data: dict[str, Any]) -> str:
    problems = []
    for problem in err.errors():
        location = list(problem["loc"])
        where = ".".join(str(part) for part in location)
        if len(location) >= 2 and location[0] == "cameras" and isinstance(location[1], int):
            entries = data.get("cameras")
            name: object = None
            if isinstance(entries, list) and location[1] < len(entries):
                entry = entries[location[1]]
                name = entry.get("name") if isinstance(entry, dict) else None
            label = f"camera {name!r}" if name is not None else f"cameras[{location[1]}]"
            where = label + (": " + ".".join(str(p) for p in location[2:]) if location[2:] else "")
        message = str(problem["msg"]).removeprefix("Value error, ")
        problems.append(f"{where}: {message}")
    return "; ".join(problems)


def cameras_from_mapping(data: dict[str, Any]) -> tuple[CameraModel, ...]:
    """Cameras from a parsed camera file (its ``[[cameras]]`` tables)."""
    try:
        parsed = _CameraFile.model_validate(data)
    except ValidationError as err:
        raise CameraFileError(_describe(err, data)) from err
    cameras: list[CameraModel] = []
    for entry in parsed.cameras:
        if entry.name in {camera.name for camera in cameras}:
            raise CameraFileError(f"camera {entry.name!r}: name: used by two cameras")
        if entry.rotation_rad is not None and entry.translation_mm is not None:
            rvec, tvec = np.array(entry.rotation_rad), np.array(entry.translation_mm)
        else:
            assert entry.position_mm is not None and entry.look_at_mm is not None
            try:
                rvec, tvec = look_at(entry.position_mm, entry.look_at_mm, entry.up)
            except CameraFileError as err:
                raise CameraFileError(f"camera {entry.name!r}: {err}") from err
        cameras.append(
            CameraModel(
                name=entry.name,
                matrix=intrinsic_matrix(entry.focal_px, entry.principal_px, entry.skew),
                distortion=np.array(entry.distortion),
                rotation_rad=rvec,
                translation_mm=tvec,
                image_size_px=(entry.width_px, entry.height_px),
                pixel_sigma_px=entry.pixel_sigma_px,
                rotation_se_rad=np.array(entry.rotation_se_rad),
                translation_se_mm=np.array(entry.translation_se_mm),
            )
        )
    return tuple(cameras)


def load_cameras(path: str | Path) -> tuple[CameraModel, ...]:
    """The cameras of a TOML camera file (module docstring); :class:`CameraFileError` names the
    file, the camera and the field of any problem."""
    path = Path(path)
    data = read_toml(path, CameraFileError)
    try:
        return cameras_from_mapping(data)
    except CameraFileError as err:
        raise CameraFileError(f"{path}: {err}") from err


def _numbers(values: Sequence[float] | FloatArray, digits: int = 10) -> str:
    return "[" + ", ".join(f"{float(v):.{digits}g}" for v in values) + "]"


def cameras_toml(cameras: Sequence[CameraModel]) -> str:
    """The camera file of ``cameras`` (the rvec / tvec form, standard errors included), which
    :func:`load_cameras` reads back to the same cameras."""
    blocks = []
    for camera in cameras:
        matrix = camera.matrix
        lines = [
            "[[cameras]]",
            f"name = {json.dumps(camera.name)}",
            f"width_px = {camera.image_size_px[0]}",
            f"height_px = {camera.image_size_px[1]}",
            f"focal_px = {_numbers([matrix[0, 0], matrix[1, 1]])}",
            f"principal_px = {_numbers([matrix[0, 2], matrix[1, 2]])}",
        ]
        if matrix[0, 1] != 0.0:
            lines.append(f"skew = {float(matrix[0, 1]):.10g}")
        lines += [
            f"distortion = {_numbers(camera.distortion)}",
            f"pixel_sigma_px = {camera.pixel_sigma_px:.6g}",
            f"rotation_rad = {_numbers(camera.rotation_rad, 12)}",
            f"translation_mm = {_numbers(camera.translation_mm, 12)}",
        ]
        if np.any(camera.rotation_se_rad) or np.any(camera.translation_se_mm):
            lines += [
                f"rotation_se_rad = {_numbers(camera.rotation_se_rad, 4)}  # 1 sigma",
                f"translation_se_mm = {_numbers(camera.translation_se_mm, 4)}  # 1 sigma",
            ]
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks) + "\n"


def write_cameras(path: str | Path, cameras: Sequence[CameraModel]) -> None:
    """Write ``cameras`` as a camera file (replacing ``path``)."""
    Path(path).write_text(cameras_toml(cameras), encoding="utf-8")
