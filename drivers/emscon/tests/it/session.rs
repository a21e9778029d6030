//! Client against the simulator: setup sequence, measurements, events, reconnects.

use std::time::Duration;

use emscon::types::{cmd, status_change, Units};
use emscon::{EmsconError, Event, ForcedStatus, SimpleState};

use crate::common::{fast_config, setup, Sim, MEAS_MS};

async fn next_status_change(rx: &mut tokio::sync::broadcast::Receiver<Event>, code: i32) -> bool {
    let fut = async {
        loop {
            match rx.recv().await {
                Ok(Event::StatusChange(c)) if c == code => return true,
                Ok(_) => continue,
                Err(_) => return false,
            }
        }
    };
    tokio::time::timeout(Duration::from_secs(2), fut)
        .await
        .unwrap_or(false)
}

#[tokio::test]
async fn full_setup_initializes_and_measures() {
    let sim = Sim::start().await;
    let c = sim.client().await;
    let mut ev = c.subscribe();
    let before = c.system_status().await.unwrap();
    assert!(!before.is_initialized());
    let st = c.setup_stationary(&setup()).await.unwrap();
    assert!(st.is_initialized());
    assert_eq!(st.version, [3, 6, 0]);
    assert!(next_status_change(&mut ev, status_change::INITIALIZATION_STATUS_CHANGED).await);
    let ms = c.measurement_status().await.unwrap();
    assert!(ms.reflector_found() && ms.initialized());
    let m = c.measure_stationary().await.unwrap();
    assert_eq!((m.x_mm, m.y_mm, m.z_mm), (1000.0, 2000.0, 300.0));
    assert_eq!(m.std_mm, [0.005, 0.005, 0.008]);
    assert!(m.std_total_mm > 0.0);
    assert_eq!(m.temperature_c, 20.0);
    assert_eq!(m.pressure_mbar, 1013.25);
    assert_eq!(m.humidity_pct, 45.0);
    assert_eq!(m.meas_time_ms, MEAS_MS);
    assert!(m.covariance.is_none());
    let took = m.received_at.duration_since(m.sent_at).unwrap();
    assert!(took >= Duration::from_millis(MEAS_MS as u64), "{took:?}");
    // Several measurements in a row.
    for _ in 0..3 {
        c.measure_stationary().await.unwrap();
    }
    sim.stop().await;
}

#[tokio::test]
async fn short_measuring_times_are_never_cut_short() {
    // Below the timer tick the server finishes the measuring time on a thread sleep.
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    for ms in [1, 2, 3] {
        c.set_stationary_params(ms, true).await.unwrap();
        for _ in 0..3 {
            let m = c.measure_stationary().await.unwrap();
            let took = m.received_at.duration_since(m.sent_at).unwrap();
            assert!(
                took >= Duration::from_millis(ms as u64),
                "{ms} ms: {took:?}"
            );
        }
    }
    sim.stop().await;
}

#[tokio::test]
async fn setup_skips_initialize_when_already_initialized() {
    let sim = Sim::start_with(SimpleState {
        initialized: true,
        ..SimpleState::default()
    })
    .await;
    // If setup called Initialize it would fail.
    sim.faults().forced_status = Some(ForcedStatus {
        command: Some(cmd::INITIALIZE),
        status: 39,
        count: 1,
    });
    let c = sim.client().await;
    c.setup_stationary(&setup()).await.unwrap();
    c.measure_stationary().await.unwrap();
    assert!(matches!(
        c.initialize().await,
        Err(EmsconError::NotInitialized)
    ));
}

#[tokio::test]
async fn reflectors_and_settings() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    let list = c.reflectors().await.unwrap();
    assert_eq!(list.len(), 3);
    assert_eq!(list[0].name, "RRR 1.5in");
    assert_eq!(list[0].surface_offset, 19.05);
    c.set_reflector(2).await.unwrap();
    assert!(matches!(
        c.set_reflector(99).await,
        Err(EmsconError::Device {
            command: 40,
            status: 3
        })
    ));
    assert!(matches!(
        c.set_stationary_params(0, true).await,
        Err(EmsconError::Device {
            command: 28,
            status: 3
        })
    ));
    c.stop_measurement().await.unwrap();
    c.clear_command_queue().await.unwrap();
}

