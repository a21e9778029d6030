//! Device traits of the cell (Tracker, Robot, Stage, Prompter) and their adapters over the
//! protocol crates in `drivers/`.
//!
//! The campaign only sees these traits. Units at this boundary are mm and rad; adapters
//! convert at the protocol edge (robotlink speaks degrees, Zaber microsteps).
//!
//! Adapters: [`EmsconTracker`] (Leica emScon TPI), [`LinkRobot`] (robotlink line protocol),
//! [`UrRobot`] (Universal Robots Dashboard, RTDE and URScript),
//! [`ZaberStageAdapter`] (Zaber ASCII stage), [`ManualStage`] (micrometer set by the technician,
//! optionally read by an RS-232 gauge); prompters [`ScriptedPrompter`] and [`ChannelPrompter`].

pub mod prompt;
pub mod robot_link;
pub mod robot_ur;
pub mod stage_manual;
pub mod stage_zaber;
#[cfg(test)]
mod tests;
pub mod tracker_emscon;

pub use prompt::{ChannelPrompter, PendingPrompt, ScriptedPrompter};
pub use robot_link::{controller_secret, LinkRobot, LinkRobotConfig, RobotSecretError};
pub use robot_ur::{UrRobot, UrRobotConfig};
pub use stage_manual::{GaugeReader, ManualStage, ManualStageConfig};
pub use stage_zaber::{ZaberStageAdapter, ZaberStageAdapterConfig};
pub use tracker_emscon::{EmsconTracker, EmsconTrackerConfig};

use std::time::{Duration, SystemTime};

use async_trait::async_trait;
use nalgebra::Vector3;

/// Which device a fault came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DeviceKind {
    /// The laser tracker.
    Tracker,
    /// The robot controller.
    Robot,
    /// The 1D stage (motorised, gauge or manual).
    Stage,
    /// The technician (prompts).
    Operator,
}

impl DeviceKind {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            DeviceKind::Tracker => "tracker",
            DeviceKind::Robot => "robot",
            DeviceKind::Stage => "stage",
            DeviceKind::Operator => "operator",
        }
    }
}

/// Classified fault, as the campaign needs it to decide what to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultKind {
    /// Tracker beam broken / target lost: discard, re-lock, measure again.
    BeamBroken,
    /// No answer in time.
    Timeout,
    /// The connection is gone: reconnect.
    Disconnected,
    /// The device refused the command (limit, unreachable, bad data, not homed …).
    Rejected,
    /// Emergency stop or power loss: the operator must intervene.
    EmergencyStop,
    /// The device is not ready (not initialised, not warmed up, busy).
    NotReady,
    /// The device spoke nonsense.
    Protocol,
    /// The operator aborted.
    Aborted,
    /// Anything else reported by the device.
    Device,
}

/// An error from a cell device.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{} {kind:?}: {message}", device.name())]
pub struct CellError {
    /// Which device.
    pub device: DeviceKind,
    /// What kind of fault.
    pub kind: FaultKind,
    /// Detail from the driver.
    pub message: String,
}

impl CellError {
    /// Build an error.
    pub fn new(device: DeviceKind, kind: FaultKind, message: impl Into<String>) -> CellError {
        CellError {
            device,
            kind,
            message: message.into(),
        }
    }

    /// Whether retrying (after a re-lock or reconnect) may help.
    pub fn is_transient(&self) -> bool {
        matches!(
            self.kind,
            FaultKind::BeamBroken
                | FaultKind::Timeout
                | FaultKind::Disconnected
                | FaultKind::NotReady
                | FaultKind::Protocol
        )
    }
}

