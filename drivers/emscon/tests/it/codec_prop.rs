//! Property tests: round trips, arbitrary chunking, garbage never panics.

use emscon::codec::{
    CodecError, Command, ErrorResponse, FrameDecoder, NivelResult, ReflectorPosResult, Reply,
    ReplyBody, ServerPacket, SingleMeasResult, SingleMeasResult2,
};
use emscon::types::{
    Environment, MeasurementStatusInfo, ReflectorInfo, SystemSettings, SystemStatus, Units,
};
use proptest::prelude::*;

fn f() -> impl Strategy<Value = f64> {
    -1.0e6f64..1.0e6
}
fn f3() -> impl Strategy<Value = [f64; 3]> {
    [f(), f(), f()]
}
fn units() -> impl Strategy<Value = Units> {
    (
        any::<i32>(),
        any::<i32>(),
        any::<i32>(),
        any::<i32>(),
        any::<i32>(),
    )
        .prop_map(|(length, angle, temperature, pressure, humidity)| Units {
            length,
            angle,
            temperature,
            pressure,
            humidity,
        })
}
fn env() -> impl Strategy<Value = Environment> {
    (f(), f(), f()).prop_map(|(temperature, pressure, humidity)| Environment {
        temperature,
        pressure,
        humidity,
    })
}
fn settings() -> impl Strategy<Value = SystemSettings> {
    (any::<i32>(), any::<[bool; 8]>()).prop_map(|(w, b)| SystemSettings {
        weather_monitor_status: w,
        apply_transformation: b[0],
        apply_station_orientation: b[1],
        keep_last_position: b[2],
        send_unsolicited_messages: b[3],
        send_reflector_position_data: b[4],
        try_measurement_mode: b[5],
        has_nivel: b[6],
        has_video_camera: b[7],
    })
}

pub fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::GetSystemStatus),
        units().prop_map(Command::SetUnits),
        Just(Command::GetUnits),
        Just(Command::Initialize),
        env().prop_map(Command::SetEnvironmentParams),
        Just(Command::GetEnvironmentParams),
        any::<i32>().prop_map(Command::SetMeasurementMode),
        any::<i32>().prop_map(Command::SetCoordinateSystemType),
        (any::<i32>(), any::<bool>()).prop_map(|(meas_time_ms, use_adm)| {
            Command::SetStationaryModeParams {
                meas_time_ms,
                use_adm,
            }
        }),
        Just(Command::GetStationaryModeParams),
        any::<i32>().prop_map(Command::SetReflector),
        Just(Command::GetReflector),
        Just(Command::GetReflectors),
        settings().prop_map(Command::SetSystemSettings),
        Just(Command::GetSystemSettings),
        Just(Command::StartMeasurement),
        Just(Command::StopMeasurement),
        Just(Command::ChangeFace),
        Just(Command::GoBirdBath),
        Just(Command::GoLastMeasuredPoint),
        f().prop_map(|approx_distance| Command::FindReflector { approx_distance }),
        (any::<i32>(), any::<i32>()).prop_map(|(stationary, continuous)| {
            Command::SetStatisticMode {
                stationary,
                continuous,
            }
        }),
        Just(Command::GetMeasurementStatusInfo),
        Just(Command::GetObjectTemperature),
        any::<i32>().prop_map(Command::ClearCommandQueue),
    ]
}

