"""The UR bench's tool cameras (issue 31): the A465 arm bench's cameras (drivers/sim/arm_bench.py,
drivers/sim/arm_markers.py) on the emulated UR5e.

The emulated controller's truth (drivers/sim/ur/controller.py ``bench``) stands
``camera_rig.count`` cameras around each measured pose of the program it plays, as the arm
bench does for the A465. A frame shows the tool's markers where the *truth* puts them at the
moment of the grab: the arm's actual joints in the controller's current cycle (the program's
path plus the offset it applies) on the true arm (its own seeded geometry) warmed to that
cycle's time (its thermal deformation). The frame is rendered with the arm bench's renderer
(:class:`~drivers.sim.arm_markers.MarkerRenderer`: noise bank, photon and read noise, the
image-plane jitter of the bench); a camera that does not see the tool gives a dark frame, as
the A465's (drivers/sim/arm_devices.py SimArmCamera).

The controller runs on the event loop (drivers/sim/ur/emulator.py), so the truth is read there
(the joints, the warm tool: a millisecond) and only the 5 MP render goes to a worker thread
(off the grab's deadline: drivers/deadline.py): the worker never touches the truth the loop
advances. Each camera draws its noise from its own seeded stream; the cameras share one bank
of dark frames (per image size), rendered when the first camera opens (seconds of CPU: the UR
bench with cameras opens that much slower).
"""

from __future__ import annotations

from typing import Self

import numpy as np
from numpy.typing import NDArray

from daemon.vision.markers import marker_pixels
from daemon.vision.multiview import CameraModel
from drivers.base import Frame
from drivers.clock import Clock
from drivers.deadline import off_the_clock
from drivers.sim.arm_markers import MarkerRenderer
from drivers.sim.ur.controller import URController

#: Keeps the cameras' noise streams apart from the controller's others (its joint sensors'
#: stream is ``[seed, 31]``).
CAMERA_STREAM = 32


class SimURCamera:
    """One of the UR bench's tool cameras (module docstring); an async context manager with
    nothing to open (the emulator is the factory's)."""

    def __init__(
        self, controller: URController, index: int, clock: Clock, renderer: MarkerRenderer
    ) -> None:
        self._controller = controller
        self.index = index
        self.model = renderer.camera
        self._clock = clock
        self._renderer = renderer
        self._jitter_px = controller.bench.config.jitter_px
        self._sequence = 0

    async def __aenter__(self) -> Self:
        # the renderer's bank of dark frames (4 x 5 MP, seconds of CPU) is made now, not at
        # the first grab that sees the tool: that grab falls in a dwell of a fraction of a
        # second (the frame itself, of the markers wherever they are, is thrown away). Not in
        # the background: rendering beside the RTDE stream starved the loop past the driver's
        # 1 s link timeout (seen in `devices check`); before the driver connects it cannot.
        await off_the_clock(self._renderer.render, self.markers_now())
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    def markers_now(self) -> np.ndarray:
        """The markers' true positions (M x 3, world mm) in the controller's current cycle:
        its actual joints on the true arm at that cycle's temperatures. On the event loop."""
        controller = self._controller
        t_s = controller.time_s
        actual, _, _ = controller.joint_state(t_s)
        controller.bench.advance_to(t_s)
        return controller.bench.markers_world_mm(actual)

    async def grab(self) -> Frame:
        now = self._clock.now()
        markers = self.markers_now()
        self._sequence += 1
        # a 5 MP render: computing, not the camera's latency (off a grab's deadline)
        image = await off_the_clock(self._render, markers)
        return Frame(image, self._renderer.rig.bit_depth, now, self._sequence, "camera")

    def _render(self, markers_mm: np.ndarray) -> np.ndarray:
        """On a worker thread: the frame of the markers at ``markers_mm``."""
        _, visible = marker_pixels(self.model, markers_mm)
        if not visible.any():
            # the tool is at another station: a dark frame, not 5 MP of rendered noise
            width, height = self.model.image_size_px
            return np.zeros((height, width), dtype=np.uint16)
        return np.asarray(self._renderer.render(markers_mm, jitter_px=self._jitter_px))


def ur_bench_cameras(
    controller: URController, clock: Clock
) -> tuple[tuple[SimURCamera, ...], tuple[CameraModel, ...]]:
    """The UR bench's cameras and their models (the truth's: a perfectly calibrated rig, as
    the A465 bench's ``camera_models``)."""
    bench = controller.bench
    streams = np.random.SeedSequence([controller.config.seed, CAMERA_STREAM]).spawn(
        len(bench.cameras)
    )
    # one bank of dark frames per image size, shared (MarkerRenderer): six cameras' banks took
    # 13.5 s to render at the bench's opening, one bank a sixth of that
    banks: dict[tuple[int, int], list[NDArray[np.generic]]] = {}
    cameras = tuple(
        SimURCamera(
            controller,
            k,
            clock,
            MarkerRenderer(
                model,
                bench.config.rig,
                np.random.default_rng(stream),
                banks.setdefault(model.image_size_px, []),
            ),
        )
        for k, (model, stream) in enumerate(zip(bench.cameras, streams, strict=True))
    )
    return cameras, bench.cameras


__all__ = ["SimURCamera", "ur_bench_cameras"]
