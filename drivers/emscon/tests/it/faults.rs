//! Every injected fault surfaces as the right typed error; recovery where a device allows it.

use std::time::Duration;

use emscon::types::{cmd, status, status_change};
use emscon::{
    ClientConfig, EmsconError, Event, ForcedStatus, Malformed, ServerOptions, SimpleState,
};

use crate::common::{fast_config, setup, Sim};

fn events_until_quiet(rx: &mut tokio::sync::broadcast::Receiver<Event>) -> Vec<Event> {
    let mut out = Vec::new();
    while let Ok(e) = rx.try_recv() {
        out.push(e);
    }
    out
}

#[tokio::test]
async fn beam_break_before_measurement_then_find_reflector() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.faults().beam_break_before_measure = 1;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    // The ReflectorFound bit is now cleared and stays so until a search.
    assert!(!c.measurement_status().await.unwrap().reflector_found());
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    c.find_reflector(2000.0).await.unwrap();
    assert!(c.measurement_status().await.unwrap().reflector_found());
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn beam_break_rt_status_without_precheck_then_go_last_point() {
    let sim = Sim::start().await;
    let cfg = ClientConfig {
        check_reflector_before_measure: false,
        ..fast_config()
    };
    let c = sim.ready_client_with(cfg).await;
    c.measure_stationary().await.unwrap();
    sim.faults().beam_break_before_measure = 1;
    // Non-OK StartMeasurement RT (10004) is a beam break.
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    c.go_last_measured_point().await.unwrap();
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn beam_break_during_measurement_relocks_after_delay() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    let mut ev = c.subscribe();
    {
        let mut f = sim.faults();
        f.beam_break_during_measure = 1;
        f.relock_after_ms = Some(60);
    }
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    tokio::time::sleep(Duration::from_millis(20)).await;
    let evs = events_until_quiet(&mut ev);
    assert!(
        evs.iter()
            .any(|e| matches!(e, Event::Error(x) if x.status == status::NO_STATIONARY_RESULT)),
        "{evs:?}"
    );
    assert!(
        evs.contains(&Event::StatusChange(status_change::MEAS_STATUS_NOT_READY)),
        "{evs:?}"
    );
    // Still broken right after, re-locked by itself later.
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    tokio::time::sleep(Duration::from_millis(80)).await;
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn status_change_not_ready_alone_is_beam_break() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    {
        let mut f = sim.faults();
        f.beam_break_during_measure = 1;
        f.beam_break_sends_error = false;
    }
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    c.find_reflector(2000.0).await.unwrap();
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn backend_target_lost_is_beam_break() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.backend.state().target_lost_next = 1;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    c.find_reflector(2000.0).await.unwrap();
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn configurable_beam_break_code() {
    let sim = Sim::start().await;
    let code = 108_710;
    let plain = ClientConfig {
        check_reflector_before_measure: false,
        ..fast_config()
    };
    {
        let c = sim.ready_client_with(plain.clone()).await;
        {
            let mut f = sim.faults();
            f.beam_break_status = code;
            f.beam_break_before_measure = 1;
        }
        assert!(matches!(
            c.measure_stationary().await,
            Err(EmsconError::Device {
                command: 49,
                status: 108_710
            })
        ));
        c.find_reflector(1000.0).await.unwrap();
    }
    let c = sim
        .ready_client_with(ClientConfig {
            beam_break_code: Some(code),
            ..plain
        })
        .await;
    sim.faults().beam_break_before_measure = 1;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
}

#[tokio::test]
async fn no_target_visible_is_target_not_found() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.backend.state().reflector_found = false;
    assert!(matches!(
        c.find_reflector(2000.0).await,
        Err(EmsconError::TargetNotFound)
    ));
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    sim.backend.state().reflector_found = true;
    c.find_reflector(2000.0).await.unwrap();
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn no_reply_times_out_then_client_recovers() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.faults().no_reply = 1;
    let err = c.system_status().await.unwrap_err();
    assert!(
        matches!(
            err,
            EmsconError::Timeout {
                what: "GetSystemStatus reply"
            }
        ),
        "{err:?}"
    );
    c.system_status().await.unwrap();
    {
        let mut f = sim.faults();
        f.no_reply = 1;
        f.no_reply_command = Some(cmd::START_MEASUREMENT);
    }
    c.system_status().await.unwrap();
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::Timeout {
            what: "StartMeasurement reply"
        })
    ));
    // a measurement that timed out may still be under way: the connection is closed, and a new
    // one measures
    assert!(!c.is_connected());
    measure_on_a_new_connection(c).await;
}