fn reply() -> impl Strategy<Value = Reply> {
    let typed = prop_oneof![
        (prop::sample::select(vec![5, 7, 20, 24, 26, 28, 40, 47, 49, 52, 62, 63, 130]))
            .prop_map(|c| (c, ReplyBody::Basic)),
        (any::<[i32; 10]>()).prop_map(|v| (
            1,
            ReplyBody::SystemStatus(SystemStatus {
                last_result_status: v[0],
                tracker_processor_status: v[1],
                laser_status: v[2],
                adm_status: v[3],
                version: [v[4], v[5], v[6]],
                weather_monitor_status: v[7],
                flags: v[8],
                serial_number: v[9],
            })
        )),
        units().prop_map(|u| (6, ReplyBody::Units(u))),
        env().prop_map(|e| (21, ReplyBody::Environment(e))),
        (any::<i32>(), any::<bool>()).prop_map(|(meas_time_ms, use_adm)| (
            29,
            ReplyBody::StationaryModeParams {
                meas_time_ms,
                use_adm
            }
        )),
        any::<i32>().prop_map(|r| (41, ReplyBody::ReflectorId(r))),
        (any::<[i32; 3]>(), f(), "[a-zA-Z0-9 .\"]{0,31}").prop_map(|(v, o, name)| (
            42,
            ReplyBody::Reflector(ReflectorInfo {
                total: v[0],
                id: v[1],
                target_type: v[2],
                surface_offset: o,
                name,
            })
        )),
        settings().prop_map(|s| (48, ReplyBody::SystemSettings(s))),
        (any::<i32>(), any::<u32>()).prop_map(|(l, b)| (
            122,
            ReplyBody::MeasurementStatusInfo {
                last_result_status: l,
                info: MeasurementStatusInfo(b)
            }
        )),
        f().prop_map(|t| (127, ReplyBody::ObjectTemperature(t))),
        (1000..5000i32, prop::collection::vec(any::<u8>(), 0..64))
            .prop_map(|(c, raw)| (c, ReplyBody::Raw(raw))),
    ];
    (typed, any::<i32>()).prop_map(|((command, body), status)| {
        // A short basic reply to a command with payload is only legal with non-OK status.
        Reply {
            command,
            status,
            body,
        }
    })
}

pub fn server_packet() -> impl Strategy<Value = ServerPacket> {
    prop_oneof![
        reply().prop_map(ServerPacket::Reply),
        (any::<i32>(), any::<i32>())
            .prop_map(|(command, status)| ServerPacket::Error(ErrorResponse { command, status })),
        (
            any::<[i32; 2]>(),
            any::<bool>(),
            f3(),
            f3(),
            f(),
            f3(),
            f3(),
            f(),
            f3()
        )
            .prop_map(|(i, t, val, std, st, pe, ap, apt, m)| {
                ServerPacket::SingleMeasResult(SingleMeasResult {
                    status: i[0],
                    meas_mode: i[1],
                    is_try_mode: t,
                    val,
                    std,
                    std_total: st,
                    pointing_error: pe,
                    apriori_std: ap,
                    apriori_std_total: apt,
                    temperature: m[0],
                    pressure: m[1],
                    humidity: m[2],
                })
            }),
        (
            any::<[i32; 2]>(),
            any::<bool>(),
            f3(),
            f3(),
            f3(),
            f3(),
            f3(),
            f3(),
            f3()
        )
            .prop_map(|(i, t, val, std, cov, pe, ap, apc, m)| {
                ServerPacket::SingleMeasResult2(SingleMeasResult2 {
                    status: i[0],
                    meas_mode: i[1],
                    is_try_mode: t,
                    val,
                    std,
                    std_total: std[0],
                    covar: cov,
                    pointing_error: pe,
                    apriori_std: ap,
                    apriori_std_total: ap[1],
                    apriori_covar: apc,
                    temperature: m[0],
                    pressure: m[1],
                    humidity: m[2],
                })
            }),
        (any::<[i32; 2]>(), f3()).prop_map(|(i, v)| ServerPacket::NivelResult(NivelResult {
            status: i[0],
            nivel_status: i[1],
            x_tilt: v[0],
            y_tilt: v[1],
            temperature: v[2],
        })),
        (any::<i32>(), f3()).prop_map(|(status, val)| ServerPacket::ReflectorPos(
            ReflectorPosResult { status, val }
        )),
        any::<i32>().prop_map(ServerPacket::StatusChange),
    ]
}

