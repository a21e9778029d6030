//! [`UrRobot`]: the [`Robot`] trait over a Universal Robots controller's own interfaces
//! (`drivers/ur`): Dashboard server (power, brakes, remote control, program stop), RTDE
//! (joints, speeds, modes, program state; read only) and URScript (`movej`, `stopj`).
//! Radians on the wire and in the trait.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use async_trait::async_trait;
use tracing::{info, warn};
use ur::client::STATE_RECIPE;
use ur::{
    DashboardClient, RobotMode, RobotState, RtdeClient, SafetyMode, ScriptClient, UrError,
    DASHBOARD_PORT, RTDE_PORT, SECONDARY_PORT,
};

use super::{CellError, DeviceKind, FaultKind, Robot};
use crate::config::RobotSection;
use crate::plan::motion::MotionLimits;

/// The abort bound the stop deceleration is chosen for: `stopj` brings the move's speed to
/// rest within this time (s).
pub const STOP_WITHIN_S: f64 = 0.2;

/// How long the arm must stand still at its target, program ended, to count as settled (ms).
pub const SETTLE_WINDOW_MS: u64 = 100;

/// RTDE output rate the adapter asks for (Hz; a CB3 streams at most 125).
const RTDE_HZ: f64 = 125.0;

/// Configuration of a [`UrRobot`].
#[derive(Debug, Clone, PartialEq)]
pub struct UrRobotConfig {
    /// The controller's host name or IP address.
    pub host: String,
    /// Dashboard server port (29999).
    pub dashboard_port: u16,
    /// RTDE port (30004).
    pub rtde_port: u16,
    /// URScript client interface port (30002, the secondary interface).
    pub script_port: u16,
    /// TCP connect timeout (ms).
    pub connect_timeout_ms: u64,
    /// Reply timeout of a Dashboard command or RTDE request (ms).
    pub request_timeout_ms: u64,
    /// How long power on and brake release may take until the arm is RUNNING (ms).
    pub power_timeout_ms: u64,
    /// The robot file's joint speeds and accelerations at 100 % (rad/s, rad/s²).
    pub limits: MotionLimits,
    /// Largest difference of `actual_q` to the target that counts as arrived (rad).
    pub settle_tolerance_rad: f64,
    /// Joint speeds below this count as standing still (rad/s).
    pub still_rad_s: f64,
    /// How long the arm must stand still at the target, program ended (ms).
    pub settle_window_ms: u64,
}

impl UrRobotConfig {
    /// The adapter for `[robot_controller]` (protocol `ur`) of a robot with `limits` (at 100 %):
    /// `address` is the controller's host, the ports are the standard ones unless set.
    pub fn from_section(s: &RobotSection, limits: MotionLimits) -> UrRobotConfig {
        UrRobotConfig {
            host: s.address.clone(),
            dashboard_port: s.dashboard_port.unwrap_or(DASHBOARD_PORT),
            rtde_port: s.rtde_port.unwrap_or(RTDE_PORT),
            script_port: s.script_port.unwrap_or(SECONDARY_PORT),
            connect_timeout_ms: s.connect_timeout_ms.unwrap_or(5000),
            request_timeout_ms: s.request_timeout_ms.unwrap_or(5000),
            power_timeout_ms: 30_000,
            limits,
            settle_tolerance_rad: s.settle_tolerance_deg.to_radians(),
            still_rad_s: 0.001,
            settle_window_ms: SETTLE_WINDOW_MS,
        }
    }

    /// `movej`'s leading-axis speed and acceleration at `speed_pct`: the slowest joint's
    /// speed (scaled) and acceleration, so no joint exceeds its own limits.
    pub fn movej_speed(&self, speed_pct: f64) -> (f64, f64) {
        UrRobotConfig::movej_speed_of(&self.limits, speed_pct)
    }

    /// [`UrRobotConfig::movej_speed`] of `limits` (the robot file's, at 100 %).
    pub fn movej_speed_of(limits: &MotionLimits, speed_pct: f64) -> (f64, f64) {
        let v = limits
            .speed_rad_s
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
            * speed_pct
            / 100.0;
        let a = limits
            .accel_rad_s2
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let v = if v.is_finite() && v > 0.0 { v } else { 0.1 };
        let a = if a.is_finite() && a > 0.0 { a } else { 4.0 * v };
        (v, a)
    }