/// Close `c` (as the cell's adapter does), connect again, set up and measure.
async fn measure_on_a_new_connection(c: emscon::Client) {
    c.close().await;
    let c = c.reconnect().await.expect("reconnect");
    c.setup_stationary(&setup()).await.expect("setup");
    c.measure_stationary().await.expect("measure");
}

/// The tracker takes three times the measuring time the client expects, so the client gives up
/// (20 ms + 20 ms margin) before the result comes (60 ms): the connection is closed at once, and
/// the late result can never pass for the next measurement's (no reflector check before it here).
#[tokio::test]
async fn a_timed_out_measurement_closes_the_connection_before_its_late_result() {
    let opts = ServerOptions {
        measuring_time_scale: 3.0,
        ..ServerOptions::default()
    };
    let sim = Sim::start_with_options(SimpleState::default(), opts).await;
    let cfg = ClientConfig {
        measure_margin: Duration::from_millis(20),
        check_reflector_before_measure: false,
        ..fast_config()
    };
    let c = sim.ready_client_with(cfg).await;
    let first = c.measure_stationary().await;
    assert!(
        matches!(first, Err(EmsconError::Timeout { .. })),
        "{first:?}"
    );
    assert!(!c.is_connected());
    let next = c.measure_stationary().await;
    assert!(
        next.is_err(),
        "a measurement on the old connection: {next:?}"
    );
}

#[tokio::test]
async fn rt_without_result_times_out() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.faults().rt_without_result = 1;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::Timeout {
            what: "measurement result"
        })
    ));
    assert!(!c.is_connected());
    measure_on_a_new_connection(c).await;
}

#[tokio::test]
async fn result_without_rt_and_result_before_rt_are_accepted() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.faults().result_without_rt = 1;
    assert_eq!(c.measure_stationary().await.unwrap().x_mm, 1000.0);
    c.system_status().await.unwrap();
    sim.faults().result_before_rt = 2;
    c.measure_stationary().await.unwrap();
    // The late RT must not be taken as the answer to the next command.
    c.system_status().await.unwrap();
    c.measure_stationary().await.unwrap();
    c.measure_stationary().await.unwrap();
    c.reflectors().await.unwrap();
}

#[tokio::test]
async fn stream_shaping_coalesce_dribble_interleave() {
    let sim = Sim::start().await;
    sim.faults().coalesce = true;
    let c = sim.ready_client().await;
    c.measure_stationary().await.unwrap();
    c.reflectors().await.unwrap();
    drop(c);
    {
        let mut f = sim.faults();
        f.coalesce = false;
        f.dribble = true;
    }
    let c = sim.ready_client().await;
    c.measure_stationary().await.unwrap();
    {
        let mut f = sim.faults();
        f.dribble = false;
        f.interleave_unsolicited = true;
    }
    let mut ev = c.subscribe();
    c.measure_stationary().await.unwrap();
    let evs = events_until_quiet(&mut ev);
    assert!(
        evs.contains(&Event::StatusChange(status_change::MEAS_STATUS_BUSY)),
        "{evs:?}"
    );
    assert!(
        evs.iter().any(|e| matches!(e, Event::ReflectorPos(_))),
        "{evs:?}"
    );
    // All at once: coalesced, dribbled, interleaved, result first.
    {
        let mut f = sim.faults();
        f.coalesce = true;
        f.dribble = true;
        f.result_before_rt = 1;
    }
    c.measure_stationary().await.unwrap();
    c.system_status().await.unwrap();
}

