"""One error hierarchy for every device. Drivers raise these, chained with ``from``."""

from __future__ import annotations


class DeviceError(Exception):
    """A device failed. ``device`` names it ("robot", "camera", "ir")."""

    kind = "device"

    def __init__(self, device: str, message: str) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.message = message


class NotConnectedError(DeviceError):
    """The device's link is not open (never opened, closed, or lost)."""

    kind = "not-connected"


class DeviceTimeoutError(DeviceError, TimeoutError):
    """The device did not answer within the allowed time."""

    kind = "timeout"


class ProtocolError(DeviceError):
    """The device answered something that cannot be understood (garbled, truncated, unreadable
    frame): an error, never a guess."""

    kind = "protocol"


class DeviceReportedError(DeviceError):
    """The device itself reported an error, e.g. C500C motion error 043."""

    kind = "device-reported"

    def __init__(self, device: str, code: int | None, text: str) -> None:
        label = f"error {code:03d}: {text}" if code is not None else text
        super().__init__(device, label)
        self.code = code
        self.text = text


class MotionHeldError(DeviceError):
    """Motion is held after a fault until the caller explicitly resumes."""

    kind = "motion-held"


class PointOfControlError(DeviceReportedError):
    """The operator must press PAUSE/CONTINUE on the controller to give the point of control
    (C500C.md); reported at once instead of waiting for the button."""

    kind = "point-of-control"

    def __init__(self, device: str, text: str) -> None:
        super().__init__(device, None, text)


class GoalLostError(DeviceError):
    """The controller no longer holds the taught operational goal (e.g. it restarted and lost
    its variables): a run whose offsets are from that goal cannot continue (issue 15)."""

    kind = "goal-lost"
