//! A simulated controller on free loopback ports, and a client set for it.

use std::net::{IpAddr, Ipv4Addr};
use std::time::Duration;

use ur::client::{DashboardClient, RtdeClient, ScriptClient, STATE_RECIPE};
use ur::{ControllerConfig, RobotMode, RobotState, ServerConfig, SimController, UrServers};
use ur::{TrapezoidMotion, UrError};

pub const TIMEOUT: Duration = Duration::from_secs(3);
pub const HOME: [f64; 6] = [0.0, -1.5, 1.5, -1.5, -1.5, 0.0];

/// A controller with short state-change delays on 127.0.0.1 free ports.
pub async fn start(config: ControllerConfig) -> (SimController, UrServers) {
    let c = SimController::new(config, Box::new(TrapezoidMotion::new(HOME)));
    let s = UrServers::start(
        c.clone(),
        &ServerConfig::ephemeral(IpAddr::V4(Ipv4Addr::LOCALHOST)),
    )
    .await
    .expect("bind loopback");
    (c, s)
}

/// Fast delays (the real ones are seconds).
pub fn fast() -> ControllerConfig {
    ControllerConfig {
        power_on_delay: Duration::from_millis(50),
        brake_release_delay: Duration::from_millis(50),
        unlock_delay: Duration::from_millis(300),
        ..ControllerConfig::default()
    }
}

/// Polls `robotmode` until `want` (2 s at most).
pub async fn wait_mode(d: &mut DashboardClient, want: RobotMode) {
    let end = tokio::time::Instant::now() + Duration::from_secs(2);
    loop {
        let m = d.robot_mode().await.expect("robotmode");
        if m == want {
            return;
        }
        assert!(
            tokio::time::Instant::now() < end,
            "robot mode {m:?}, want {want:?}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Dashboard power on + brake release until RUNNING.
pub async fn make_running(s: &UrServers) -> DashboardClient {
    let mut d = DashboardClient::connect(s.dashboard, TIMEOUT)
        .await
        .expect("dashboard");
    d.power_on().await.expect("power on");
    wait_mode(&mut d, RobotMode::Idle).await;
    d.brake_release().await.expect("brake release");
    wait_mode(&mut d, RobotMode::Running).await;
    d
}

/// An RTDE client streaming [`STATE_RECIPE`] at 125 Hz.
pub async fn rtde(s: &UrServers) -> RtdeClient {
    let mut r = RtdeClient::connect(s.rtde, TIMEOUT).await.expect("rtde");
    r.setup_outputs(&STATE_RECIPE, 125.0).await.expect("setup");
    r.start().await.expect("start");
    r
}

pub fn script(s: &UrServers) -> ScriptClient {
    ScriptClient::new(s.script[0], TIMEOUT)
}

/// Follows RTDE until `done(state)` (3 s at most); returns the states seen.
pub async fn follow(
    r: &mut RtdeClient,
    mut done: impl FnMut(&RobotState) -> bool,
) -> Result<Vec<RobotState>, UrError> {
    let end = tokio::time::Instant::now() + Duration::from_secs(3);
    let mut seen = Vec::new();
    loop {
        let st = ur::RobotState::from_package(&r.next_data().await?)?;
        seen.push(st);
        if done(&st) {
            return Ok(seen);
        }
        assert!(
            tokio::time::Instant::now() < end,
            "condition not reached; last state {st:?}"
        );
    }
}

pub fn max_abs_diff(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
