"""Frames for pylon's camera emulation (CamEmu, ``PYLON_CAMEMU=N``) to serve through the real
GenICam driver (drivers/genicam/transport.py): image files and the feature file that points an
emulated camera at them (``camera.feature_file``).

What the emulation does (measured with pypylon 26.9; tests/test_genicam_markers.py checks it):

- With ``TestImageSelector = Off`` and ``ImageFileMode = On`` an emulated camera serves the
  image file ``ImageFilename`` instead of its test pattern, or, when that names a folder, the
  folder's images one per frame in the order of their names, starting again after the last.
  Different cameras serve different files. The files are read when grabbing starts: a file
  written later is not seen, and ``ImageFilename`` cannot change while the camera grabs.
- PNG and TIFF, 8 or 16 bits per pixel, are converted to the camera's pixel format by their
  most significant bits: a 16-bit file's value ``v`` arrives as ``v`` in Mono16, ``v >> 4``
  in Mono12 and ``v >> 8`` in Mono8. A frame of ``bit_depth`` bits is therefore written as a
  16-bit file of ``counts << (16 - bit_depth)`` (8-bit frames as 8-bit files) and arrives
  exactly, counts for counts.
- A file larger than the ROI is cut to it; a smaller one arrives at its own size (the driver
  refuses such a frame: drivers/genicam/camera.py); a file that cannot be read fails the grab.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

#: The first line of a GenApi persistence stream (pylon's .pfs feature file): without it
#: pylon refuses the file ("missing the magic GUID").
FEATURE_FILE_GUID = "# {05D8C294-F295-4dfb-9D01-096BD04049F4}"
#: Bits per pixel of the image files the emulation reads.
FILE_BITS_8 = 8
FILE_BITS_16 = 16


def emulation_image(frame: NDArray[np.integer], bit_depth: int) -> NDArray[np.integer]:
    """The image file's pixels that the emulation converts back to ``frame`` in pixel format
    ``Mono<bit_depth>`` (module docstring: most significant bits)."""
    counts = np.asarray(frame)
    if counts.ndim != 2:
        raise ValueError(f"a frame is 2-D grey, got shape {counts.shape}")
    if bit_depth not in (8, 10, 12, 16):
        raise ValueError(f"bit_depth must be 8, 10, 12 or 16, got {bit_depth!r}")
    if counts.size and (int(counts.min()) < 0 or int(counts.max()) >= 1 << bit_depth):
        raise ValueError(f"counts outside 0 .. {(1 << bit_depth) - 1} ({bit_depth} bits)")
    if bit_depth == FILE_BITS_8:
        return counts.astype(np.uint8)
    return (counts.astype(np.uint16) << (FILE_BITS_16 - bit_depth)).astype(np.uint16)


def write_emulation_image(path: Path, frame: NDArray[np.integer], bit_depth: int) -> Path:
    """Write ``frame`` (counts of ``bit_depth`` bits) as a PNG or TIFF the emulation serves
    as it is (by ``path``'s suffix)."""
    if not cv2.imwrite(str(path), emulation_image(frame, bit_depth)):
        raise OSError(f"cannot write the image file {path}")
    return path


def write_emulation_frames(
    folder: Path, frames: Sequence[NDArray[np.integer]], bit_depth: int
) -> Path:
    """``frames`` as ``folder``/000000.png, 000001.png, ...: the emulated camera whose
    ``ImageFilename`` is ``folder`` serves them in this order, one per frame, then again."""
    folder.mkdir(parents=True, exist_ok=True)
    for index, frame in enumerate(frames):
        write_emulation_image(folder / f"{index:06d}.png", frame, bit_depth)
    return folder


def write_feature_file(path: Path, image_source: Path) -> Path:
    """A pylon feature file that turns the emulation's test pattern off and serves
    ``image_source`` (a file or a folder): ``camera.feature_file`` of an emulated camera."""
    lines = (
        FEATURE_FILE_GUID,
        "TestImageSelector\tOff",
        "ImageFileMode\tOn",
        f"ImageFilename\t{image_source.resolve()}",
    )
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
