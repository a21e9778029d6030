//! Golden bytes and byte offsets, written by hand from the 3.6 header layout.

use emscon::codec::{
    command_size, reply_size, CodecError, Command, ErrorResponse, NivelResult, ReflectorPosResult,
    Reply, ReplyBody, ServerPacket, SingleMeasResult, SingleMeasResult2,
};
use emscon::types::{
    cmd, Environment, MeasurementStatusInfo, ReflectorInfo, SystemSettings, SystemStatus, Units,
};

fn i32_at(b: &[u8], off: usize) -> i32 {
    i32::from_le_bytes(b[off..off + 4].try_into().unwrap())
}
fn f64_at(b: &[u8], off: usize) -> f64 {
    f64::from_le_bytes(b[off..off + 8].try_into().unwrap())
}

#[test]
fn golden_get_system_status_ct() {
    let b = Command::GetSystemStatus.to_bytes();
    assert_eq!(b, [12, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0]);
}

#[test]
fn golden_set_stationary_mode_params_ct() {
    let b = Command::SetStationaryModeParams {
        meas_time_ms: 1000,
        use_adm: true,
    }
    .to_bytes();
    assert_eq!(
        b,
        [20, 0, 0, 0, 0, 0, 0, 0, 28, 0, 0, 0, 0xE8, 0x03, 0, 0, 1, 0, 0, 0]
    );
}

#[test]
fn golden_find_reflector_ct() {
    let b = Command::FindReflector {
        approx_distance: 3000.0,
    }
    .to_bytes();
    assert_eq!(
        b,
        [20, 0, 0, 0, 0, 0, 0, 0, 63, 0, 0, 0, 0, 0, 0, 0, 0, 0x70, 0xA7, 0x40]
    );
}

#[test]
fn golden_go_position_ct() {
    // packed as the TPI's GoPositionCT: header, command 55, 3 × f64, ES_BOOL bUseADM
    let b = Command::GoPosition {
        x: 3000.0,
        y: 0.0,
        z: -1.0,
        use_adm: true,
    }
    .to_bytes();
    let mut want = vec![40, 0, 0, 0, 0, 0, 0, 0, 55, 0, 0, 0];
    for v in [3000.0f64, 0.0, -1.0] {
        want.extend_from_slice(&v.to_le_bytes());
    }
    want.extend_from_slice(&[1, 0, 0, 0]);
    assert_eq!(b, want);
}

#[test]
fn golden_set_units_ct() {
    let b = Command::SetUnits(Units::MM_DEG).to_bytes();
    let mut want = vec![32, 0, 0, 0, 0, 0, 0, 0, 5, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0];
    want.extend_from_slice(&[0; 12]);
    assert_eq!(b, want);
}

