//! Golden bytes and lines from the published documents and reference clients:
//! - RTDE: UR's RTDE guide and `rtde/rtde.py` + `rtde/serialize.py` of UR's
//!   RTDE_Python_Client_Library (`struct.pack(">HB", size, cmd)`, `">H"` version, `">d"`
//!   frequency + comma-joined names, `">IIII"` version reply, `">B"` success bytes), and
//!   ur_rtde's `rtde.cpp` (`htons(size)`, payload `{0x00, 0x02}` for the version request,
//!   output names each followed by a comma).
//! - Dashboard: UR's "Dashboard Server e-Series" command table and ur_rtde's
//!   `dashboard_client.cpp` (the reply strings it compares against).
//! - URScript: python-urx's `_format_move` (`movej([q...], a=.., v=.., r=..)`).

use ur::dashboard::{self, Command, RobotMode, SafetyMode};
use ur::rtde::{
    decode_values, encode_values, ClientPackage, FrameDecoder, MessageLevel, RtdeType,
    ServerPackage, TextMessage, Value,
};
use ur::script::{self, Statement};

fn hex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

#[test]
fn rtde_client_packages_match_the_reference_clients_bytes() {
    // rtde.py: struct.pack(">HB", 5, 86) + struct.pack(">H", 2); ur_rtde: {0x00, 0x02}
    let v = ClientPackage::RequestProtocolVersion(2).encode().unwrap();
    assert_eq!(v, hex("0005 56 0002"));
    assert_eq!(
        ClientPackage::GetUrcontrolVersion.encode().unwrap(),
        hex("0003 76")
    );
    assert_eq!(ClientPackage::Start.encode().unwrap(), hex("0003 53"));
    assert_eq!(ClientPackage::Pause.encode().unwrap(), hex("0003 50"));
    // rtde.py: struct.pack(">d", 125) + b"actual_q,robot_mode"
    let o = ClientPackage::SetupOutputs {
        frequency: 125.0,
        names: vec!["actual_q".into(), "robot_mode".into()],
    }
    .encode()
    .unwrap();
    let mut want = hex("001e 4f 405f400000000000");
    want.extend_from_slice(b"actual_q,robot_mode");
    assert_eq!(o, want);
    // the same decoded back, and ur_rtde's trailing comma read as no extra name
    let mut d = FrameDecoder::new();
    d.push(&o);
    let mut ur_rtde = hex("001f 4f 405f400000000000");
    ur_rtde.extend_from_slice(b"actual_q,robot_mode,");
    d.push(&ur_rtde);
    for _ in 0..2 {
        match d.next_client().unwrap().unwrap() {
            ClientPackage::SetupOutputs { frequency, names } => {
                assert_eq!(frequency, 125.0);
                assert_eq!(names, ["actual_q", "robot_mode"]);
            }
            other => panic!("{other:?}"),
        }
    }
    // rtde.py send_input_setup: the names joined by commas
    let i = ClientPackage::SetupInputs(vec!["input_int_register_0".into()])
        .encode()
        .unwrap();
    let mut want = hex("0017 49");
    want.extend_from_slice(b"input_int_register_0");
    assert_eq!(i, want);
}