async fn expect_recoverable(sim: &Sim, m: Malformed) {
    let c = sim.ready_client().await;
    sim.faults().malformed.push_back(m);
    let err = c.system_status().await.unwrap_err();
    assert!(matches!(err, EmsconError::Protocol(_)), "{m:?}: {err:?}");
    assert!(c.is_connected(), "{m:?}");
    c.system_status().await.unwrap();
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn malformed_recoverable_packets_are_protocol_errors() {
    let sim = Sim::start().await;
    for m in [
        Malformed::SizeMismatch,
        Malformed::UnknownType,
        Malformed::WrongCommandEcho,
    ] {
        expect_recoverable(&sim, m).await;
    }
}

#[tokio::test]
async fn malformed_framing_is_fatal_then_reconnect() {
    let sim = Sim::start().await;
    for m in [Malformed::SizeTooSmall, Malformed::SizeTooLarge] {
        let c = sim.ready_client().await;
        sim.faults().malformed.push_back(m);
        let err = c.system_status().await.unwrap_err();
        assert!(matches!(err, EmsconError::Protocol(_)), "{m:?}: {err:?}");
        assert!(!c.is_connected());
        assert!(matches!(
            c.system_status().await,
            Err(EmsconError::Disconnected)
        ));
        drop(c);
        let c = sim.ready_client().await;
        c.measure_stationary().await.unwrap();
    }
}

#[tokio::test]
async fn nan_result_is_protocol_error() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.faults().malformed.push_back(Malformed::NanResult);
    c.system_status().await.unwrap(); // NaN fault waits for a result
    let err = c.measure_stationary().await.unwrap_err();
    assert!(
        matches!(&err, EmsconError::Protocol(s) if s.contains("NaN")),
        "{err:?}"
    );
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn disconnect_mid_packet_then_reconnect() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.faults().disconnect_mid_packet = 1;
    assert!(matches!(
        c.system_status().await,
        Err(EmsconError::Disconnected)
    ));
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::Disconnected)
    ));
    assert!(!c.is_connected());
    let c2 = c.reconnect().await.unwrap();
    drop(c);
    c2.setup_stationary(&crate::common::setup()).await.unwrap();
    c2.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn tp_connection_closing_then_close() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    let mut ev = c.subscribe();
    sim.faults().closing_then_close = 1;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::Disconnected)
    ));
    let evs = events_until_quiet(&mut ev);
    assert!(
        evs.contains(&Event::StatusChange(status_change::TP_CONNECTION_CLOSING)),
        "{evs:?}"
    );
    assert!(evs.contains(&Event::Disconnected));
    assert!(matches!(
        c.system_status().await,
        Err(EmsconError::Disconnected)
    ));
    let c = sim.ready_client().await;
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn forced_statuses_map_to_typed_errors() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    type Check = fn(&EmsconError) -> bool;
    let cases: [(i32, Check); 4] = [
        (status::TRACKER_NOT_INITIALIZED, |e| {
            matches!(e, EmsconError::NotInitialized)
        }),
        (status::SENSOR_NOT_WARMED_UP, |e| {
            matches!(e, EmsconError::NotWarmedUp)
        }),
        (status::SERVER_BUSY, |e| matches!(e, EmsconError::Busy)),
        (status::METEO_DATA_OUT_OF_RANGE, |e| {
            matches!(
                e,
                EmsconError::Device {
                    command: 49,
                    status: 57
                }
            )
        }),
    ];
    for (st, check) in cases {
        sim.faults().forced_status = Some(ForcedStatus {
            command: Some(cmd::START_MEASUREMENT),
            status: st,
            count: 1,
        });
        let err = c.measure_stationary().await.unwrap_err();
        assert!(check(&err), "status {st}: {err:?}");
        assert_eq!(err.status(), Some(st));
        c.measure_stationary().await.unwrap();
    }
    // Forced onto any command, with a full-size (56-byte) failed reply.
    sim.faults().forced_status = Some(ForcedStatus {
        command: None,
        status: status::SERVER_BUSY,
        count: 1,
    });
    assert!(matches!(c.system_status().await, Err(EmsconError::Busy)));
    c.system_status().await.unwrap();
}