    /// `stopj`'s deceleration after a move at `v`, `a`: at least `v / 0.2 s` so the arm is at
    /// rest within the abort bound.
    pub fn stop_accel(v: f64, a: f64) -> f64 {
        a.max(v / STOP_WITHIN_S)
    }

    fn connect_timeout(&self) -> Duration {
        Duration::from_millis(self.connect_timeout_ms)
    }

    fn request_timeout(&self) -> Duration {
        Duration::from_millis(self.request_timeout_ms)
    }
}

fn err(kind: FaultKind, message: impl Into<String>) -> CellError {
    CellError::new(DeviceKind::Robot, kind, message)
}

/// Classify a driver error for the campaign.
pub fn classify_ur(e: &UrError) -> FaultKind {
    match e {
        UrError::Io { .. } | UrError::Closed(_) => FaultKind::Disconnected,
        UrError::Timeout(..) => FaultKind::Timeout,
        UrError::Protocol(_) | UrError::Codec(_) => FaultKind::Protocol,
        UrError::Refused { .. } | UrError::Script(_) => FaultKind::Rejected,
    }
}

fn cell_err(e: UrError) -> CellError {
    err(classify_ur(&e), e.to_string())
}

/// The fault that forbids motion in state `s`: its safety mode's ([`safety_fault`]), or an arm
/// not RUNNING (`"the arm is <mode><context>"`).
fn motion_fault(s: &RobotState, context: &str) -> Result<(), CellError> {
    if let Some(e) = safety_fault(s.safety_mode) {
        return Err(e);
    }
    if s.robot_mode != RobotMode::Running {
        return Err(err(
            FaultKind::EmergencyStop,
            format!("the arm is {}{context}", s.robot_mode.name()),
        ));
    }
    Ok(())
}

/// The fault a safety mode means for the campaign, `None` when the arm may move. Every stop
/// is the operator's to release (on the pendant); cellcal never sends `unlock protective stop`.
pub fn safety_fault(mode: SafetyMode) -> Option<CellError> {
    match mode {
        SafetyMode::Normal | SafetyMode::Reduced => None,
        m if m.is_emergency_stop() => Some(err(
            FaultKind::EmergencyStop,
            format!(
                "emergency stop ({}): release it and power the arm on the pendant",
                m.name()
            ),
        )),
        SafetyMode::ProtectiveStop => Some(err(
            FaultKind::EmergencyStop,
            "protective stop: find the cause, then unlock it on the pendant (cellcal never does)",
        )),
        m => Some(err(
            FaultKind::EmergencyStop,
            format!(
                "safety mode {}: the operator must clear it on the pendant",
                m.name()
            ),
        )),
    }
}

/// A Universal Robots controller over Dashboard, RTDE and URScript.
#[derive(Debug)]
pub struct UrRobot {
    cfg: UrRobotConfig,
    dashboard: Option<DashboardClient>,
    rtde: Option<RtdeClient>,
    speed_pct: Option<f64>,
    /// The last `movej` target and its speed and acceleration.
    target: Option<[f64; 6]>,
    last_move: Option<(f64, f64)>,
    identity: Option<String>,
    /// The controller's software version (major, minor), from RTDE once connected.
    version: Option<(u32, u32)>,
}