#[test]
fn rtde_controller_packages_match_the_guide() {
    assert_eq!(
        ServerPackage::ProtocolVersion(true).encode().unwrap(),
        hex("0004 56 01")
    );
    // ">IIII": 5.11.1.108318
    let v = ServerPackage::UrcontrolVersion {
        major: 5,
        minor: 11,
        bugfix: 1,
        build: 108318,
    };
    let bytes = v.encode().unwrap();
    assert_eq!(bytes, hex("0013 76 00000005 0000000b 00000001 0001a71e"));
    assert_eq!(ServerPackage::decode(b'v', &bytes[3..]).unwrap(), v);
    // setup outputs reply: recipe id byte + comma-separated types
    let mut o = hex("0012 4f 01");
    o.extend_from_slice(b"VECTOR6D,INT32");
    assert_eq!(
        ServerPackage::SetupOutputs {
            recipe: 1,
            types: vec!["VECTOR6D".into(), "INT32".into()]
        }
        .encode()
        .unwrap(),
        o
    );
    // data package: recipe 1, robot_mode INT32 7, safety_mode INT32 1, runtime_state UINT32 2
    let values = [Value::Int32(7), Value::Int32(1), Value::Uint32(2)];
    let data = ServerPackage::Data {
        recipe: 1,
        values: encode_values(&values),
    }
    .encode()
    .unwrap();
    assert_eq!(data, hex("0010 55 01 00000007 00000001 00000002"));
    let types = [RtdeType::Int32, RtdeType::Int32, RtdeType::Uint32];
    assert_eq!(decode_values(&types, &data[4..]).unwrap(), values);
    // VECTOR6D: six big-endian doubles (">dddddd"); 1.0 = 3ff0000000000000
    let v6 = encode_values(&[Value::Vector6d([1.0, 0.0, 0.0, 0.0, 0.0, -2.0])]);
    assert_eq!(
        v6,
        hex("3ff0000000000000 0000000000000000 0000000000000000 \
             0000000000000000 0000000000000000 c000000000000000")
    );
    // text message v2 (serialize.Message): len, message, len, source, level
    let t = ServerPackage::Text(TextMessage {
        message: "hi".into(),
        source: "RTDE".into(),
        level: MessageLevel::Warning,
    })
    .encode()
    .unwrap();
    let mut want = hex("000c 4d 02");
    want.extend_from_slice(b"hi");
    want.push(4);
    want.extend_from_slice(b"RTDE");
    want.push(2);
    assert_eq!(t, want);
    // start / pause replies: one success byte
    assert_eq!(
        ServerPackage::decode(b'S', &[1]).unwrap(),
        ServerPackage::Start(true)
    );
    assert_eq!(
        ServerPackage::decode(b'P', &[0]).unwrap(),
        ServerPackage::Pause(false)
    );
}

#[test]
fn rtde_field_types_are_the_guides() {
    use ur::vars::{input_type, output_type};
    for (name, ty) in [
        ("timestamp", RtdeType::Double),
        ("actual_q", RtdeType::Vector6d),
        ("actual_qd", RtdeType::Vector6d),
        ("target_q", RtdeType::Vector6d),
        ("robot_mode", RtdeType::Int32),
        ("safety_mode", RtdeType::Int32),
        ("runtime_state", RtdeType::Uint32),
        ("robot_status_bits", RtdeType::Uint32),
        ("safety_status_bits", RtdeType::Uint32),
        ("joint_mode", RtdeType::Vector6Int32),
        ("actual_digital_input_bits", RtdeType::Uint64),
        ("actual_tool_accelerometer", RtdeType::Vector3d),
        ("output_int_register_0", RtdeType::Int32),
        ("output_int_register_47", RtdeType::Int32),
        ("output_double_register_19", RtdeType::Double),
        ("output_bit_register_64", RtdeType::Bool),
    ] {
        assert_eq!(output_type(name), Some(ty), "{name}");
    }
    for bad in [
        "output_int_register_48",
        "output_int_register_",
        "output_bit_register_63",
        "actual_Q",
        "",
    ] {
        assert_eq!(output_type(bad), None, "{bad}");
    }
    assert_eq!(input_type("input_int_register_0"), Some(RtdeType::Int32));
    assert_eq!(input_type("speed_slider_fraction"), Some(RtdeType::Double));
    assert_eq!(input_type("output_int_register_0"), None);
    assert_eq!(input_type("actual_q"), None);
}

#[test]
fn dashboard_commands_and_replies_are_the_documented_lines() {
    for (cmd, line) in [
        (Command::PowerOn, "power on"),
        (Command::BrakeRelease, "brake release"),
        (Command::RobotMode, "robotmode"),
        (Command::SafetyStatus, "safetystatus"),
        (Command::SafetyMode, "safetymode"),
        (Command::IsInRemoteControl, "is in remote control"),
        (Command::Stop, "stop"),
        (Command::UnlockProtectiveStop, "unlock protective stop"),
        (Command::ClosePopup, "close popup"),
        (Command::CloseSafetyPopup, "close safety popup"),
        (Command::Quit, "quit"),
        (Command::PolyscopeVersion, "PolyscopeVersion"),
    ] {
        assert_eq!(cmd.text(), line);
        assert_eq!(Command::parse(line), Some(cmd.clone()), "{line}");
        // a controller takes commands case-insensitively
        assert_eq!(Command::parse(&line.to_uppercase()), Some(cmd));
    }
    assert_eq!(
        Command::parse("popup Calibration running"),
        Some(Command::Popup("Calibration running".into()))
    );
    assert_eq!(Command::parse("power onn"), None);
    assert_eq!(
        dashboard::not_understood("power onn"),
        "could not understand: 'power onn'"
    );
    assert_eq!(
        dashboard::BANNER,
        "Connected: Universal Robots Dashboard Server"
    );
    assert_eq!(
        dashboard::parse_robot_mode("Robotmode: RUNNING"),
        Some(RobotMode::Running)
    );
    assert_eq!(
        dashboard::parse_robot_mode("Robotmode: POWER_OFF\n"),
        Some(RobotMode::PowerOff)
    );
    assert_eq!(
        dashboard::parse_safety_mode("Safetystatus: PROTECTIVE_STOP"),
        Some(SafetyMode::ProtectiveStop)
    );
    assert_eq!(
        dashboard::parse_safety_mode("Safetymode: ROBOT_EMERGENCY_STOP"),
        Some(SafetyMode::RobotEmergencyStop)
    );
    assert_eq!(dashboard::parse_safety_mode("Robotmode: RUNNING"), None);
    assert_eq!(dashboard::parse_remote_control("true"), Some(true));
    assert_eq!(dashboard::parse_remote_control("false"), Some(false));
    assert_eq!(
        dashboard::parse_remote_control("Command is not allowed"),
        None
    );
    // RTDE integers (RTDE guide: robot_mode, safety_mode)
    assert_eq!(RobotMode::Running.code(), 7);
    assert_eq!(RobotMode::PowerOff.code(), 3);
    assert_eq!(RobotMode::NoController.code(), -1);
    assert_eq!(SafetyMode::Normal.code(), 1);
    assert_eq!(SafetyMode::ProtectiveStop.code(), 3);
    assert_eq!(SafetyMode::RobotEmergencyStop.code(), 7);
    assert_eq!(SafetyMode::SystemEmergencyStop.code(), 6);
}

