//! The RTDE field names a controller knows and their types (UR's RTDE guide, "Field names
//! and associated types", e-Series 5.x). Unknown names get `NOT_FOUND` from a controller.

use crate::rtde::RtdeType;

use RtdeType::*;

/// Output fields (controller to client) with fixed names.
const OUTPUTS: &[(&str, RtdeType)] = &[
    ("timestamp", Double),
    ("target_q", Vector6d),
    ("target_qd", Vector6d),
    ("target_qdd", Vector6d),
    ("target_current", Vector6d),
    ("target_moment", Vector6d),
    ("actual_q", Vector6d),
    ("actual_qd", Vector6d),
    ("actual_current", Vector6d),
    ("actual_current_window", Vector6d),
    ("joint_control_output", Vector6d),
    ("actual_TCP_pose", Vector6d),
    ("actual_TCP_speed", Vector6d),
    ("actual_TCP_force", Vector6d),
    ("target_TCP_pose", Vector6d),
    ("target_TCP_speed", Vector6d),
    ("actual_digital_input_bits", Uint64),
    ("joint_temperatures", Vector6d),
    ("actual_execution_time", Double),
    ("robot_mode", Int32),
    ("joint_mode", Vector6Int32),
    ("safety_mode", Int32),
    ("safety_status", Int32),
    ("actual_tool_accelerometer", Vector3d),
    ("speed_scaling", Double),
    ("target_speed_fraction", Double),
    ("actual_momentum", Double),
    ("actual_main_voltage", Double),
    ("actual_robot_voltage", Double),
    ("actual_robot_current", Double),
    ("actual_joint_voltage", Vector6d),
    ("actual_digital_output_bits", Uint64),
    ("runtime_state", Uint32),
    ("elbow_position", Vector3d),
    ("elbow_velocity", Vector3d),
    ("robot_status_bits", Uint32),
    ("safety_status_bits", Uint32),
    ("analog_io_types", Uint32),
    ("standard_analog_input0", Double),
    ("standard_analog_input1", Double),
    ("standard_analog_output0", Double),
    ("standard_analog_output1", Double),
    ("io_current", Double),
    ("euromap67_input_bits", Uint32),
    ("euromap67_output_bits", Uint32),
    ("euromap67_24V_voltage", Double),
    ("euromap67_24V_current", Double),
    ("tool_mode", Uint32),
    ("tool_analog_input_types", Uint32),
    ("tool_analog_input0", Double),
    ("tool_analog_input1", Double),
    ("tool_output_voltage", Int32),
    ("tool_output_current", Double),
    ("tool_temperature", Double),
    ("tcp_force_scalar", Double),
    ("output_bit_registers0_to_31", Uint32),
    ("output_bit_registers32_to_63", Uint32),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("tool_output_mode", Uint8),
    ("tool_digital_output0_mode", Uint8),
    ("tool_digital_output1_mode", Uint8),
    ("payload", Double),
    ("payload_cog", Vector3d),
    ("payload_inertia", Vector6d),
    ("script_control_line", Uint32),
    ("ft_raw_wrench", Vector6d),
    ("joint_position_deviation_ratio", Double),
    ("collision_detection_ratio", Double),
    ("time_scale_source", Uint32),
];

/// Input fields (client to controller) with fixed names.
const INPUTS: &[(&str, RtdeType)] = &[
    ("speed_slider_mask", Uint32),
    ("speed_slider_fraction", Double),
    ("standard_digital_output_mask", Uint8),
    ("standard_digital_output", Uint8),
    ("configurable_digital_output_mask", Uint8),
    ("configurable_digital_output", Uint8),
    ("tool_digital_output_mask", Uint8),
    ("tool_digital_output", Uint8),
    ("standard_analog_output_mask", Uint8),
    ("standard_analog_output_type", Uint8),
    ("standard_analog_output_0", Double),
    ("standard_analog_output_1", Double),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("external_force_torque", Vector6d),
];

/// The index `n` of `name` = `{prefix}{n}` when `n` is in `range`.
fn register(name: &str, prefix: &str, range: std::ops::RangeInclusive<u32>) -> bool {
    name.strip_prefix(prefix)
        .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) && !n.starts_with("00"))
        .and_then(|n| n.parse::<u32>().ok())
        .is_some_and(|n| range.contains(&n))
}

/// The general-purpose registers (`{input,output}_{bit,int,double}_register_N`) of `name`.
fn register_type(name: &str) -> Option<RtdeType> {
    for side in ["input_", "output_"] {
        if let Some(rest) = name.strip_prefix(side) {
            if register(rest, "bit_register_", 64..=127) {
                return Some(Bool);
            }
            if register(rest, "int_register_", 0..=47) {
                return Some(Int32);
            }
            if register(rest, "double_register_", 0..=47) {
                return Some(Double);
            }
        }
    }
    None
}

/// The type of output field `name`, `None` when a controller answers `NOT_FOUND`.
pub fn output_type(name: &str) -> Option<RtdeType> {
    OUTPUTS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| *t)
        .or_else(|| register_type(name))
}

/// The type of input field `name`, `None` when a controller answers `NOT_FOUND`.
pub fn input_type(name: &str) -> Option<RtdeType> {
    INPUTS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| *t)
        .or_else(|| register_type(name).filter(|_| name.starts_with("input_")))
}