impl UrRobot {
    /// A robot adapter; nothing is connected until [`Robot::prepare`] or [`Robot::check`].
    pub fn new(cfg: UrRobotConfig) -> UrRobot {
        UrRobot {
            cfg,
            dashboard: None,
            rtde: None,
            speed_pct: None,
            target: None,
            last_move: None,
            identity: None,
            version: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &UrRobotConfig {
        &self.cfg
    }

    /// `host:port`, resolved. Cancel-safe: it only resolves.
    async fn addr(&self, port: u16) -> Result<SocketAddr, CellError> {
        let mut it = tokio::net::lookup_host((self.cfg.host.as_str(), port))
            .await
            .map_err(|e| {
                err(
                    FaultKind::Disconnected,
                    format!("cannot resolve UR controller {}: {e}", self.cfg.host),
                )
            })?;
        it.next().ok_or_else(|| {
            err(
                FaultKind::Disconnected,
                format!("UR controller {} has no address", self.cfg.host),
            )
        })
    }

    /// The Dashboard connection, taken out of `self` for one command (a dropped command then
    /// drops the connection, never leaving a reply unread). Cancel-safe.
    async fn take_dashboard(&mut self) -> Result<DashboardClient, CellError> {
        if let Some(d) = self.dashboard.take() {
            return Ok(d);
        }
        let addr = self.addr(self.cfg.dashboard_port).await?;
        DashboardClient::connect(
            addr,
            self.cfg.request_timeout().max(self.cfg.connect_timeout()),
        )
        .await
        .map_err(cell_err)
    }

    /// The RTDE connection (version 2, the state recipe, started), taken out of `self` as
    /// [`UrRobot::take_dashboard`]. Cancel-safe: a drop leaves no connection.
    async fn take_rtde(&mut self) -> Result<RtdeClient, CellError> {
        if let Some(r) = self.rtde.take() {
            return Ok(r);
        }
        let addr = self.addr(self.cfg.rtde_port).await?;
        let mut r = RtdeClient::connect(addr, self.cfg.request_timeout())
            .await
            .map_err(cell_err)?;
        let v = r.controller_version().await.map_err(cell_err)?;
        r.setup_outputs(&STATE_RECIPE, RTDE_HZ)
            .await
            .map_err(cell_err)?;
        r.start().await.map_err(cell_err)?;
        let id = format!(
            "Universal Robots controller {}.{}.{}.{} at {}",
            v.major, v.minor, v.bugfix, v.build, self.cfg.host
        );
        info!(identity = %id, "UR controller connected");
        self.identity = Some(id);
        self.version = Some((v.major, v.minor));
        Ok(r)
    }

    /// The newest RTDE state. Cancel-safe: the connection is out of `self` while read, so a
    /// drop closes it and the next call opens a new one.
    async fn state(&mut self) -> Result<RobotState, CellError> {
        let mut r = self.take_rtde().await?;
        let t = self.cfg.request_timeout();
        let s = tokio::time::timeout(t, r.latest_state())
            .await
            .map_err(|_| err(FaultKind::Timeout, format!("RTDE: no data within {t:?}")))?
            .map_err(cell_err)?;
        self.rtde = Some(r);
        Ok(s)
    }

    /// One Dashboard command through `f`. Cancel-safe (see [`UrRobot::take_dashboard`]).
    async fn dashboard<T, F>(&mut self, f: F) -> Result<T, CellError>
    where
        F: for<'a> FnOnce(
            &'a mut DashboardClient,
        ) -> std::pin::Pin<
            Box<dyn std::future::Future<Output = Result<T, UrError>> + Send + 'a>,
        >,
    {
        let mut d = self.take_dashboard().await?;
        let out = f(&mut d).await;
        if !matches!(&out, Err(e) if classify_ur(e) != FaultKind::Rejected) {
            self.dashboard = Some(d);
        }
        out.map_err(cell_err)
    }

    fn script(&self, addr: SocketAddr) -> ScriptClient {
        ScriptClient::new(addr, self.cfg.request_timeout())
    }

    /// Whether the controller answers `is in remote control` (PolyScope 5.6 on; a CB3 has no
    /// local/remote mode, and an e-Series before 5.6 refuses remote-only commands in Local
    /// control with its own reply, which reaches the operator). Known once RTDE is connected.
    fn reports_remote_control(&self) -> bool {
        self.version.is_none_or(|v| v >= (5, 6))
    }

    /// Refuses unless the pendant is in remote control (scripts and power commands need it),
    /// where the controller reports it ([`Self::reports_remote_control`]). Cancel-safe.
    async fn require_remote(&mut self) -> Result<(), CellError> {
        if !self.reports_remote_control() {
            return Ok(());
        }
        let remote = self
            .dashboard(|d| Box::pin(d.is_in_remote_control()))
            .await?;
        if remote {
            Ok(())
        } else {
            Err(err(
                FaultKind::Rejected,
                "the UR controller is in Local control: switch the pendant to Remote \
                 (Settings > System > Remote Control)",
            ))
        }
    }

    /// Waits until RTDE reports the arm RUNNING (power on, brakes released) in a safety mode
    /// that allows motion. Cancel-safe.
    async fn wait_running(&mut self) -> Result<(), CellError> {
        let deadline = Instant::now() + Duration::from_millis(self.cfg.power_timeout_ms);
        loop {
            let s = self.state().await?;
            if let Some(e) = safety_fault(s.safety_mode) {
                return Err(e);
            }
            if s.robot_mode == RobotMode::Running {
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(err(
                    FaultKind::NotReady,
                    format!(
                        "the arm is {} after {} ms, not RUNNING",
                        s.robot_mode.name(),
                        self.cfg.power_timeout_ms
                    ),
                ));
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

fn six(q: &[f64]) -> Result<[f64; 6], CellError> {
    let q: [f64; 6] = q.try_into().map_err(|_| {
        err(
            FaultKind::Rejected,
            format!("a UR arm has 6 joints, got {}", q.len()),
        )
    })?;
    if q.iter().any(|v| !v.is_finite()) {
        return Err(err(FaultKind::Rejected, "joint target is not finite"));
    }
    Ok(q)
}

#[async_trait]
impl Robot for UrRobot {
    /// Remote control checked, safety mode checked, then Dashboard `power on` and `brake
    /// release`, waiting until the arm is RUNNING: the only place that powers the arm (called
    /// by the engine after arming). Cancel-safe: a drop may have powered the arm.
    async fn prepare(&mut self, speed_pct: f64) -> Result<(), CellError> {
        if !(speed_pct > 0.0 && speed_pct <= 100.0) {
            return Err(err(
                FaultKind::Rejected,
                format!("speed {speed_pct} % not in (0, 100]"),
            ));
        }
        // RTDE first: the controller's version says whether it reports remote control
        let s = self.state().await?;
        self.require_remote().await?;
        if let Some(e) = safety_fault(s.safety_mode) {
            return Err(e);
        }
        if s.robot_mode != RobotMode::Running {
            self.dashboard(|d| Box::pin(d.power_on())).await?;
            self.dashboard(|d| Box::pin(d.brake_release())).await?;
        }
        self.wait_running().await?;
        self.speed_pct = Some(speed_pct);
        Ok(())
    }

    /// `def cellcal_move(): movej(q, a, v) end` on the secondary interface, after RTDE says
    /// the arm is RUNNING in a normal safety mode. Cancel-safe in the trait's sense: a dropped
    /// call may have sent a program (or part of one, which the controller does not run).
    async fn move_joints(&mut self, q_rad: &[f64]) -> Result<(), CellError> {
        let q = six(q_rad)?;
        let speed = self.speed_pct.ok_or_else(|| {
            err(
                FaultKind::NotReady,
                "the UR arm was not prepared (power, brakes, speed)",
            )
        })?;
        let s = self.state().await?;
        motion_fault(&s, ", not RUNNING")?;
        let (v, a) = self.cfg.movej_speed(speed);
        let addr = self.addr(self.cfg.script_port).await?;
        self.target = Some(q);
        self.last_move = Some((v, a));
        self.script(addr).movej(&q, a, v).await.map_err(cell_err)
    }

    /// Follows RTDE until `actual_q` is within the settle tolerance of the target, every joint
    /// speed below the threshold and no program runs, for the settle window; a safety stop or
    /// lost power ends it with the fault. Cancel-safe: a drop leaves the arm moving.
    async fn wait_settled(&mut self, timeout: Duration) -> Result<Vec<f64>, CellError> {
        let target = self
            .target
            .ok_or_else(|| err(FaultKind::Rejected, "no move to wait for"))?;
        let deadline = Instant::now() + timeout;
        let window = Duration::from_millis(self.cfg.settle_window_ms);
        let mut since: Option<Instant> = None;
        loop {
            let s = self.state().await?;
            motion_fault(&s, " during the move")?;
            let at = s
                .actual_q
                .iter()
                .zip(&target)
                .all(|(a, b)| (a - b).abs() <= self.cfg.settle_tolerance_rad);
            let still = s.actual_qd.iter().all(|v| v.abs() <= self.cfg.still_rad_s);
            let now = Instant::now();
            if at && still && !s.program_running() {
                let t0 = *since.get_or_insert(now);
                if now.duration_since(t0) >= window {
                    return Ok(s.actual_q.to_vec());
                }
            } else {
                since = None;
            }
            if now >= deadline {
                return Err(err(
                    FaultKind::Timeout,
                    format!(
                        "not settled within {timeout:?} (at target {at}, standing still {still}, \
                         program running {})",
                        s.program_running()
                    ),
                ));
            }
            tokio::time::sleep(Duration::from_millis(8)).await;
        }
    }

    /// RTDE `actual_q`. Cancel-safe.
    async fn joints(&mut self) -> Result<Vec<f64>, CellError> {
        Ok(self.state().await?.actual_q.to_vec())
    }

    /// Dashboard `stop` (ends the running program), then `stopj(a)` with `a` ≥ the move's
    /// speed / 0.2 s. Succeeds when either reached the controller. Cancel-safe: each step uses
    /// its own connection or a fresh one.
    async fn stop(&mut self) -> Result<(), CellError> {
        let dash = self.dashboard(|d| Box::pin(d.stop())).await;
        let (v, a) = self
            .last_move
            .unwrap_or_else(|| self.cfg.movej_speed(self.speed_pct.unwrap_or(100.0)));
        let script = match self.addr(self.cfg.script_port).await {
            Ok(addr) => self
                .script(addr)
                .stopj(UrRobotConfig::stop_accel(v, a))
                .await
                .map_err(cell_err),
            Err(e) => Err(e),
        };
        match (dash, script) {
            (_, Ok(())) => Ok(()),
            // the program is stopped (or none ran): the arm decelerates at the controller's rate
            (Ok(()), Err(e))
            | (
                Err(CellError {
                    kind: FaultKind::Rejected,
                    ..
                }),
                Err(e),
            ) => {
                warn!(error = %e, "UR stopj not sent after Dashboard stop");
                Ok(())
            }
            (_, Err(e)) => Err(e),
        }
    }

    /// New Dashboard and RTDE connections; power is left as it is. Cancel-safe: a dropped call
    /// leaves no connection or complete ones.
    async fn reconnect(&mut self) -> Result<(), CellError> {
        self.dashboard = None;
        self.rtde = None;
        let d = self.take_dashboard().await?;
        let r = self.take_rtde().await?;
        self.dashboard = Some(d);
        self.rtde = Some(r);
        Ok(())
    }

    /// Connect if needed, then RTDE modes and joints and the Dashboard's remote-control state:
    /// no power, no brake release, no script. Cancel-safe.
    async fn check(&mut self) -> Result<String, CellError> {
        let s = self.state().await?;
        let remote = match self.version {
            Some((major, minor)) if !self.reports_remote_control() => Ok(format!(
                "remote control not reported (controller {major}.{minor}, before PolyScope 5.6)"
            )),
            _ => Err(()),
        };
        let remote = match remote {
            Ok(text) => text,
            Err(()) => match self.dashboard(|d| Box::pin(d.is_in_remote_control())).await {
                Ok(true) => "remote control".to_owned(),
                Ok(false) => "LOCAL control (switch the pendant to Remote)".to_owned(),
                Err(e) => format!("remote control unknown ({e})"),
            },
        };
        let joints: Vec<String> = s
            .actual_q
            .iter()
            .map(|q| format!("{:.3}", q.to_degrees()))
            .collect();
        Ok(format!(
            "{}; robot mode {}, safety mode {}, {}, {}; joints [{}] deg",
            self.identity.as_deref().unwrap_or("UR controller"),
            s.robot_mode.name(),
            s.safety_mode.name(),
            remote,
            if s.program_running() {
                "program RUNNING"
            } else {
                "no program running"
            },
            joints.join(", ")
        ))
    }

    fn identity(&self) -> Option<String> {
        self.identity.clone()
    }
}
