"""ur-rtde's own clients (PyPI ``ur-rtde``: RTDEReceiveInterface, RTDEIOInterface,
DashboardClient), driven line by line from a test: ``python -m tests.ur_rtde_clients HOST``
reads one command per line on stdin and answers one JSON line on stdout.

A subprocess, not a thread: ur-rtde's calls block in C++ while holding the interpreter lock,
so called from a thread of the test they would stop the event loop that serves the emulator.

Commands: ``receive`` (a snapshot of RTDEReceiveInterface's getters), ``motion`` (the
controller's timestamp, then the joint speeds, target accelerations and currents, then the
timestamp again: both alike, the three are of one package), ``slider F``
(RTDEIOInterface.setSpeedSlider), ``io_int N V`` and
``io_double N V`` (RTDEIOInterface with the upper range registers), ``dash WORD`` (one
DashboardClient call: play, pause, stop, programState, robotmode, safetystatus,
unlockProtectiveStop), ``quit``.
"""

from __future__ import annotations

import json
import sys
from typing import Any


def main(host: str) -> None:
    import dashboard_client
    import rtde_io
    import rtde_receive

    receiver: Any = None
    io: Any = None
    dashboard: Any = None
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        answer: dict[str, Any] = {}
        try:
            if words[0] == "receive":
                if receiver is None:
                    receiver = rtde_receive.RTDEReceiveInterface(host)
                answer = {
                    "connected": receiver.isConnected(),
                    "timestamp": receiver.getTimestamp(),
                    "q": receiver.getActualQ(),
                    "pose": receiver.getActualTCPPose(),
                    "temperatures": receiver.getJointTemperatures(),
                    "robot_mode": receiver.getRobotMode(),
                    "safety_mode": receiver.getSafetyMode(),
                    "runtime_state": receiver.getRuntimeState(),
                    "protective_stopped": receiver.isProtectiveStopped(),
                }
            elif words[0] == "motion":
                if receiver is None:
                    receiver = rtde_receive.RTDEReceiveInterface(host)
                answer = {
                    "before": receiver.getTimestamp(),
                    "qd": receiver.getActualQd(),
                    "qdd": receiver.getTargetQdd(),
                    "current": receiver.getActualCurrent(),
                    "speed_scaling": receiver.getSpeedScaling(),
                    "after": receiver.getTimestamp(),
                }
            elif words[0] == "slider":
                if io is None:
                    io = rtde_io.RTDEIOInterface(host, use_upper_range_registers=True)
                answer = {"ok": io.setSpeedSlider(float(words[1]))}
            elif words[0] in ("io_int", "io_double"):
                if io is None:
                    io = rtde_io.RTDEIOInterface(host, use_upper_range_registers=True)
                register, value = int(words[1]), words[2]
                if words[0] == "io_int":
                    answer = {"ok": io.setInputIntRegister(register, int(value))}
                else:
                    answer = {"ok": io.setInputDoubleRegister(register, float(value))}
            elif words[0] == "dash":
                if dashboard is None:
                    dashboard = dashboard_client.DashboardClient(host)
                    dashboard.connect()
                result = getattr(dashboard, words[1])()
                answer = {"answer": result}
            elif words[0] == "quit":
                break
            else:
                answer = {"error": f"unknown command {words[0]}"}
        except Exception as err:  # reported to the test, which fails on it
            answer = {"error": f"{type(err).__name__}: {err}"}
        print(json.dumps(answer), flush=True)
    for client in (receiver, io, dashboard):
        if client is not None:
            client.disconnect()


if __name__ == "__main__":
    main(sys.argv[1])
