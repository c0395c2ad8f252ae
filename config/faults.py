"""Fault-injection specs of the simulated devices: ``KIND[=SECONDS][@N|%P],...``.

One syntax for every simulated device: the C500C emulator's serial faults (``--faults``,
drivers/sim/emulator.py) and the bench camera's and IR reader's sensor faults
(``bench.camera_faults``, ``bench.ir_faults``, drivers/sim/devices.py). It lives in ``config``
because a spec is a setting, checked when the settings load (a bad spec exits 2 naming the
field), and ``config`` may not import ``drivers``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, Literal, TypeVar

if TYPE_CHECKING:  # settings load without NumPy: `thermocomp <command> --help` stays light
    import numpy as np

KindT = TypeVar("KindT", bound=str)

#: Sensor faults of the simulated camera and IR reader (issue 10). no-frame: the grab/read
#: never returns; late: the frame/reading is delivered SECONDS after its exposure (its
#: timestamp); unreadable: the device delivers data the driver's own checks refuse.
SensorFaultKind = Literal["no-frame", "late", "unreadable"]
SENSOR_FAULT_KINDS: tuple[SensorFaultKind, ...] = ("no-frame", "late", "unreadable")

_FAULT_ITEM = re.compile(
    r"^(?P<kind>[a-z][a-z-]*)(?:=(?P<seconds>[0-9.]+))?(?:@(?P<at>\d+)|%(?P<p>[0-9.]+))?$"
)


@dataclass(frozen=True, slots=True)
class Fault(Generic[KindT]):
    """One injected fault. ``at_count`` (1-based count of the device's events since it
    opened: command lines, grabs, reads) or ``probability`` (per event, seeded) decide when it
    strikes; neither means the next event (faults injected by hand)."""

    kind: KindT
    seconds: float | None = None
    at_count: int | None = None
    probability: float | None = None

    def strikes(self, count: int, rng: np.random.Generator) -> bool:
        """Whether it strikes the ``count``-th event; a probability draws from ``rng``."""
        if self.at_count == count:
            return True
        return self.probability is not None and rng.random() < self.probability


def parse_faults(spec: str, kinds: tuple[KindT, ...]) -> tuple[Fault[KindT], ...]:
    """Parse ``KIND[=SECONDS][@N|%P],...`` with KIND one of ``kinds``: e.g.
    ``drop@5,delay=2@7,corrupt%0.01``. ``@N`` strikes at the N-th event, ``%P`` at every event
    with probability P. Raises ValueError with a message naming the bad item."""
    faults: list[Fault[KindT]] = []
    for item in filter(None, (part.strip() for part in spec.split(","))):
        match = _FAULT_ITEM.match(item)
        if match is None or match["kind"] not in kinds:
            raise ValueError(
                f"bad fault {item!r}: expected KIND[=SECONDS][@N|%P] with KIND one of "
                + ", ".join(kinds)
            )
        try:
            seconds = float(match["seconds"]) if match["seconds"] else None
            probability = float(match["p"]) if match["p"] else None
        except ValueError:  # e.g. "1.2.3"
            raise ValueError(f"bad fault {item!r}: not a number") from None
        if probability is not None and not 0.0 <= probability <= 1.0:
            raise ValueError(f"bad fault {item!r}: probability must be within 0..1")
        if match["at"] is None and probability is None:
            raise ValueError(f"bad fault {item!r}: say when with @N or %P")
        at_count = int(match["at"]) if match["at"] else None
        if at_count == 0:
            raise ValueError(f"bad fault {item!r}: @N counts from 1")
        faults.append(
            Fault(
                kind=kinds[kinds.index(match["kind"])],
                seconds=seconds,
                at_count=at_count,
                probability=probability,
            )
        )
    return tuple(faults)


def parse_sensor_faults(spec: str) -> tuple[Fault[SensorFaultKind], ...]:
    """Parse a camera or IR fault spec (SENSOR_FAULT_KINDS): ``late`` needs ``=SECONDS``,
    the other kinds take none."""
    faults: list[Fault[SensorFaultKind]] = []
    for item in filter(None, (part.strip() for part in spec.split(","))):
        (fault,) = parse_faults(item, SENSOR_FAULT_KINDS)
        if fault.kind == "late" and not fault.seconds:
            raise ValueError(f"bad fault {item!r}: late needs =SECONDS > 0, e.g. late=3@5")
        if fault.kind != "late" and fault.seconds is not None:
            raise ValueError(f"bad fault {item!r}: {fault.kind} takes no =SECONDS")
        faults.append(fault)
    return tuple(faults)
