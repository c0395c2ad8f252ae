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
    """The controller waited for the operator to press PAUSE/CONTINUE
    (docs/reference/c500c-console.md "Point of control") longer than the configured timeout
    (robot.point_of_control_timeout_s)."""

    kind = "point-of-control"

    def __init__(self, device: str, text: str) -> None:
        super().__init__(device, None, text)


class GoalLostError(DeviceError):
    """The controller no longer holds the taught operational goal (it restarted, or its
    variables were cleared): the run cannot go on from it. The message starts with "the
    controller lost the taught goal"."""

    kind = "goal-lost"

    def __init__(self, device: str, detail: str) -> None:
        super().__init__(device, f"the controller lost the taught goal ({detail})")
        self.detail = detail


class ConsoleQuestionError(DeviceError):
    """The console asked a question (docs/reference/c500c-console.md "Questions") or printed a
    message after which it will not do what was asked; the command ended with this error instead of
    waiting."""

    kind = "console-question"
