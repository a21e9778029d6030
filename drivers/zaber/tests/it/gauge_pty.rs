use std::sync::Arc;
use std::time::Duration;

use zaber::pty::{spawn_gauge_pty, spawn_stage_pty};
use zaber::sim::{GaugeSim, StageSim, StageSimConfig};
use zaber::{GaugeClient, GaugeConfig, GaugeError, ZaberStage};

use crate::common::{stage_cfg, STEPS_PER_MM};

fn gauge_cfg() -> GaugeConfig {
    GaugeConfig {
        reply_timeout: Duration::from_millis(150),
        min_mm: -5.0,
        max_mm: 250.0,
        ..Default::default()
    }
}

#[tokio::test]
async fn gauge_reads_stage_position_over_pty() {
    // Simulated world: the gauge measures the stage carriage.
    let stage_sim = StageSim::new(StageSimConfig {
        homed: true,
        ..Default::default()
    });
    let s2 = stage_sim.clone();
    let gauge_sim = GaugeSim::new(Arc::new(move || s2.position_steps() as f64 / STEPS_PER_MM));
    let sdev = spawn_stage_pty(stage_sim.clone()).unwrap();
    let gdev = spawn_gauge_pty(gauge_sim.clone()).unwrap();
    let mut stage = ZaberStage::open(&sdev.path(), stage_cfg()).unwrap();
    // Sylvac-style 4800 7E2 on the pty.
    let mut gauge = GaugeClient::open(&gdev.path(), gauge_cfg()).unwrap();
    stage.move_abs_mm(42.5).await.unwrap();
    let v = gauge.read_mm().await.unwrap();
    assert!((v - 42.5).abs() < 1e-4, "{v}");

    gauge_sim.faults().no_reply = 1;
    assert!(matches!(gauge.read_mm().await, Err(GaugeError::Timeout)));
    gauge_sim.faults().status = 1;
    let e = gauge.read_mm().await.unwrap_err();
    assert!(
        matches!(e, GaugeError::DeviceStatus(ref s) if s.starts_with('9')),
        "{e:?}"
    );
    gauge_sim.faults().inch = 1;
    let e = gauge.read_mm().await.unwrap_err();
    assert!(
        matches!(e, GaugeError::WrongUnit(ref u) if u == "in"),
        "{e:?}"
    );
    gauge_sim.faults().out_of_range = 1;
    let e = gauge.read_mm().await.unwrap_err();
    assert!(matches!(e, GaugeError::OutOfRange(v) if v > 900.0), "{e:?}");
    assert!((gauge.read_mm().await.unwrap() - 42.5).abs() < 1e-4);
}

#[tokio::test]
async fn gauge_open_missing_port_is_io_error() {
    let e = GaugeClient::open("/dev/pts/does-not-exist", gauge_cfg()).unwrap_err();
    assert!(matches!(e, GaugeError::Io(_)), "{e:?}");
}
