use std::time::Duration;

use zaber::pty::{spawn_stage_pty, PtyDevice};
use zaber::sim::{StageSim, StageSimConfig};
use zaber::{StageConfig, ZaberStage};

/// Microsteps per mm of the simulated product at its default resolution 64.
pub const STEPS_PER_MM: f64 = 64.0 / 0.003_048;

pub fn stage_cfg() -> StageConfig {
    StageConfig {
        min_mm: 0.0,
        max_mm: 5000.0,
        tolerance_mm: 0.001,
        reply_timeout: Duration::from_millis(200),
        poll_interval: Duration::from_millis(5),
        move_timeout: Duration::from_millis(500),
        home_timeout: Duration::from_millis(500),
        ..Default::default()
    }
}

pub fn sim(homed: bool) -> StageSim {
    StageSim::new(StageSimConfig {
        homed,
        ..Default::default()
    })
}

/// Simulated stage on a pty plus a client that opened the slave path with tokio-serial.
pub fn stage_on_pty(homed: bool) -> (StageSim, PtyDevice, ZaberStage<tokio_serial::SerialStream>) {
    let sim = sim(homed);
    let dev = spawn_stage_pty(sim.clone()).expect("pty");
    assert!(dev.path().starts_with("/dev/pts/"), "{}", dev.path());
    let stage = ZaberStage::open(&dev.path(), stage_cfg()).expect("open slave via tokio-serial");
    (sim, dev, stage)
}