/// Splits `bytes` at the given (sorted, deduplicated) cut points.
fn chunks(bytes: &[u8], cuts: &[usize]) -> Vec<Vec<u8>> {
    let mut cuts: Vec<usize> = cuts.iter().map(|c| c % (bytes.len() + 1)).collect();
    cuts.sort_unstable();
    cuts.dedup();
    let mut out = Vec::new();
    let mut prev = 0;
    for c in cuts {
        out.push(bytes[prev..c].to_vec());
        prev = c;
    }
    out.push(bytes[prev..].to_vec());
    out
}

type Outcome = Result<ServerPacket, CodecError>;

/// Feeds chunks and collects every decoded packet or error (stops after a fatal error).
fn decode_all(parts: &[Vec<u8>]) -> Vec<Outcome> {
    let mut d = FrameDecoder::new();
    let mut out = Vec::new();
    for p in parts {
        d.push(p);
        loop {
            match d.next_packet::<ServerPacket>() {
                Ok(Some(pkt)) => out.push(Ok(pkt)),
                Ok(None) => break,
                Err(e) => out.push(Err(e)),
            }
        }
    }
    out
}

fn valid(p: &ServerPacket) -> bool {
    // Drop replies that are only legal as non-OK (short basic replies to payload commands).
    match p {
        ServerPacket::Reply(r) => {
            let short = matches!(r.body, ReplyBody::Basic)
                && emscon::codec::reply_size(r.command) != Some(16);
            !short || r.status != 0
        }
        _ => true,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn command_round_trip(c in command()) {
        let b = c.to_bytes();
        prop_assert_eq!(Some(b.len()), emscon::codec::command_size(c.id()));
        prop_assert_eq!(Command::decode(&b), Ok(c));
    }

    #[test]
    fn server_packet_round_trip(p in server_packet().prop_filter("legal", valid)) {
        let b = p.to_bytes();
        prop_assert_eq!(ServerPacket::decode(&b), Ok(p));
    }

    #[test]
    fn any_chunking_yields_same_packets(
        pkts in prop::collection::vec(server_packet().prop_filter("legal", valid), 1..8),
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let stream: Vec<u8> = pkts.iter().flat_map(|p| p.to_bytes()).collect();
        let got = decode_all(&chunks(&stream, &cuts));
        let want: Vec<Outcome> = pkts.into_iter().map(Ok).collect();
        prop_assert_eq!(got, want);
    }

    #[test]
    fn one_byte_dribble_yields_same_packets(
        pkts in prop::collection::vec(server_packet().prop_filter("legal", valid), 1..4),
    ) {
        let stream: Vec<u8> = pkts.iter().flat_map(|p| p.to_bytes()).collect();
        let parts: Vec<Vec<u8>> = stream.iter().map(|b| vec![*b]).collect();
        let want: Vec<Outcome> = pkts.into_iter().map(Ok).collect();
        prop_assert_eq!(decode_all(&parts), want);
    }

    #[test]
    fn garbage_never_panics_and_is_chunking_independent(
        garbage in prop::collection::vec(any::<u8>(), 0..600),
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let whole = decode_all(std::slice::from_ref(&garbage));
        let split = decode_all(&chunks(&garbage, &cuts));
        prop_assert_eq!(whole, split);
        let _ = Command::decode(&garbage);
        let _ = ServerPacket::decode(&garbage);
    }

    #[test]
    fn plausible_headers_never_panic(
        size in 0i32..300, ty in -2i32..12, command in -2i32..200,
        tail in prop::collection::vec(any::<u8>(), 0..300),
    ) {
        let mut b = size.to_le_bytes().to_vec();
        b.extend_from_slice(&ty.to_le_bytes());
        b.extend_from_slice(&command.to_le_bytes());
        b.extend_from_slice(&tail);
        let mut d = FrameDecoder::new();
        d.push(&b);
        for _ in 0..4 {
            let _ = d.next_packet::<ServerPacket>();
        }
        let mut d = FrameDecoder::new();
        d.push(&b);
        for _ in 0..4 {
            let _ = d.next_packet::<Command>();
        }
    }
}