/// One stationary tracker measurement (measurement frame, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerPoint {
    /// Position (mm).
    pub p_mm: Vector3<f64>,
    /// Per-axis standard deviation (mm).
    pub std_mm: [f64; 3],
    /// Total standard deviation (mm).
    pub std_total_mm: f64,
    /// Air temperature (°C).
    pub temperature_c: f64,
    /// Air pressure (mbar).
    pub pressure_mbar: f64,
    /// Relative humidity (%).
    pub humidity_pct: f64,
    /// Local time the measurement was requested.
    pub sent_at: SystemTime,
    /// Local time the result arrived.
    pub received_at: SystemTime,
}

/// A laser tracker.
///
/// Cancel-safety contract: the engine drops any of these futures when a campaign is aborted
/// (`guarded` in `campaign::engine`) and on its own timeouts, so every method must be
/// cancel-safe: a drop at any await may leave the device mid-command, but never a stream out
/// of step (a late reply or result is dropped, or the connection is closed so the next call
/// fails `Disconnected` and [`Tracker::reconnect`] recovers).
#[async_trait]
pub trait Tracker: Send + Sync {
    /// Connect if needed and configure for stationary measurement (units, mode, reflector).
    /// Must be cancel-safe (see the trait): a dropped call leaves a setup to run again.
    async fn prepare(&mut self) -> Result<(), CellError>;
    /// One stationary measurement of the reflector. Must be cancel-safe (see the trait): the
    /// result of a dropped measurement must never be returned by a later call.
    async fn measure(&mut self) -> Result<TrackerPoint, CellError>;
    /// Re-acquire the target after a beam break: first where the ball should be
    /// (`predicted_mm`, tracker frame, when the caller knows it), then at the last measured
    /// point, then by a search; `Ok` only with a reflector locked. Must be cancel-safe (see the
    /// trait); a dropped call may leave the beam moving.
    async fn relock(&mut self, predicted_mm: Option<Vector3<f64>>) -> Result<(), CellError>;
    /// Drop and re-establish the connection, then prepare again. Must be cancel-safe (see the
    /// trait): a dropped call leaves no connection or a complete one.
    async fn reconnect(&mut self) -> Result<(), CellError>;
    /// Connect if needed and report what the tracker says without moving its head (no
    /// Initialize, no search, no measurement): one line for the operator (`cellcal run`
    /// without `--arm`). Must be cancel-safe (see the trait).
    async fn check(&mut self) -> Result<String, CellError> {
        Err(cannot_check(DeviceKind::Tracker))
    }
    /// What the device said it is at its last successful connection (model, serial, firmware),
    /// for the campaign journal and the report; `None` before one or when it cannot say.
    fn identity(&self) -> Option<String> {
        None
    }
}

/// The refusal of a device that has no check without motion.
fn cannot_check(device: DeviceKind) -> CellError {
    CellError::new(
        device,
        FaultKind::Device,
        "this device cannot be checked without motion",
    )
}

/// A robot controller.
///
/// Cancel-safety contract: the engine drops any of these futures when a campaign is aborted
/// (`guarded` in `campaign::engine`) and on its own timeouts, then calls [`Robot::stop`]; so
/// every method must be cancel-safe: a drop never leaves the link out of step, and `stop`
/// must reach the arm right after a dropped `move_joints` or `wait_settled` (dropping those
/// does not stop the arm by itself).
#[async_trait]
pub trait Robot: Send + Sync {
    /// Connect if needed, identify, power on and set the speed (percent of maximum). Must be
    /// cancel-safe (see the trait); a dropped call may have switched power on.
    async fn prepare(&mut self, speed_pct: f64) -> Result<(), CellError>;
    /// Start a joint move to `q_rad` (returns when accepted, not when finished). Must be
    /// cancel-safe (see the trait); a dropped call may still have started the move.
    async fn move_joints(&mut self, q_rad: &[f64]) -> Result<(), CellError>;
    /// Wait until the robot has settled; returns the joints read after settling (rad). Must be
    /// cancel-safe (see the trait); a drop leaves the arm moving until [`Robot::stop`].
    async fn wait_settled(&mut self, timeout: Duration) -> Result<Vec<f64>, CellError>;
    /// Current joints (rad). Must be cancel-safe (see the trait).
    async fn joints(&mut self) -> Result<Vec<f64>, CellError>;
    /// Stop any motion now. Must be cancel-safe (see the trait) and work after any other
    /// call was dropped; the engine bounds it with a timeout, so it may itself be dropped.
    async fn stop(&mut self) -> Result<(), CellError>;
    /// Drop and re-establish the connection; never switches power on (only `prepare` does).
    /// Must be cancel-safe (see the trait): a dropped call leaves no connection or a complete
    /// one.
    async fn reconnect(&mut self) -> Result<(), CellError>;
    /// Connect if needed and report what the controller says without power or motion (its
    /// identity, STATE, the joints): one line for the operator (`cellcal run` without
    /// `--arm`). Must be cancel-safe (see the trait).
    async fn check(&mut self) -> Result<String, CellError> {
        Err(cannot_check(DeviceKind::Robot))
    }
    /// What the device said it is at its last successful connection (model, serial, firmware),
    /// for the campaign journal and the report; `None` before one or when it cannot say.
    fn identity(&self) -> Option<String> {
        None
    }
}