#[test]
fn urscript_is_what_urx_and_ur_rtde_send_and_the_subset_parses() {
    let q = [0.1, -std::f64::consts::FRAC_PI_2, 1.0, 0.0, -0.5, 2.0];
    let m = script::movej(&q, 1.4, 1.05).unwrap();
    assert_eq!(
        m,
        "movej([0.1, -1.5707963267948966, 1, 0, -0.5, 2], a=1.4, v=1.05)"
    );
    let p = script::program("cellcal_move", &[m]).unwrap();
    assert_eq!(
        p,
        "def cellcal_move():\n  movej([0.1, -1.5707963267948966, 1, 0, -0.5, 2], a=1.4, v=1.05)\nend\n"
    );
    assert_eq!(
        script::parse_program(&p).unwrap(),
        [Statement::MoveJ {
            q,
            a: 1.4,
            v: 1.05,
            t: 0.0,
            r: 0.0
        }]
    );
    assert_eq!(script::stopj(2.0).unwrap(), "stopj(2)");
    // python-urx's format, bare line, positional and named arguments, comments
    let urx = "movej([1.0,2.0,3.0,4.0,5.0,6.0], a=0.5, v=0.25, r=0)";
    let parsed = script::parse_program(urx).unwrap();
    assert_eq!(
        parsed,
        [Statement::MoveJ {
            q: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            a: 0.5,
            v: 0.25,
            t: 0.0,
            r: 0.0
        }]
    );
    let prog =
        "def p():\n  # go\n  movej([0,0,0,0,0,0], 1.2, 0.3)\n  sleep(0.5)\n  stopj(a=3)\nend\n";
    assert_eq!(
        script::parse_program(prog).unwrap(),
        [
            Statement::MoveJ {
                q: [0.0; 6],
                a: 1.2,
                v: 0.3,
                t: 0.0,
                r: 0.0
            },
            Statement::Sleep(0.5),
            Statement::StopJ { a: 3.0 }
        ]
    );
    // movej with defaults (URScript manual: a=1.4, v=1.05)
    match &script::parse_program("movej([0,0,0,0,0,0])").unwrap()[0] {
        Statement::MoveJ { a, v, .. } => assert_eq!((*a, *v), (1.4, 1.05)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn urscript_refuses_what_a_controller_would_not_run_or_cellcal_must_not_send() {
    for bad in [
        "movej([0,0,0,0,0], a=1, v=1)",
        "movej([0,0,0,0,0,0], a=-1, v=1)",
        "movej([0,0,0,0,0,nan], a=1, v=1)",
        "movej([0,0,0,0,0,inf], a=1, v=1)",
        "movej(p[0,0,0,0,0,0], a=1, v=1)",
        "movej([0,0,0,0,0,0], a=1, v=1, w=2)",
        "movej([0,0,0,0,0,0], a=1, a=2)",
        "movel([0,0,0,0,0,0], a=1, v=1)",
        "stopj()",
        "stopj(0)",
        "def p():\n  movej([0,0,0,0,0,0])\n",
        "end",
        "def p():\n  stopj(1)\nend\nstopj(1)",
        "def p():\n  set_digital_out(0, True)\n  stopj(1)\nend",
    ] {
        assert!(script::parse_program(bad).is_err(), "{bad:?} parsed");
    }
    assert!(script::movej(&[0.0, 0.0, 0.0, 0.0, 0.0, f64::NAN], 1.0, 1.0).is_err());
    assert!(script::movej(&[0.0; 6], 0.0, 1.0).is_err());
    assert!(script::movej(&[0.0; 6], 1.0, f64::INFINITY).is_err());
    assert!(script::stopj(-1.0).is_err());
    assert!(script::program("bad name", &[]).is_err());
    assert!(script::program("p", &["a\nb".into()]).is_err());
}

/// The output setup ur_rtde 1.6.5's `RTDEReceiveInterface(host)` sends to an e-Series
/// controller (recorded from the client: `V` 0x0002, `v` twice, then this `O` at 500 Hz, the
/// names each followed by a comma). It refuses a controller that answers `NOT_FOUND` to any.
const UR_RTDE_1_6_5_RECIPE: &str = "timestamp,target_q,target_qd,target_qdd,target_current,\
target_moment,actual_q,actual_qd,actual_current,joint_control_output,actual_TCP_pose,\
actual_TCP_speed,actual_TCP_force,target_TCP_pose,target_TCP_speed,actual_digital_input_bits,\
joint_temperatures,actual_execution_time,robot_mode,joint_mode,safety_mode,\
actual_tool_accelerometer,speed_scaling,target_speed_fraction,actual_momentum,\
actual_main_voltage,actual_robot_voltage,actual_robot_current,actual_joint_voltage,\
actual_digital_output_bits,runtime_state,standard_analog_input0,standard_analog_input1,\
standard_analog_output0,standard_analog_output1,robot_status_bits,safety_status_bits,\
ft_raw_wrench,payload,payload_cog,payload_inertia,output_int_register_2,\
output_int_register_12,output_int_register_13,output_int_register_14,output_int_register_15,\
output_int_register_16,output_int_register_17,output_int_register_18,output_int_register_19,\
output_double_register_12,output_double_register_13,output_double_register_14,\
output_double_register_15,output_double_register_16,output_double_register_17,\
output_double_register_18,output_double_register_19,";

#[test]
fn the_simulator_knows_every_variable_ur_rtde_asks_for_with_its_type() {
    let mut pkg = (3u16 + 8 + UR_RTDE_1_6_5_RECIPE.len() as u16)
        .to_be_bytes()
        .to_vec();
    pkg.push(b'O');
    pkg.extend_from_slice(&500.0f64.to_be_bytes());
    pkg.extend_from_slice(UR_RTDE_1_6_5_RECIPE.as_bytes());
    let mut d = FrameDecoder::new();
    d.push(&pkg);
    let Some(ClientPackage::SetupOutputs { frequency, names }) = d.next_client().unwrap() else {
        panic!("not a setup outputs package");
    };
    assert_eq!(frequency, 500.0);
    assert_eq!(names.len(), 58);
    // ur_rtde's robot_state.cpp types: 3 doubles for the accelerometer and payload_cog,
    // 6 for the other vectors, int32 x6 for joint_mode
    for n in &names {
        let t = ur::vars::output_type(n).unwrap_or_else(|| panic!("{n} NOT_FOUND"));
        let want = match n.as_str() {
            "actual_tool_accelerometer" | "payload_cog" => RtdeType::Vector3d,
            "joint_mode" => RtdeType::Vector6Int32,
            "robot_mode" | "safety_mode" => RtdeType::Int32,
            "runtime_state" | "robot_status_bits" | "safety_status_bits" => RtdeType::Uint32,
            "actual_digital_input_bits" | "actual_digital_output_bits" => RtdeType::Uint64,
            n if n.starts_with("output_int_register_") => RtdeType::Int32,
            n if n.starts_with("target_")
                || n.starts_with("actual_")
                    && !matches!(
                        n,
                        "actual_execution_time"
                            | "actual_momentum"
                            | "actual_main_voltage"
                            | "actual_robot_voltage"
                            | "actual_robot_current"
                    )
                || matches!(
                    n,
                    "joint_control_output"
                        | "joint_temperatures"
                        | "ft_raw_wrench"
                        | "payload_inertia"
                ) =>
            {
                if n == "target_speed_fraction" {
                    RtdeType::Double
                } else {
                    RtdeType::Vector6d
                }
            }
            _ => RtdeType::Double,
        };
        assert_eq!(t, want, "{n}");
    }
}
