"""The e-Series controller's modes as RTDE and the Dashboard Server report them (the RTDE
guide's robot_mode, safety_mode and runtime_state; the Dashboard Server's programState,
robotmode and safetystatus answers)."""

from __future__ import annotations

import enum


class RobotMode(enum.IntEnum):
    """RTDE ``robot_mode`` (INT32); the Dashboard's ``Robotmode: NAME``."""

    NO_CONTROLLER = -1
    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7
    UPDATING_FIRMWARE = 8


class SafetyMode(enum.IntEnum):
    """RTDE ``safety_mode`` (INT32); the Dashboard's ``Safetystatus: NAME``."""

    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9
    VALIDATE_JOINT_ID = 10
    UNDEFINED_SAFETY_MODE = 11
    AUTOMATIC_MODE_SAFEGUARD_STOP = 12
    SYSTEM_THREE_POSITION_ENABLING_STOP = 13


class RuntimeState(enum.IntEnum):
    """RTDE ``runtime_state`` (UINT32): the program's state."""

    STOPPING = 0
    STOPPED = 1
    PLAYING = 2
    PAUSING = 3
    PAUSED = 4
    RESUMING = 5


#: The Dashboard's ``programState`` words for the runtime states.
PROGRAM_STATE_WORDS = {
    RuntimeState.STOPPING: "STOPPED",
    RuntimeState.STOPPED: "STOPPED",
    RuntimeState.PLAYING: "PLAYING",
    RuntimeState.PAUSING: "PAUSED",
    RuntimeState.PAUSED: "PAUSED",
    RuntimeState.RESUMING: "PLAYING",
}

#: safety_status_bits (UINT32) bit of each safety mode (the guide: bits 0-10 are normal,
#: reduced, protective stopped, recovery, safeguard stopped, system emergency stopped, robot
#: emergency stopped, emergency stopped, violation, fault, stopped due to safety).
SAFETY_STATUS_BIT = {
    SafetyMode.NORMAL: 0,
    SafetyMode.REDUCED: 1,
    SafetyMode.PROTECTIVE_STOP: 2,
    SafetyMode.RECOVERY: 3,
    SafetyMode.SAFEGUARD_STOP: 4,
    SafetyMode.SYSTEM_EMERGENCY_STOP: 5,
    SafetyMode.ROBOT_EMERGENCY_STOP: 6,
    SafetyMode.VIOLATION: 8,
    SafetyMode.FAULT: 9,
}
#: robot_status_bits (UINT32): bit 0 power on, bit 1 program running.
ROBOT_STATUS_POWER_ON = 1
ROBOT_STATUS_PROGRAM_RUNNING = 2