#[test]
fn golden_error_and_status_change() {
    let e = ServerPacket::Error(ErrorResponse {
        command: 49,
        status: 10009,
    })
    .to_bytes();
    assert_eq!(e, [16, 0, 0, 0, 1, 0, 0, 0, 49, 0, 0, 0, 0x19, 0x27, 0, 0]);
    let s = ServerPacket::StatusChange(151).to_bytes();
    assert_eq!(s, [12, 0, 0, 0, 8, 0, 0, 0, 151, 0, 0, 0]);
    let r = ServerPacket::Reply(Reply::ok(cmd::INITIALIZE)).to_bytes();
    assert_eq!(r, [16, 0, 0, 0, 0, 0, 0, 0, 7, 0, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn single_meas_result_offsets() {
    let m = SingleMeasResult {
        status: 0,
        meas_mode: 0,
        is_try_mode: true,
        val: [1.0, 2.0, 3.0],
        std: [4.0, 5.0, 6.0],
        std_total: 7.0,
        pointing_error: [8.0, 9.0, 10.0],
        apriori_std: [11.0, 12.0, 13.0],
        apriori_std_total: 14.0,
        temperature: 21.5,
        pressure: 1001.0,
        humidity: 33.0,
    };
    let b = ServerPacket::SingleMeasResult(m).to_bytes();
    assert_eq!(b.len(), 156);
    assert_eq!(i32_at(&b, 0), 156);
    assert_eq!(i32_at(&b, 4), 2);
    assert_eq!(i32_at(&b, 16), 1);
    for (off, v) in [
        (20, 1.0),
        (28, 2.0),
        (36, 3.0),
        (44, 4.0),
        (52, 5.0),
        (60, 6.0),
        (68, 7.0),
    ] {
        assert_eq!(f64_at(&b, off), v, "offset {off}");
    }
    assert_eq!(f64_at(&b, 76), 8.0);
    assert_eq!(f64_at(&b, 100), 11.0);
    assert_eq!(f64_at(&b, 124), 14.0);
    assert_eq!(f64_at(&b, 132), 21.5);
    assert_eq!(f64_at(&b, 140), 1001.0);
    assert_eq!(f64_at(&b, 148), 33.0);
    assert_eq!(
        ServerPacket::decode(&b),
        Ok(ServerPacket::SingleMeasResult(m))
    );
}

#[test]
fn single_meas_result2_offsets() {
    let m = SingleMeasResult2 {
        val: [1.0, 2.0, 3.0],
        std_total: 7.0,
        covar: [0.1, 0.2, 0.3],
        temperature: 21.5,
        pressure: 1001.0,
        humidity: 33.0,
        ..SingleMeasResult2::default()
    };
    let b = ServerPacket::SingleMeasResult2(m).to_bytes();
    assert_eq!(b.len(), 204);
    assert_eq!(i32_at(&b, 4), 9);
    assert_eq!(f64_at(&b, 20), 1.0);
    assert_eq!(f64_at(&b, 36), 3.0);
    assert_eq!(f64_at(&b, 68), 7.0);
    assert_eq!(f64_at(&b, 76), 0.1);
    assert_eq!(f64_at(&b, 180), 21.5);
    assert_eq!(f64_at(&b, 188), 1001.0);
    assert_eq!(f64_at(&b, 196), 33.0);
    assert_eq!(
        ServerPacket::decode(&b),
        Ok(ServerPacket::SingleMeasResult2(m))
    );
}

#[test]
fn reply_offsets() {
    let st = SystemStatus {
        last_result_status: 0,
        tracker_processor_status: 5,
        laser_status: 3,
        adm_status: 2,
        version: [3, 6, 9],
        weather_monitor_status: 2,
        flags: 0,
        serial_number: 4242,
    };
    let b = ServerPacket::Reply(Reply {
        command: 1,
        status: 0,
        body: ReplyBody::SystemStatus(st),
    })
    .to_bytes();
    assert_eq!(b.len(), 56);
    assert_eq!(i32_at(&b, 20), 5);
    assert_eq!(i32_at(&b, 32), 3);
    assert_eq!(i32_at(&b, 40), 9);
    assert_eq!(i32_at(&b, 52), 4242);

    let b = ServerPacket::Reply(Reply {
        command: 122,
        status: 0,
        body: ReplyBody::MeasurementStatusInfo {
            last_result_status: 0,
            info: MeasurementStatusInfo(0x800),
        },
    })
    .to_bytes();
    assert_eq!(b.len(), 24);
    assert_eq!(i32_at(&b, 20), 0x800);

    let b = Command::SetSystemSettings(SystemSettings {
        weather_monitor_status: 2,
        send_unsolicited_messages: true,
        keep_last_position: false,
        ..SystemSettings::default()
    })
    .to_bytes();
    assert_eq!(b.len(), 48);
    assert_eq!(i32_at(&b, 12), 2);
    assert_eq!(i32_at(&b, 28), 1);
    assert_eq!(i32_at(&b, 24), 0);

    let b = ServerPacket::ReflectorPos(ReflectorPosResult {
        status: 0,
        val: [1.0, 2.0, 3.0],
    })
    .to_bytes();
    assert_eq!(b.len(), 36);
    assert_eq!(
        (f64_at(&b, 12), f64_at(&b, 20), f64_at(&b, 28)),
        (1.0, 2.0, 3.0)
    );

    let b = ServerPacket::NivelResult(NivelResult::default()).to_bytes();
    assert_eq!(b.len(), 40);

    let b = ServerPacket::Reply(Reply {
        command: 42,
        status: 0,
        body: ReplyBody::Reflector(ReflectorInfo {
            total: 1,
            id: 7,
            target_type: 5,
            surface_offset: 19.05,
            name: "AB".into(),
        }),
    })
    .to_bytes();
    assert_eq!(b.len(), 100);
    assert_eq!(i32_at(&b, 20), 7);
    assert_eq!(f64_at(&b, 28), 19.05);
    assert_eq!(&b[36..42], &[b'A', 0, b'B', 0, 0, 0]);
}

#[test]
fn size_tables_match_devices_md() {
    for (c, ct, rt) in [
        (cmd::GET_SYSTEM_STATUS, 12, 56),
        (cmd::SET_UNITS, 32, 16),
        (cmd::INITIALIZE, 12, 16),
        (cmd::SET_ENVIRONMENT_PARAMS, 36, 16),
        (cmd::SET_MEASUREMENT_MODE, 16, 16),
        (cmd::SET_COORDINATE_SYSTEM_TYPE, 16, 16),
        (cmd::SET_STATIONARY_MODE_PARAMS, 20, 16),
        (cmd::SET_REFLECTOR, 16, 16),
        (cmd::GET_REFLECTORS, 12, 100),
        (cmd::SET_SYSTEM_SETTINGS, 48, 16),
        (cmd::START_MEASUREMENT, 12, 16),
        (cmd::STOP_MEASUREMENT, 12, 16),
        (cmd::GO_LAST_MEASURED_POINT, 12, 16),
        (cmd::FIND_REFLECTOR, 20, 16),
        (cmd::GET_MEASUREMENT_STATUS_INFO, 12, 24),
        (cmd::CLEAR_COMMAND_QUEUE, 16, 16),
    ] {
        assert_eq!(command_size(c), Some(ct), "CT {c}");
        assert_eq!(reply_size(c), Some(rt), "RT {c}");
    }
}

#[test]
fn every_reply_body_round_trips() {
    let bodies = vec![
        (7, ReplyBody::Basic),
        (1, ReplyBody::SystemStatus(SystemStatus::default())),
        (6, ReplyBody::Units(Units::MM_DEG)),
        (
            21,
            ReplyBody::Environment(Environment {
                temperature: 1.0,
                pressure: 2.0,
                humidity: 3.0,
            }),
        ),
        (
            29,
            ReplyBody::StationaryModeParams {
                meas_time_ms: 500,
                use_adm: true,
            },
        ),
        (41, ReplyBody::ReflectorId(3)),
        (48, ReplyBody::SystemSettings(SystemSettings::default())),
        (127, ReplyBody::ObjectTemperature(22.5)),
        (9999, ReplyBody::Raw(vec![1, 2, 3, 4, 5])),
        (9999, ReplyBody::Raw(vec![])),
    ];
    for (command, body) in bodies {
        let p = ServerPacket::Reply(Reply {
            command,
            status: 0,
            body,
        });
        assert_eq!(ServerPacket::decode(&p.to_bytes()), Ok(p));
    }
}

#[test]
fn decode_errors_are_typed() {
    // Basic reply for GetSystemStatus with OK status: size mismatch.
    let b = ServerPacket::Reply(Reply::ok(cmd::GET_SYSTEM_STATUS)).to_bytes();
    assert!(matches!(
        ServerPacket::decode(&b),
        Err(CodecError::SizeMismatch {
            command: Some(1),
            size: 16,
            expected: 56,
            ..
        })
    ));
    // Unknown type.
    let b = [16, 0, 0, 0, 5, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0];
    assert_eq!(ServerPacket::decode(&b), Err(CodecError::UnknownType(5)));
    // Unknown command in a CT.
    let b = [12, 0, 0, 0, 0, 0, 0, 0, 0xE7, 0x03, 0, 0];
    assert_eq!(Command::decode(&b), Err(CodecError::UnknownCommand(999)));
    // Status change with wrong size.
    let b = [16, 0, 0, 0, 8, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0];
    assert!(matches!(
        ServerPacket::decode(&b),
        Err(CodecError::SizeMismatch { .. })
    ));
    // Results are not commands.
    let b = ServerPacket::StatusChange(1).to_bytes();
    assert_eq!(Command::decode(&b), Err(CodecError::UnknownType(8)));
}