#[tokio::test]
async fn not_warmed_up_backend() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    sim.backend.state().warmed_up = false;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::NotWarmedUp)
    ));
    sim.backend.state().warmed_up = true;
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn go_position_locks_only_where_the_reflector_is() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    let at = sim.backend.state().xyz_mm;
    sim.faults().beam_break_before_measure = 1;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::BeamBroken)
    ));
    // pointing 1 m away answers OK but finds nothing there
    c.go_position([at[0] + 1000.0, at[1], at[2]], true)
        .await
        .unwrap();
    assert!(!c.measurement_status().await.unwrap().reflector_found());
    // pointing within the capture radius locks on
    c.go_position([at[0] + 5.0, at[1] - 5.0, at[2]], true)
        .await
        .unwrap();
    assert!(c.measurement_status().await.unwrap().reflector_found());
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn a_dropped_measurement_never_passes_its_result_off_as_the_next_one() {
    let sim = Sim::start().await;
    let c = sim.client().await;
    let slow = emscon::StationarySetup {
        meas_time_ms: 400,
        ..crate::common::setup()
    };
    c.setup_stationary(&slow).await.unwrap();
    let first = sim.backend.state().xyz_mm;
    // the caller gives up mid-measurement (an abort), then the ball moves
    let dropped = tokio::time::timeout(Duration::from_millis(50), c.measure_stationary()).await;
    assert!(dropped.is_err(), "the measurement finished within 50 ms");
    sim.backend.state().xyz_mm = [first[0] + 100.0, first[1], first[2]];
    match c.measure_stationary().await {
        Ok(m) => assert!(
            (m.x_mm - first[0] - 100.0).abs() < 1e-9,
            "the dropped measurement's point came back as the next one: {m:?}"
        ),
        Err(e) => assert!(matches!(e, EmsconError::Disconnected), "{e:?}"),
    }
}

#[tokio::test]
async fn a_dropped_get_reflectors_never_leaves_its_late_replies_to_the_next_command() {
    use emscon::codec::{Command, FrameDecoder, Reply, ReplyBody, ServerPacket};
    use emscon::types::ReflectorInfo;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let (a, mut b) = tokio::io::duplex(4096);
    let c = emscon::Client::from_stream(a, fast_config());
    let (rest_tx, rest_rx) = tokio::sync::oneshot::channel::<()>();
    // A scripted tracker: GetReflectors answers one of three replies at once and the other
    // two only when the test says so; every other command gets a plain OK.
    let peer = tokio::spawn(async move {
        let reflector = |id| {
            ServerPacket::Reply(Reply {
                command: cmd::GET_REFLECTORS,
                status: 0,
                body: ReplyBody::Reflector(ReflectorInfo {
                    total: 3,
                    id,
                    target_type: 5,
                    surface_offset: 0.0,
                    name: format!("R{id}"),
                }),
            })
            .to_bytes()
        };
        let mut rest_rx = Some(rest_rx);
        let mut d = FrameDecoder::new();
        let mut buf = [0u8; 256];
        loop {
            let n = b.read(&mut buf).await.unwrap();
            if n == 0 {
                return;
            }
            d.push(&buf[..n]);
            while let Some(command) = d.next_packet::<Command>().unwrap() {
                if command.id() == cmd::GET_REFLECTORS {
                    b.write_all(&reflector(1)).await.unwrap();
                    if let Some(rx) = rest_rx.take() {
                        let _ = rx.await;
                    }
                    b.write_all(&reflector(2)).await.unwrap();
                    b.write_all(&reflector(3)).await.unwrap();
                } else {
                    let rep = ServerPacket::Reply(Reply::ok(command.id())).to_bytes();
                    b.write_all(&rep).await.unwrap();
                }
            }
        }
    });
    // the caller gives up after the first reply (an abort)
    let dropped = tokio::time::timeout(Duration::from_millis(150), c.reflectors()).await;
    assert!(
        dropped.is_err(),
        "GetReflectors finished with one of three replies"
    );
    rest_tx.send(()).unwrap();
    match c.set_reflector(1).await {
        Ok(()) => {}
        Err(e) => assert!(
            matches!(e, EmsconError::Disconnected),
            "the dropped GetReflectors' late replies desynchronised the next command: {e:?}"
        ),
    }
    drop(c);
    peer.await.unwrap();
}
