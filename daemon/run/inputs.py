"""Every file and name the settings (and a run) refer to, loaded once before anything opens
(issues 26 and 28): the two-link model's network, the bench's truth network, and on an arm
daemon the arm file, the duty cycle (taught on that arm), the camera file and the arm model.

``thermocomp serve`` checks them before it serves (api/startup.py: exit 2, never 3, which
systemd would retry forever) and ``thermocomp run`` before it opens the devices, so a mistyped
name or a bad file is one line naming it -- with the names that exist and a "did you mean" --
instead of a traceback from deep inside the daemon's start. Blocking (files, a few ms to a
second for an arm's inverse kinematics): call it before the event loop or on a worker.
"""

from __future__ import annotations

from pathlib import Path

from config import Settings
from config.inputs import InputError
from daemon.arm.arm_model import check_fits, load_arm_model, named_arm_model_path
from daemon.arm.controller_loading import load_duty_on
from daemon.arm.loading import load_arm
from daemon.model import load_network
from daemon.model.presets import named_network_path
from daemon.run.arm.setup import arm_file
from daemon.vision.cameras import load_cameras
from drivers.sim.joint_arm import DEFAULT_START_JOINTS_DEG

#: The bench's truth built from the thesis geometry (drivers/sim/bench.py), not a file.
GEOMETRY_TRUTH = "thesis-two-link-geometry"


class ArmBenchError(InputError):
    """An arm the simulated arm bench cannot drive."""


class CameraCountError(InputError):
    """The camera file's cameras do not match the cameras watching the tool."""


def check_inputs(settings: Settings, arm_model: str | None = None) -> None:
    """Load what ``settings`` name (and a run's ``arm_model``); the first problem is raised
    as an :class:`~config.inputs.InputError` whose text is the one line to show."""
    data_dir = settings.storage.data_dir
    load_network(settings.model.network, data_dir)
    bench = settings.bench
    if bench.enabled and bench.truth_network != GEOMETRY_TRUTH:
        load_network(bench.truth_network)
    arm_settings = settings.arm
    if not arm_settings.enabled:
        return
    path = arm_file(settings)
    arm = load_arm(path)
    if bench.enabled and settings.robot.driver == "sim":
        # the arm bench's controller is the C500C console's joint-space emulator: the A465's
        # six axes (drivers/sim/joint_arm.py), which an arm of another count cannot drive
        axes = len(DEFAULT_START_JOINTS_DEG)
        if len(arm.joints) != axes:
            raise ArmBenchError(
                f"arm.arm_file {arm_settings.arm_file}: arm {arm.name!r} has "
                f"{len(arm.joints)} joints; the arm bench's emulated C500C moves {axes}"
            )
    # after the bench's check: an arm the bench cannot drive is the mistake to name, not
    # the duty cycle's joint count that follows from it
    if arm_settings.duty_cycle is not None:
        load_duty_on(arm, path, arm_settings.duty_cycle)
    if arm_settings.cameras_file is not None:
        cameras = load_cameras(Path(arm_settings.cameras_file))
        watching = (
            len(arm_settings.camera_devices)
            if arm_settings.camera_devices
            else arm_settings.cameras
        )
        if len(cameras) != watching:
            source = "arm.camera_devices" if arm_settings.camera_devices else "arm.cameras"
            raise CameraCountError(
                f"{arm_settings.cameras_file}: {len(cameras)} camera(s) but {watching} watch the "
                f"tool ({source}): one model per camera, in the same order"
            )
    if arm_model is not None:
        model = load_arm_model(named_arm_model_path(arm_model, data_dir))
        check_fits(model, arm.name, len(arm.joints))


def check_named_network(settings: Settings, name: str) -> None:
    """A run's network by name (a preset or a network saved in the data directory) loads:
    NetworkNotFoundError when nothing has that name, else an InputError naming the file."""
    load_network(named_network_path(name, settings.storage.data_dir))


def check_named_arm_model(settings: Settings, name: str) -> None:
    """A run's arm model by name loads and fits the daemon's arm: ArmModelNotFoundError when
    nothing has that name, else an InputError naming the file or the mismatch."""
    model = load_arm_model(named_arm_model_path(name, settings.storage.data_dir))
    if settings.arm.enabled:
        arm = load_arm(arm_file(settings))
        check_fits(model, arm.name, len(arm.joints))