/// The 1D stage carrying the target ball.
///
/// Cancel-safety contract: the engine drops these futures when a campaign is aborted
/// (`guarded` in `campaign::engine`), so every method must be cancel-safe: a drop may leave a
/// move or homing under way (or a question open), but the next call must not take a late
/// reply or reading for its own.
#[async_trait]
pub trait Stage: Send + Sync {
    /// Whether a person moves it (prompts).
    fn is_manual(&self) -> bool;
    /// Prepare (home a motorised stage). Must be cancel-safe (see the trait).
    async fn prepare(&mut self) -> Result<(), CellError>;
    /// Move to `position_mm`; returns the read-back or confirmed position (mm). Must be
    /// cancel-safe (see the trait); a dropped call may leave the move under way.
    async fn move_to(&mut self, position_mm: f64) -> Result<f64, CellError>;
    /// What the engine is doing at the next [`Stage::move_to`] (a manual stage shows it with
    /// its question); a motorised stage ignores it.
    fn set_prompt_context(&mut self, _context: PromptContext) {}
    /// Stop any stage motion now (a motorised stage: the driver's stop, then idle; a manual
    /// stage has nothing to stop). Must be cancel-safe (see the trait) and work after a dropped
    /// [`Stage::move_to`]; the engine bounds it with a timeout.
    async fn stop(&mut self) -> Result<(), CellError> {
        Ok(())
    }
    /// Open the device if needed and report what it says without any motion (no homing):
    /// one line for the operator (`cellcal run` without `--arm`). Must be cancel-safe (see
    /// the trait).
    async fn check(&mut self) -> Result<String, CellError> {
        Err(cannot_check(DeviceKind::Stage))
    }
    /// Whether a person may have a hand at the stage after a [`Stage::move_to`] (a manual
    /// stage), so that no robot motion may follow before [`Stage::confirm_clear`].
    fn needs_clear(&self) -> bool {
        false
    }
    /// Ask the technician to confirm that the cell is clear before the robot moves again (a
    /// prompt [`CONFIRM_CLEAR`] answered only by [`Answer::Clear`]); `Ok` at once when
    /// [`Stage::needs_clear`] is false. Must be cancel-safe (see the trait): a dropped call
    /// withdraws the question and confirms nothing.
    async fn confirm_clear(&mut self, _context: PromptContext) -> Result<(), CellError> {
        Ok(())
    }
    /// What the device said it is at its last successful connection (model, serial, firmware),
    /// for the campaign journal and the report; `None` before one or when it cannot say.
    fn identity(&self) -> Option<String> {
        None
    }
}

/// The two stage positions a pose is measured at.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
pub enum StagePosition {
    /// The first stage position (`stage.p1_mm`).
    P1,
    /// The second stage position (`stage.p1_mm + stage.travel_mm`).
    P2,
}

