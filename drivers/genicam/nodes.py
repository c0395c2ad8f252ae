"""pylon and the GenICam node map (drivers/genicam/transport.py's transport, the spot camera's and
the radiometric IR reader's configuration): importing pypylon once, choosing a pixel format,
reading and writing nodes that may not exist on a given camera, loading a feature file."""

from __future__ import annotations

import importlib
import threading
import warnings
from pathlib import Path
from types import ModuleType
from typing import Any

from drivers.errors import NotConnectedError, ProtocolError

#: How to get pypylon when it is missing: the optional extra.
INSTALL_HINT = "install the genicam extra: pip install 'thermocomp[genicam]' (pypylon)"
#: Pixel formats the drivers read, and their significant bits: unpacked mono only, which pylon
#: hands over as uint8 / uint16 arrays.
MONO_FORMATS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono14": 14, "Mono16": 16}
_IMPORT_LOCK = threading.Lock()


def pylon_module() -> ModuleType:
    """``pypylon.pylon``, or NotConnectedError naming the extra to install.

    Its SWIG bindings emit DeprecationWarnings while they load; where warnings are errors
    (``-W error``, the test suite) the extension module then crashes the interpreter instead
    of failing the import, so they are silenced for the (one, locked) import."""
    try:
        with _IMPORT_LOCK, warnings.catch_warnings():
            warnings.filterwarnings("ignore", "builtin type [Ss]wig", DeprecationWarning)
            return importlib.import_module("pypylon.pylon")
    except ImportError as err:
        raise NotConnectedError(
            "genicam", f"pypylon cannot be imported ({err}): {INSTALL_HINT}"
        ) from err


def choose_pixel_format(wanted: str, offered: tuple[str, ...], device: str) -> str:
    """``wanted`` when the camera offers it and the drivers can read it; else one clear line."""
    mono = [name for name in offered if name in MONO_FORMATS]
    if wanted not in MONO_FORMATS:
        raise ProtocolError(
            device, f"unsupported pixel format {wanted}: use one of {', '.join(MONO_FORMATS)}"
        )
    if wanted not in offered:
        raise ProtocolError(
            device,
            f"the camera does not offer pixel format {wanted} (it offers "
            f"{', '.join(mono) or 'no unpacked mono format'})",
        )
    return wanted


def find_node(camera: Any, name: str) -> Any | None:
    """The camera's GenICam node ``name`` when it exists and is available, else None."""
    pylon_module()
    genicam = importlib.import_module("pypylon.genicam")
    try:
        node = camera.GetNodeMap().GetNode(name)
    except Exception:  # pylon raises its own types for unknown names
        return None
    if node is None or not genicam.IsAvailable(node):
        return None
    return node


def has_node(camera: Any, name: str) -> bool:
    """The camera has the node ``name`` and it is available now."""
    return find_node(camera, name) is not None


def node_value(camera: Any, name: str) -> Any | None:
    """A readable node's value (number, or an enumeration's symbolic), else None."""
    node = find_node(camera, name)
    genicam = importlib.import_module("pypylon.genicam")
    if node is None or not genicam.IsReadable(node):
        return None
    value = getattr(camera, name).Value
    return value


def set_node(camera: Any, name: str, value: Any, device: str) -> bool:
    """Write a node if the camera has it writable; False when it has not. A value the camera
    refuses (out of range, wrong step) is one clear line naming the node."""
    node = find_node(camera, name)
    genicam = importlib.import_module("pypylon.genicam")
    if node is None or not genicam.IsWritable(node):
        return False
    try:
        getattr(camera, name).Value = value
    except Exception as err:
        raise ProtocolError(device, f"the camera refuses {name} = {value!r}: {err}") from err
    return True


def load_feature_file(camera: Any, path: Path, device: str) -> None:
    """Write the features of a pylon feature file (``.pfs``: pylon Viewer's "Save Features",
    pypylon ``FeaturePersistence.Save``; a GenApi persistence stream, one ``name<TAB>value``
    per line after its GUID header) to the open camera, validating each value. A missing
    file, an unknown feature or a refused value is one line naming the file."""
    pylon = pylon_module()
    try:
        pylon.FeaturePersistence.Load(str(path), camera.GetNodeMap(), True)
    except Exception as err:  # pylon's RuntimeException, with GenApi's file and line
        first = (str(err).splitlines() or [""])[0]
        reason = first.split(" : ")[0].strip() or type(err).__name__
        raise ProtocolError(device, f"feature file {path}: {reason}") from err
