"""The RTDE variables this project reads, writes or emulates, with their types as the public
RTDE guide lists them (e-Series, PolyScope 5.x), and the registers' numbering.

Registers (the guide, "Controller inputs/outputs"): integer and double registers 0-47 each way
(``input_int_register_N``, ``input_double_register_N``, ``output_int_register_N``,
``output_double_register_N``) and bit registers 64-127 (``input_bit_register_N``,
``output_bit_register_N``). Registers 0-23 are also written or read by the fieldbus adapters
(EtherNet/IP, PROFINET, MODBUS): with one enabled the controller answers ``IN_USE`` for them,
so this project uses the upper range, 24-47 (issue 31; robot.register_base).
"""

from __future__ import annotations

from drivers.ur.rtde_protocol import DataType

#: Registers per kind and direction (0..47) and the first of the upper range.
REGISTER_COUNT = 48
UPPER_RANGE_FIRST = 24
BIT_REGISTERS = range(64, 128)

D, I32, U32, U64 = DataType.DOUBLE, DataType.INT32, DataType.UINT32, DataType.UINT64
V6, V3, V6I, B, U8 = (
    DataType.VECTOR6D,
    DataType.VECTOR3D,
    DataType.VECTOR6INT32,
    DataType.BOOL,
    DataType.UINT8,
)

#: Outputs (controller -> client) with their types, the guide's "Controller outputs" table:
#: every one ur-rtde's RTDEReceiveInterface asks for (it refuses a controller that answers
#: NOT_FOUND to any), and the ones the UR driver reads.
OUTPUTS: dict[str, DataType] = {
    "timestamp": D,
    "target_q": V6,
    "target_qd": V6,
    "target_qdd": V6,
    "target_current": V6,
    "target_moment": V6,
    "actual_q": V6,
    "actual_qd": V6,
    "actual_current": V6,
    "actual_current_as_torque": V6,
    "joint_control_output": V6,
    "actual_TCP_pose": V6,
    "actual_TCP_speed": V6,
    "actual_TCP_force": V6,
    "target_TCP_pose": V6,
    "target_TCP_speed": V6,
    "actual_digital_input_bits": U64,
    "joint_temperatures": V6,
    "actual_execution_time": D,
    "robot_mode": I32,
    "joint_mode": V6I,
    "safety_mode": I32,
    "safety_status": I32,
    "actual_tool_accelerometer": V3,
    "speed_scaling": D,
    "target_speed_fraction": D,
    "actual_momentum": D,
    "actual_main_voltage": D,
    "actual_robot_voltage": D,
    "actual_robot_current": D,
    "actual_joint_voltage": V6,
    "actual_digital_output_bits": U64,
    "runtime_state": U32,
    "elbow_position": V3,
    "elbow_velocity": V3,
    "robot_status_bits": U32,
    "safety_status_bits": U32,
    "analog_io_types": U32,
    "standard_analog_input0": D,
    "standard_analog_input1": D,
    "standard_analog_output0": D,
    "standard_analog_output1": D,
    "io_current": D,
    "euromap67_input_bits": U32,
    "euromap67_output_bits": U32,
    "euromap67_24V_voltage": D,
    "euromap67_24V_current": D,
    "tool_mode": U32,
    "tool_analog_input_types": U32,
    "tool_analog_input0": D,
    "tool_analog_input1": D,
    "tool_output_voltage": I32,
    "tool_output_current": D,
    "tool_temperature": D,
    "tcp_force_scalar": D,
    "output_bit_registers0_to_31": U32,
    "output_bit_registers32_to_63": U32,
    "input_bit_registers0_to_31": U32,
    "input_bit_registers32_to_63": U32,
    "ft_raw_wrench": V6,
    "payload": D,
    "payload_cog": V3,
    "payload_inertia": V6,
}
for _n in range(REGISTER_COUNT):
    OUTPUTS[f"output_int_register_{_n}"] = I32
    OUTPUTS[f"output_double_register_{_n}"] = D
    # the controller reports its input registers as outputs too (the guide)
    OUTPUTS[f"input_int_register_{_n}"] = I32
    OUTPUTS[f"input_double_register_{_n}"] = D
for _n in BIT_REGISTERS:
    OUTPUTS[f"output_bit_register_{_n}"] = B
    OUTPUTS[f"input_bit_register_{_n}"] = B

#: Inputs (client -> controller), the guide's "Controller inputs" table.
INPUTS: dict[str, DataType] = {
    "speed_slider_mask": U32,
    "speed_slider_fraction": D,
    "standard_digital_output_mask": U8,
    "standard_digital_output": U8,
    "configurable_digital_output_mask": U8,
    "configurable_digital_output": U8,
    "tool_digital_output_mask": U8,
    "tool_digital_output": U8,
    "standard_analog_output_mask": U8,
    "standard_analog_output_type": U8,
    "standard_analog_output_0": D,
    "standard_analog_output_1": D,
}
for _n in range(REGISTER_COUNT):
    INPUTS[f"input_int_register_{_n}"] = I32
    INPUTS[f"input_double_register_{_n}"] = D
for _n in BIT_REGISTERS:
    INPUTS[f"input_bit_register_{_n}"] = B


def int_input(n: int) -> str:
    return f"input_int_register_{n}"


def double_input(n: int) -> str:
    return f"input_double_register_{n}"


def int_output(n: int) -> str:
    return f"output_int_register_{n}"


def double_output(n: int) -> str:
    return f"output_double_register_{n}"


def register_number(name: str) -> int | None:
    """N of a numbered register name (``input_int_register_31`` -> 31), else None."""
    head, _, tail = name.rpartition("_")
    if head.endswith("register") and tail.isdigit():
        return int(tail)
    return None