/// What the engine is doing when a question is asked, for the technician; null (or false) when
/// not known (a front end must not claim what is not stated here).
#[derive(
    Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
pub struct PromptContext {
    /// What the stage move is for: `pose`, `drift` (drift check at the reference pose),
    /// `setup` (tool frame, base registration) or `reregister`; null when not known.
    pub step: Option<String>,
    /// The pose being measured, counted from 1 in measuring order (n of `poses_total`).
    pub pose: Option<usize>,
    /// Poses planned in the campaign (N).
    pub poses_total: Option<usize>,
    /// The stage position asked for (`P1` or `P2`); null for any other position.
    pub position: Option<StagePosition>,
    /// The controller reported the robot settled at its target and the engine commands no
    /// motion until this question is answered (and, with `[stage] confirm_clear`, until the
    /// technician confirmed the cell clear): safe to approach the stage.
    pub robot_stopped: bool,
    /// Why the previous answer to the same request was refused (out of tolerance, not a
    /// number); null on the first ask.
    pub retry_reason: Option<String>,
}

impl PromptContext {
    /// One line for the technician: `pose 3 of 20 · P2 · robot stopped — safe to approach`
    /// (only what is known; an unknown robot state says to check it).
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        match (self.step.as_deref(), self.pose, self.poses_total) {
            (_, Some(n), Some(total)) => parts.push(format!("pose {n} of {total}")),
            (_, Some(n), None) => parts.push(format!("pose {n}")),
            (Some("drift"), ..) => parts.push("drift check at the reference pose".into()),
            (Some("setup"), ..) => parts.push("setup".into()),
            (Some("reregister"), ..) => parts.push("re-registering the tracker frame".into()),
            _ => {}
        }
        match self.position {
            Some(StagePosition::P1) => parts.push("P1".into()),
            Some(StagePosition::P2) => parts.push("P2".into()),
            None => {}
        }
        parts.push(if self.robot_stopped {
            "robot stopped — safe to approach".into()
        } else {
            "robot state not known — check that it stands still before approaching".into()
        });
        parts.join(" · ")
    }
}

/// A question to the technician.
#[derive(Debug, Clone, PartialEq)]
pub struct Prompt {
    /// Short id for front ends (`stage_p2`, `drift_ok`, …).
    pub id: String,
    /// The text shown to the technician.
    pub text: String,
    /// Expected numeric answer (mm), if a number is asked for.
    pub expected_mm: Option<f64>,
    /// What the engine is doing (pose n of N, P1 or P2, robot stopped, why re-asked).
    pub context: PromptContext,
}

/// The id of the question that asks the technician to confirm the cell clear before the robot
/// moves again; only [`Answer::Clear`] (or [`Answer::Abort`]) answers it.
pub const CONFIRM_CLEAR: &str = "confirm_clear";

/// The technician's answer.
#[derive(Debug, Clone, PartialEq)]
pub enum Answer {
    /// A number (e.g. the micrometer reading, mm).
    Number(f64),
    /// Confirmed without a number.
    Confirmed,
    /// The cell is clear: nobody at the stage, the robot may move (the deliberate answer to a
    /// [`CONFIRM_CLEAR`] question; no other question takes it).
    Clear,
    /// Abort the campaign.
    Abort,
}

/// Asks the technician (terminal, web page, or a scripted answerer in headless runs).
///
/// Cancel-safety contract: the engine drops a pending `ask` when a campaign is aborted, so it
/// must be cancel-safe: a dropped question is withdrawn or, if a front end still shows it,
/// answering it does nothing (the answer is never given to a later question).
#[async_trait]
pub trait Prompter: Send + Sync {
    /// Ask and wait for an answer. Must be cancel-safe (see the trait).
    async fn ask(&self, prompt: Prompt) -> Result<Answer, CellError>;
}