#[tokio::test]
async fn extended_statistics_use_single_meas_result2() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    c.set_statistic_mode(true).await.unwrap();
    let m = c.measure_stationary().await.unwrap();
    assert_eq!(m.covariance, Some([0.0; 3]));
    assert_eq!(m.x_mm, 1000.0);
}

#[tokio::test]
async fn meter_units_are_converted_and_bad_units_rejected() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    c.set_units(Units {
        length: 0,
        ..Units::MM_DEG
    })
    .await
    .unwrap();
    let m = c.measure_stationary().await.unwrap();
    assert_eq!(m.x_mm, 1.0);
    assert!(matches!(
        c.set_units(Units {
            length: 5,
            ..Units::MM_DEG
        })
        .await,
        Err(EmsconError::Device {
            command: 5,
            status: 3
        })
    ));
    c.set_units_mm_deg().await.unwrap();
    assert_eq!(c.measure_stationary().await.unwrap().x_mm, 1000.0);
}

#[tokio::test]
async fn measure_before_initialize_is_not_initialized() {
    let sim = Sim::start().await;
    let c = sim.client().await;
    assert!(matches!(
        c.measure_stationary().await,
        Err(EmsconError::NotInitialized)
    ));
    assert!(matches!(
        c.find_reflector(2000.0).await,
        Err(EmsconError::NotInitialized)
    ));
    c.initialize().await.unwrap();
    c.set_stationary_params(MEAS_MS, true).await.unwrap();
    c.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn go_last_measured_point_needs_a_point() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    assert!(matches!(
        c.go_last_measured_point().await,
        Err(EmsconError::Device {
            command: 62,
            status: 28
        })
    ));
    c.measure_stationary().await.unwrap();
    c.go_last_measured_point().await.unwrap();
}

#[tokio::test]
async fn reconnect_after_client_drop() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    c.measure_stationary().await.unwrap();
    drop(c);
    // Tracker stays initialised across connections; a new client is cheap.
    let c2 = sim.client().await;
    assert!(c2.system_status().await.unwrap().is_initialized());
    c2.setup_stationary(&setup()).await.unwrap();
    c2.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn second_client_is_refused_and_first_keeps_working() {
    let sim = Sim::start().await;
    let c1 = sim.ready_client().await;
    let c2 = sim.client().await;
    let mut ev = c2.subscribe();
    let err = c2.system_status().await.unwrap_err();
    assert!(matches!(err, EmsconError::ConnectionRefused), "{err:?}");
    assert!(err.to_string().contains("10011"));
    assert!(!c2.is_connected());
    assert!(matches!(
        c2.system_status().await,
        Err(EmsconError::ConnectionRefused)
    ));
    let _ = tokio::time::timeout(Duration::from_millis(200), ev.recv()).await;
    c1.measure_stationary().await.unwrap();
}

#[tokio::test]
async fn server_shutdown_disconnects_client() {
    let sim = Sim::start().await;
    let c = sim.ready_client().await;
    let mut ev = c.subscribe();
    sim.stop().await;
    assert!(next_status_change(&mut ev, status_change::SERVER_CLOSING).await);
    assert!(matches!(
        c.system_status().await,
        Err(EmsconError::Disconnected)
    ));
}

#[tokio::test]
async fn client_close_then_calls_fail() {
    let sim = Sim::start().await;
    let c = sim.client_with(fast_config()).await;
    c.system_status().await.unwrap();
    c.close().await;
    assert!(matches!(
        c.system_status().await,
        Err(EmsconError::Disconnected)
    ));
}

#[tokio::test]
async fn works_over_in_memory_duplex_too() {
    // The client is transport-agnostic: talk to a scripted peer over a duplex pipe.
    use emscon::codec::{Command, FrameDecoder, Reply, ServerPacket};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let (a, mut b) = tokio::io::duplex(1024);
    let c = emscon::Client::from_stream(a, fast_config());
    let peer = tokio::spawn(async move {
        let mut d = FrameDecoder::new();
        let mut buf = [0u8; 256];
        loop {
            let n = b.read(&mut buf).await.unwrap();
            if n == 0 {
                return;
            }
            d.push(&buf[..n]);
            while let Some(cmd) = d.next_packet::<Command>().unwrap() {
                let rep = ServerPacket::Reply(Reply::ok(cmd.id())).to_bytes();
                b.write_all(&rep).await.unwrap();
            }
        }
    });
    c.set_reflector(1).await.unwrap();
    c.stop_measurement().await.unwrap();
    drop(c);
    peer.await.unwrap();
}
