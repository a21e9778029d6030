//! The measurement loop and its fault policy.
//!
//! Fault policy: a beam break discards the point in progress, re-locks and measures again (a
//! point is never averaged across a break); a point above the quality gate is stored as
//! `discarded` and measured again; a disconnect or timeout reconnects and retries. A device that
//! keeps failing (after `max_attempts`), a device error, an emergency stop or a drift above the
//! threshold is an *operator fault*: with [`FaultPolicy::Pause`] the campaign pauses with the
//! reason and, on resume, re-prepares the devices and measures the whole pose again (a reading
//! taken before the fault is kept as `discarded`); with [`FaultPolicy::Fail`] (headless runs) it stops
//! in `failed`, resumable. A safety refusal (target outside the limits or the
//! workspace, no route whose every leg passes the path check) always stops in `failed`. Abort cancels every wait, stops the robot and the stage
//! and leaves the campaign resumable at the first unmeasured pose; a disarm does the same and
//! pauses (resumed only once armed again). With a manual stage, no robot move follows a stage
//! answer before the technician confirmed the cell clear ([`Run::ensure_clear`]). Every event (state change, measured pose,
//! fault, drift check, setup, note, result) is journalled in the store's `events` table before
//! it is emitted, and emitted with its journal sequence number ([`journal_event`]). Whatever
//! ends a run, the stored state is a final one ([`run_campaign`]).

mod frame;
mod setup;
mod stop;
#[cfg(test)]
mod tests_fake;

pub use setup::{BaseResult, SetupResult, ToolFrameResult};
pub use stop::{
    decide as stop_decision, predict_check, stop_block, CheckPrediction,
    Thresholds as StopThresholds,
};

use std::future::Future;
use std::time::Duration;

use nalgebra::Vector3;

use super::events::{CampaignEvent, CampaignState, Control};
use crate::calibrate::{calibrate_result, BaseSource, CalibrateError, IdentCheck, IdentifyReport};
use crate::cell::{
    CellError, DeviceKind, FaultKind, PromptContext, Robot, Stage, StagePosition, Tracker,
    TrackerPoint,
};
use crate::config::CellConfig;
use crate::dataset::{Observation, PoseSet};
use crate::identify::{IdentifyOptions, ObsConfig};
use crate::iso9283::IsoReport;
use crate::model::RobotModel;
use crate::plan::iso9283::IsoPlan;
use crate::plan::{campaign_router, target_ok, Plan, PlanEntry, PlanRequest, RouteError, Router};
use crate::store::{
    identification_rows, PointKind, PointRecord, PoseMeasurement, Store, StoreError, StoreHandle,
};
use crate::wall_clock::{now_unix_ms, unix_ms};

/// The three devices of the cell.
pub struct Devices {
    /// Laser tracker.
    pub tracker: Box<dyn Tracker>,
    /// Robot controller.
    pub robot: Box<dyn Robot>,
    /// Stage.
    pub stage: Box<dyn Stage>,
}

/// What the engine does when a fault needs the operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FaultPolicy {
    /// Pause with the reason; `Resume` retries the step, `Abort` ends the run (daemon, terminal).
    #[default]
    Pause,
    /// Stop in `failed` (resumable): for runs with nobody to answer.
    Fail,
}

/// Everything a campaign run needs besides the devices.
pub struct CampaignContext {
    /// Cell configuration.
    pub cfg: CellConfig,
    /// Nominal robot model (with the configured tool).
    pub nominal: RobotModel,
    /// Planning constraints (re-checked before every move).
    pub plan_request: PlanRequest,
    /// The plan (drift reference included).
    pub plan: Plan,
    /// The store.
    pub store: StoreHandle,
    /// Campaign id in the store.
    pub campaign_id: i64,
    /// Commands and events.
    pub control: Control,
    /// What an operator fault does.
    pub on_fault: FaultPolicy,
    /// An ISO 9283 campaign's plan (then the run ends with the ISO figures, not an
    /// identification); `None` for a calibration campaign.
    pub iso: Option<IsoPlan>,
    /// The planned duration of the whole plan on this cell, measured afresh
    /// ([`crate::campaign::estimate::estimate_campaign_time`]); `None` when not estimated.
    pub estimate: Option<crate::plan::CampaignEstimate>,
}

/// How a run ended.
#[derive(Debug, Clone)]
pub enum Outcome {
    /// Every pose measured and identified.
    Done(Box<IdentifyReport>),
    /// Every visit of an ISO 9283 campaign measured, its figures computed and stored.
    Iso(Box<IsoReport>),
    /// Aborted by the operator; resumable.
    Aborted,
    /// Stopped by a fault; resumable.
    Failed(String),
}

/// An error that ends a run without a resumable state change.
#[derive(Debug, thiserror::Error)]
pub enum CampaignError {
    /// The store failed (its message names the campaign store).
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The identification failed.
    #[error("identification: {0}")]
    Identify(CalibrateError),
    /// A store task panicked or was cancelled.
    #[error("store task failed: {0}")]
    Task(String),
    /// The ISO 9283 figures could not be computed.
    #[error("ISO 9283 figures: {0}")]
    Iso(String),
}

from_cause!(CalibrateError => CampaignError::Identify);

enum Stop {
    /// The operator aborted.
    Aborted,
    /// The campaign was disarmed: every device is stopped and the campaign pauses until it is
    /// armed and resumed (whatever the [`FaultPolicy`]: a disarm is an operator's act).
    Disarmed,
    /// A safety refusal: never retried.
    Failed(String),
    /// A fault the operator can fix (pause and retry, or fail, per [`FaultPolicy`]).
    Fault(String),
    Store(CampaignError),
}

impl From<CampaignError> for Stop {
    fn from(e: CampaignError) -> Stop {
        Stop::Store(e)
    }
}

fn record(p: &TrackerPoint, stage_mm: f64) -> PointRecord {
    PointRecord {
        x_mm: p.p_mm.x,
        y_mm: p.p_mm.y,
        z_mm: p.p_mm.z,
        std_mm: p.std_mm,
        std_total_mm: p.std_total_mm,
        temperature_c: p.temperature_c,
        pressure_mbar: p.pressure_mbar,
        humidity_pct: p.humidity_pct,
        stage_mm,
        sent_at_ms: unix_ms(p.sent_at),
        received_at_ms: unix_ms(p.received_at),
    }
}

/// Why a robot fault after a reconnect pauses instead of retrying: the arm is not powered on
/// behind the operator's back.
const ROBOT_RECONNECTED: &str = "robot controller reconnected: check the cell, then resume";

/// Which joint settled farther than `tol` (rad) from its target, if any.
fn settle_error(target: &[f64], settled: &[f64], tol: f64) -> Option<String> {
    if target.len() != settled.len() {
        return Some(format!(
            "the controller reported {} joints for a {}-joint target",
            settled.len(),
            target.len()
        ));
    }
    let (k, off) = target
        .iter()
        .zip(settled)
        .map(|(t, s)| (s - t).abs())
        .enumerate()
        .fold((0, 0.0_f64), |best, (k, d)| {
            if d.is_nan() || d > best.1 {
                (k, d)
            } else {
                best
            }
        });
    (off.is_nan() || off > tol).then(|| {
        format!(
            "joint {} settled {:.4} deg from its target (tolerance {:.4} deg)",
            k + 1,
            off.to_degrees(),
            tol.to_degrees()
        )
    })
}

/// Whether the measured stage travel |P2 − P1| agrees with the stage's own travel (the two
/// readings' difference) within the stage tolerance plus three standard deviations of the two
/// points; `Err` says by how much it does not (a slipped stage, a lock on a stray reflector).
fn check_travel(
    p1: &PointRecord,
    p2: &PointRecord,
    tol_mm: f64,
    gate_mm: f64,
) -> Result<(), String> {
    let sd = |p: &PointRecord| {
        if p.std_total_mm.is_finite() {
            p.std_total_mm
        } else {
            gate_mm
        }
    };
    let allowed = tol_mm + 3.0 * sd(p1).hypot(sd(p2));
    let d = [p2.x_mm - p1.x_mm, p2.y_mm - p1.y_mm, p2.z_mm - p1.z_mm];
    let measured = d.iter().map(|v| v * v).sum::<f64>().sqrt();
    let expected = (p2.stage_mm - p1.stage_mm).abs();
    let off = (measured - expected).abs();
    if off.is_finite() && off <= allowed {
        Ok(())
    } else {
        Err(format!(
            "|P2 − P1| = {measured:.4} mm but the stage moved {expected:.4} mm (off by {off:.4} mm, allowed {allowed:.4} mm)"
        ))
    }
}

/// Await a device call unless the campaign is aborted or disarmed first; a campaign not armed
/// never starts it (no device call, power-on included, is made while disarmed).
/// Cancel-safe when `fut` is: on abort or disarm it drops `fut` (the device traits'
/// contract makes that safe) and returns `Stop::Aborted` or `Stop::Disarmed`.
async fn guarded<T>(
    control: &Control,
    fut: impl Future<Output = Result<T, CellError>>,
) -> Result<Result<T, CellError>, Stop> {
    let mut armed = control.armed.subscribe();
    if control.abort.is_cancelled() {
        return Err(Stop::Aborted);
    }
    if !*armed.borrow_and_update() {
        return Err(Stop::Disarmed);
    }
    tokio::select! {
        biased;
        _ = control.abort.cancelled() => Err(Stop::Aborted),
        _ = armed.wait_for(|a| !*a) => Err(Stop::Disarmed),
        r = fut => Ok(r),
    }
}

/// The longest wait for one device's answer to a stop.
const STOP_BOUND: Duration = Duration::from_secs(2);

/// Why a campaign paused on a disarm (and stays paused while disarmed).
const DISARMED: &str = "disarmed: the robot and the stage were stopped; arm, then resume";

/// Run `f` on the store on a blocking thread (the store's mutex is held only there).
/// Cancel-safe in effect: a dropped call still runs `f` to completion; only its result is lost.
async fn with_store<T: Send + 'static>(
    store: &StoreHandle,
    f: impl FnOnce(&mut Store) -> Result<T, StoreError> + Send + 'static,
) -> Result<T, CampaignError> {
    store.call(f).await.map_err(campaign_error)
}

/// A store error as the engine reports it (a failed blocking task as [`CampaignError::Task`]).
fn campaign_error(e: StoreError) -> CampaignError {
    match e {
        StoreError::Task(t) => CampaignError::Task(t),
        e => CampaignError::Store(e),
    }
}

/// Journal `event` for campaign `id` and publish it on `control` with the sequence number the
/// store assigned; both happen under the store lock ([`StoreHandle::journal`]), so live events
/// leave in journal order and every live event is in the journal before anyone sees it. Returns
/// the sequence number. Cancel-safe: the work runs on a blocking thread, so a dropped call
/// still journals and publishes the event exactly once.
pub async fn journal_event(
    store: &StoreHandle,
    id: i64,
    control: &Control,
    event: CampaignEvent,
) -> Result<i64, CampaignError> {
    let control = control.clone();
    store
        .journal(id, now_unix_ms(), event, move |e| control.publish(e))
        .await
        .map_err(campaign_error)
}

struct Run<'a> {
    ctx: &'a CampaignContext,
    dev: &'a mut Devices,
    /// The stage reading after its last successful move (mm); `None` once anything may have
    /// moved it (a fault, a pause, a new preparation).
    stage_mm: Option<f64>,
    /// Joints of the drift reference (the frame reference's, once known).
    drift_q: Vec<f64>,
    /// Routes of every move through the drift reference (its error refuses every move).
    router: Result<Router, RouteError>,
    /// Where the ball should be (once the base is registered).
    aim: Option<frame::Aim>,
    /// The predicted position of the point being measured: where a re-lock looks first.
    aim_at: Option<Vector3<f64>>,
    /// The controller reported the robot settled at its last target and no robot command was
    /// sent since (false whenever that is not known).
    robot_settled: bool,
    /// A technician may have a hand at the stage (a manual stage was asked to move) and has
    /// not yet confirmed the cell clear: no robot motion until [`Run::ensure_clear`].
    hand_at_stage: bool,
    /// What is being measured (the context of a technician question).
    step: Step,
}

/// What the engine is measuring, as a technician question's context names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// The setup step (tool frame, base registration).
    Setup,
    /// A drift check at the reference pose (the frame reference included).
    Drift,
    /// Re-measuring stored points to re-register the tracker frame.
    Reregister,
    /// The `n`-th pose measured (from 1).
    Pose(usize),
}

impl Step {
    /// The `step` name of a prompt context.
    fn name(self) -> &'static str {
        match self {
            Step::Setup => "setup",
            Step::Drift => "drift",
            Step::Reregister => "reregister",
            Step::Pose(_) => "pose",
        }
    }
}

/// The deviation of a measured P1 from where the nominal model (registered base, measured
/// tool) puts the ball: measured − predicted (mm, tracker frame).
fn deviation(aim: Option<&frame::Aim>, m: &PoseMeasurement) -> Option<Vector3<f64>> {
    let predicted = aim?.ball(&m.joints_rad, m.p1.stage_mm)?;
    Some(Vector3::new(m.p1.x_mm, m.p1.y_mm, m.p1.z_mm) - predicted)
}

/// Retry a step after the operator fixed a fault: `Stop::Fault` pauses (or fails, per the
/// policy) and runs the step again on resume; every other outcome passes through.
macro_rules! with_operator {
    ($run:expr, $step:expr) => {
        loop {
            match $step {
                Ok(v) => break v,
                Err(Stop::Fault(reason)) => $run.operator_pause(reason).await?,
                Err(Stop::Disarmed) => $run.disarmed_pause().await?,
                Err(e) => return Err(e),
            }
        }
    };
}

impl Run<'_> {
    /// [`with_store`] on the campaign's store. Cancel-safe in the same sense.
    async fn store<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Store) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, CampaignError> {
        with_store(&self.ctx.store, f).await
    }

    /// Journal an event in the store, then emit it with its sequence number. Cancel-safe as
    /// [`journal_event`].
    async fn journal(&self, e: CampaignEvent) -> Result<(), CampaignError> {
        journal_event(&self.ctx.store, self.ctx.campaign_id, &self.ctx.control, e)
            .await
            .map(|_| ())
    }

    /// Journal and emit a device fault and the action taken.
    /// Cancel-safe as [`journal_event`].
    async fn fault(
        &self,
        device: DeviceKind,
        kind: FaultKind,
        message: &str,
        action: &str,
    ) -> Result<(), CampaignError> {
        self.journal(CampaignEvent::fault(device, kind, message, action))
            .await
    }

    /// Store the new state, then journal and emit it. Not cancel-safe: a drop between the two
    /// leaves the stored state without its event; the run is ended by its abort token, never
    /// dropped.
    async fn set_state(&self, state: CampaignState) -> Result<(), CampaignError> {
        let id = self.ctx.campaign_id;
        let stored = state.stored();
        self.store(move |s| s.set_state(id, stored)).await?;
        self.journal(CampaignEvent::State { state }).await
    }

    /// Recover from a transient fault; returns the action taken.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn recover(&mut self, e: &CellError) -> Result<&'static str, Stop> {
        let action = match (e.device, e.kind) {
            (DeviceKind::Tracker, FaultKind::BeamBroken) => "relock",
            // the connection is intact: stop what may still move, then the caller retries
            (DeviceKind::Robot, FaultKind::Timeout) => "stop, retry",
            (_, FaultKind::Disconnected | FaultKind::Protocol | FaultKind::Timeout) => "reconnect",
            (_, FaultKind::NotReady) => "wait",
            _ => "pause",
        };
        if e.device == DeviceKind::Robot {
            self.robot_settled = false;
        }
        self.fault(e.device, e.kind, &e.message, action).await?;
        let abort = &self.ctx.control.abort;
        let r = match (action, e.device) {
            ("relock", _) => {
                let at = self.aim_at;
                abort.run_until_cancelled(self.dev.tracker.relock(at)).await
            }
            ("reconnect", DeviceKind::Tracker) => {
                abort
                    .run_until_cancelled(self.dev.tracker.reconnect())
                    .await
            }
            ("reconnect", DeviceKind::Robot) => {
                // never powers the arm on: after a reconnect somebody must look at the cell
                match abort.run_until_cancelled(self.dev.robot.reconnect()).await {
                    None => return Err(Stop::Aborted),
                    Some(_) => return Err(Stop::Fault(ROBOT_RECONNECTED.into())),
                }
            }
            ("stop, retry", _) => {
                let stop = self.dev.robot.stop();
                let _ = abort
                    .run_until_cancelled(tokio::time::timeout(Duration::from_secs(2), stop))
                    .await;
                Some(Ok(()))
            }
            ("wait", _) => {
                tokio::time::sleep(Duration::from_millis(200)).await;
                Some(Ok(()))
            }
            _ => return Err(Stop::Fault(e.to_string())),
        };
        match r {
            None => Err(Stop::Aborted),
            // a failed recovery counts as another attempt; the caller's loop decides
            Some(Err(re)) => {
                self.fault(re.device, re.kind, &re.message, "retry").await?;
                Ok(action)
            }
            Some(Ok(())) => Ok(action),
        }
    }

    /// One accepted tracker point (beam breaks and gate failures are measured again).
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn measure_point(
        &mut self,
        pose: Option<usize>,
        joints: &[f64],
        stage_mm: f64,
    ) -> Result<TrackerPoint, Stop> {
        let max = self.ctx.cfg.tracker.max_attempts;
        let gate = self.ctx.cfg.tracker.max_std_total_mm;
        let mut last = String::new();
        self.aim_at = self.aim.as_ref().and_then(|a| a.ball(joints, stage_mm));
        for _ in 0..max {
            let r = guarded(&self.ctx.control, self.dev.tracker.measure()).await?;
            match r {
                Ok(p) if p.std_total_mm.is_finite() && p.std_total_mm > gate => {
                    let note = format!(
                        "std_total {:.4} mm above the gate {gate} mm",
                        p.std_total_mm
                    );
                    last = note.clone();
                    self.fault(DeviceKind::Tracker, FaultKind::Device, &note, "retry")
                        .await?;
                    self.keep_point(PointKind::Discarded, pose, joints, &p, stage_mm, note)
                        .await?;
                }
                Ok(p) => return Ok(p),
                Err(e) if e.is_transient() => {
                    last = e.to_string();
                    self.recover(&e).await?;
                }
                Err(e) => {
                    self.fault(e.device, e.kind, &e.message, "pause").await?;
                    return Err(Stop::Fault(e.to_string()));
                }
            }
        }
        Err(Stop::Fault(format!(
            "tracker: no acceptable point after {max} attempts ({last})"
        )))
    }

    /// Store a tracker point outside a pose commit (drift, setup, discarded) with its note;
    /// returns its row id.
    /// Cancel-safe in effect, as [`with_store`]: a dropped call still stores the point.
    async fn keep_point(
        &self,
        kind: PointKind,
        pose: Option<usize>,
        joints: &[f64],
        p: &TrackerPoint,
        stage_mm: f64,
        note: String,
    ) -> Result<i64, CampaignError> {
        self.keep_record(kind, pose, joints, record(p, stage_mm), note)
            .await
    }

    /// [`Run::keep_point`] of an already recorded point.
    /// Cancel-safe in effect, as [`with_store`].
    async fn keep_record(
        &self,
        kind: PointKind,
        pose: Option<usize>,
        joints: &[f64],
        rec: PointRecord,
        note: String,
    ) -> Result<i64, CampaignError> {
        let id = self.ctx.campaign_id;
        let q = joints.to_vec();
        self.store(move |s| s.add_point(id, kind, pose, Some(&q), &rec, &note))
            .await
    }

    /// A pose whose |P2 − P1| agrees with the stage travel: a disagreeing pair is kept as
    /// `discarded` and the pose measured again, up to the tracker's `max_attempts`, then the
    /// operator is asked.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn measure_sane_pose(
        &mut self,
        entry: &PlanEntry,
        s1: f64,
        s2: f64,
    ) -> Result<PoseMeasurement, Stop> {
        let max = self.ctx.cfg.tracker.max_attempts;
        let tol = self.ctx.cfg.stage.tolerance_mm;
        let gate = self.ctx.cfg.tracker.max_std_total_mm;
        let mut last = String::new();
        for _ in 0..max {
            let m = self.measure_pose(entry, s1, s2).await?;
            let Some(p2) = m.p2 else { return Ok(m) };
            let Err(why) = check_travel(&m.p1, &p2, tol, gate) else {
                return Ok(m);
            };
            self.fault(DeviceKind::Stage, FaultKind::Device, &why, "measure again")
                .await?;
            for p in [m.p1, p2] {
                let note = format!("pose {}: {why}", entry.index);
                self.keep_record(
                    PointKind::Discarded,
                    Some(entry.index),
                    &m.joints_rad,
                    p,
                    note,
                )
                .await?;
            }
            self.stage_mm = None;
            last = why;
        }
        Err(Stop::Fault(format!(
            "pose {}: {last}, {max} times: check the stage and the ball",
            entry.index
        )))
    }

    /// Whether `q` passes the joint-limit and workspace checks (line of sight included).
    fn target_safe(&self, q: &[f64]) -> bool {
        self.ctx.nominal.within_limits(q) && target_ok(&self.ctx.nominal, q, &self.ctx.plan_request)
    }

    /// Move to a joint target after the safety checks, through the via points of its route
    /// from the robot's joints as read before each attempt (every leg passes the path check);
    /// returns the joints read after settling at the target. Every attempt re-checks that the
    /// campaign is armed; joints that settle farther than `settle_tolerance_deg` from the
    /// target count as a failed attempt. Not cancel-safe: abort stops the robot.
    async fn move_to(&mut self, q: &[f64]) -> Result<Vec<f64>, Stop> {
        self.move_via(q, None).await
    }

    /// [`Run::move_to`] with an `approach` pre-pose (ISO 9283 unidirectional approach): the
    /// route goes to the pre-pose, which passes the same target checks, and the last leg
    /// pre-pose → target must pass the path check directly. Not cancel-safe (as `move_to`).
    async fn move_via(&mut self, q: &[f64], approach: Option<&[f64]>) -> Result<Vec<f64>, Stop> {
        for t in approach.into_iter().chain(std::iter::once(q)) {
            if !self.target_safe(t) {
                return Err(Stop::Failed(format!(
                    "target {t:?} fails the joint-limit/workspace check: not sent"
                )));
            }
        }
        let max = self.ctx.cfg.robot_controller.max_attempts;
        let timeout = Duration::from_millis(self.ctx.cfg.robot_controller.settle_timeout_ms);
        let tol = self.settle_tolerance();
        let mut last = String::new();
        self.ensure_clear().await?;
        self.robot_settled = false;
        for _ in 0..max {
            if !self.ctx.control.is_armed() {
                return Err(Stop::Disarmed);
            }
            let router = self
                .router
                .as_mut()
                .map_err(|e| Stop::Failed(format!("no move is routed: {e}")))?;
            let r = {
                let robot = &mut self.dev.robot;
                let control = &self.ctx.control;
                guarded(control, async {
                    let from = robot.joints().await?;
                    let vias = match approached_route(router, &from, approach, q) {
                        Ok(vias) => vias,
                        Err(e) => {
                            return Ok(Err(Stop::Failed(format!(
                                "no safe path to {q:?}: {e}: not sent"
                            ))))
                        }
                    };
                    // every leg is checked: a disarm between legs sends no further MOVEJ
                    for via in &vias {
                        if !control.is_armed() {
                            return Ok(Err(Stop::Disarmed));
                        }
                        robot.move_joints(via).await?;
                        robot.wait_settled(timeout).await?;
                    }
                    if !control.is_armed() {
                        return Ok(Err(Stop::Disarmed));
                    }
                    robot.move_joints(q).await?;
                    robot.wait_settled(timeout).await.map(Ok)
                })
                .await?
            };
            match r {
                Ok(Ok(joints)) => match settle_error(q, &joints, tol) {
                    None => {
                        self.robot_settled = true;
                        return Ok(joints);
                    }
                    Some(why) => {
                        self.fault(DeviceKind::Robot, FaultKind::Device, &why, "repeat move")
                            .await?;
                        last = why;
                    }
                },
                Ok(Err(stop)) => return Err(stop),
                Err(e) if e.is_transient() => {
                    last = e.to_string();
                    self.recover(&e).await?;
                }
                Err(e) => {
                    self.fault(e.device, e.kind, &e.message, "pause").await?;
                    let _ =
                        tokio::time::timeout(Duration::from_secs(2), self.dev.robot.stop()).await;
                    return Err(Stop::Fault(e.to_string()));
                }
            }
        }
        Err(Stop::Fault(format!(
            "robot: move failed after {max} attempts ({last})"
        )))
    }

    /// Put the stage at `mm` (skipped when its last move already put it there, so a technician
    /// is not asked twice); returns the reading.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn stage_to(&mut self, mm: f64) -> Result<f64, Stop> {
        let tol = self.ctx.cfg.stage.tolerance_mm;
        if let Some(at) = self.stage_mm.filter(|at| (at - mm).abs() <= tol) {
            return Ok(at);
        }
        self.stage_mm = None;
        let context = self.prompt_context(mm);
        // from the question on, a hand may be at the stage until the cell is confirmed clear
        self.hand_at_stage |= self.dev.stage.needs_clear();
        let r = {
            let stage = &mut self.dev.stage;
            stage.set_prompt_context(context);
            guarded(&self.ctx.control, stage.move_to(mm)).await?
        };
        match r {
            Ok(v) => {
                self.stage_mm = Some(v);
                Ok(v)
            }
            Err(e) => Err(self.stage_failed(e).await?),
        }
    }

    /// Journal a stage (or technician) failure and say how the run stops: the technician's
    /// abort aborts, anything else pauses. Cancel-safe as [`journal_event`].
    async fn stage_failed(&self, e: CellError) -> Result<Stop, CampaignError> {
        let aborted = e.kind == FaultKind::Aborted;
        let action = if aborted { "abort" } else { "pause" };
        self.fault(e.device, e.kind, &e.message, action).await?;
        Ok(if aborted {
            Stop::Aborted
        } else {
            Stop::Fault(e.to_string())
        })
    }

    /// Before robot motion: when a technician may have a hand at the stage, ask them to
    /// confirm the cell clear (the robot stands still meanwhile) and move nothing until they
    /// do. Not cancel-safe: one step of the run, ended by the abort token (the question is
    /// [`guarded`]), never by dropping it.
    async fn ensure_clear(&mut self) -> Result<(), Stop> {
        if !self.hand_at_stage {
            return Ok(());
        }
        let context = self.prompt_context(self.stage_mm.unwrap_or(f64::NAN));
        let r = guarded(&self.ctx.control, self.dev.stage.confirm_clear(context)).await?;
        match r {
            Ok(()) => {
                self.hand_at_stage = false;
                Ok(())
            }
            Err(e) => Err(self.stage_failed(e).await?),
        }
    }

    /// The context of a question asked while the stage goes to `mm`: the step, the pose,
    /// P1 or P2, and whether the robot is known to stand still.
    fn prompt_context(&self, mm: f64) -> PromptContext {
        let stage = &self.ctx.cfg.stage;
        let s1 = stage.p1_mm;
        let at = |x: f64| (mm - x).abs() <= stage.tolerance_mm;
        let position = if at(s1) {
            Some(StagePosition::P1)
        } else if at(s1 + stage.travel_mm) {
            Some(StagePosition::P2)
        } else {
            None
        };
        let pose = match self.step {
            Step::Pose(n) => Some(n),
            _ => None,
        };
        PromptContext {
            step: Some(self.step.name().to_owned()),
            pose,
            poses_total: pose.map(|_| self.ctx.plan.poses.len()),
            position,
            robot_stopped: self.robot_settled,
            retry_reason: None,
        }
    }

    /// Measure the drift reference at `q` (stage at P1); returns the point and its row id.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn drift_point(&mut self, q: &[f64]) -> Result<(Vector3<f64>, i64), Stop> {
        self.step = Step::Drift;
        let joints = self.move_to(q).await?;
        let s1 = self.ctx.cfg.stage.p1_mm;
        let s = self.stage_to(s1).await?;
        let p = self.measure_point(None, &joints, s).await?;
        let row = self
            .keep_point(
                PointKind::Drift,
                None,
                &joints,
                &p,
                s,
                "drift reference".into(),
            )
            .await?;
        Ok((p.p_mm, row))
    }

    /// Wait for Start while armed. A Start that arrives while disarmed is forgotten (it must
    /// not turn a later Arm into motion).
    /// The stored state follows Arm and Disarm meanwhile (`armed` / `idle`).
    /// Not cancel-safe: a drop between a stored `armed`/`idle` and its event leaves the event
    /// unsent; it returns `Stop::Aborted` on the abort token instead.
    async fn wait_start(&self, mut armed: bool) -> Result<(), Stop> {
        let mut start = self.ctx.control.start.subscribe();
        loop {
            let now_armed = self.ctx.control.is_armed();
            if now_armed != armed {
                armed = now_armed;
                self.set_state(if armed {
                    CampaignState::Armed
                } else {
                    CampaignState::Idle
                })
                .await?;
            }
            if *start.borrow_and_update() {
                if armed {
                    return Ok(());
                }
                self.ctx.control.start.send_replace(false);
            }
            tokio::select! {
                _ = start.changed() => {}
                _ = tokio::time::sleep(Duration::from_millis(50)) => {}
                _ = self.ctx.control.abort.cancelled() => return Err(Stop::Aborted),
            }
        }
    }

    /// Stay paused with `reason` until the operator resumes (or aborts); a resume while
    /// disarmed is refused (the campaign stays paused, nothing is prepared or powered on).
    /// Not cancel-safe: a drop while waiting leaves the stored state `paused`; it returns
    /// `Stop::Aborted` on the abort token instead.
    async fn paused(&self, reason: String) -> Result<(), Stop> {
        let mut pause = self.ctx.control.pause.subscribe();
        // a re-registration belongs to the resume it comes with, not to one before this pause
        self.ctx.control.take_reregister();
        self.set_state(CampaignState::Paused { reason }).await?;
        loop {
            while *pause.borrow_and_update() {
                tokio::select! {
                    r = pause.changed() => if r.is_err() { return Err(Stop::Aborted) },
                    _ = self.ctx.control.abort.cancelled() => return Err(Stop::Aborted),
                }
            }
            if self.ctx.control.is_armed() {
                break;
            }
            self.ctx.control.pause.send_replace(true);
            self.set_state(CampaignState::Paused {
                reason: "not armed: arm, then resume".into(),
            })
            .await?;
        }
        self.set_state(CampaignState::Running).await?;
        Ok(())
    }

    /// Return at once unless the operator paused; then [`Run::paused`] (not cancel-safe, as it).
    async fn wait_unpaused(&self) -> Result<(), Stop> {
        if !*self.ctx.control.pause.borrow() {
            return Ok(());
        }
        self.paused("paused by the operator".into()).await
    }

    /// An operator fault: pause with the reason (or fail, per the policy); on resume the
    /// devices are prepared again (a failure there pauses again).
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn operator_pause(&mut self, reason: String) -> Result<(), Stop> {
        if self.ctx.on_fault == FaultPolicy::Fail {
            return Err(Stop::Fault(reason));
        }
        self.halt("fault").await?;
        self.pause_until_prepared(reason).await
    }

    /// A disarm: every device stopped at once, then paused (whatever the policy) until the
    /// operator arms and resumes; the devices are prepared again before the step is retried.
    /// Not cancel-safe: one step of the run, ended by the abort token, never by dropping it.
    async fn disarmed_pause(&mut self) -> Result<(), Stop> {
        self.halt("disarm").await?;
        self.pause_until_prepared(DISARMED.into()).await
    }

    /// Pause with `reason`; on resume (armed) prepare the devices, pausing again while that
    /// fails or the campaign is disarmed again. Not cancel-safe (as [`Run::paused`]).
    async fn pause_until_prepared(&mut self, mut reason: String) -> Result<(), Stop> {
        loop {
            self.ctx.control.pause.send_replace(true);
            self.paused(reason).await?;
            match self.prepare().await {
                Ok(()) => return Ok(()),
                Err(Stop::Fault(r)) => reason = r,
                Err(Stop::Disarmed) => {
                    self.halt("disarm").await?;
                    reason = DISARMED.into();
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Prepare robot, tracker and stage (in that order) and journal what each says it is; a
    /// device that cannot be prepared is an operator fault. Not cancel-safe: a drop may leave a
    /// device half-prepared (the next preparation starts it again); the abort token ends it.
    async fn prepare(&mut self) -> Result<(), Stop> {
        self.stage_mm = None;
        self.robot_settled = false;
        let speed = self.ctx.cfg.robot_controller.speed_pct;
        for device in [DeviceKind::Robot, DeviceKind::Tracker, DeviceKind::Stage] {
            let r = match device {
                DeviceKind::Robot => {
                    let r = &mut self.dev.robot;
                    guarded(&self.ctx.control, r.prepare(speed)).await?
                }
                DeviceKind::Tracker => {
                    let t = &mut self.dev.tracker;
                    guarded(&self.ctx.control, t.prepare()).await?
                }
                _ => {
                    let s = &mut self.dev.stage;
                    guarded(&self.ctx.control, s.prepare()).await?
                }
            };
            if let Err(e) = r {
                self.fault(e.device, e.kind, &e.message, "pause").await?;
                return Err(Stop::Fault(format!(
                    "{} could not be prepared: {e}",
                    device.name()
                )));
            }
        }
        self.journal(CampaignEvent::Devices {
            tracker: self.dev.tracker.identity(),
            robot: self.dev.robot.identity(),
            stage: self.dev.stage.identity(),
        })
        .await?;
        Ok(())
    }

    /// Move, then both readings of one planned pose, starting where the stage stands: P1 then
    /// P2, or P2 then P1 when the stage is known to be at P2 (the last pose ended there), so a
    /// pose moves the stage once (a technician sets it once) and the next pose starts where
    /// this one ended. The records keep their meaning (`p1` is the reading at P1, the position
    /// point). A reading taken before a later step fails is kept as `discarded`.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn measure_pose(
        &mut self,
        entry: &PlanEntry,
        s1: f64,
        s2: f64,
    ) -> Result<PoseMeasurement, Stop> {
        let approach = self.ctx.plan.approach.get(&entry.index).cloned();
        let joints = self.move_via(&entry.q_rad, approach.as_deref()).await?;
        if !self.ctx.cfg.axis_readings().at(entry.set) {
            let a1 = self.stage_to(s1).await?;
            let p1 = self.measure_point(Some(entry.index), &joints, a1).await?;
            return Ok(PoseMeasurement {
                index: entry.index,
                joints_rad: joints,
                p1: record(&p1, a1),
                p2: None,
            });
        }
        let tol = self.ctx.cfg.stage.tolerance_mm;
        let p2_first = self.stage_mm.is_some_and(|at| (at - s2).abs() <= tol);
        let (first_mm, second_mm) = if p2_first { (s2, s1) } else { (s1, s2) };
        let a = self.stage_to(first_mm).await?;
        let first = self.measure_point(Some(entry.index), &joints, a).await?;
        let second = async {
            let b = self.stage_to(second_mm).await?;
            let p = self.measure_point(Some(entry.index), &joints, b).await?;
            Ok::<_, Stop>((b, p))
        }
        .await;
        match second {
            Ok((b, p)) => {
                let (p1, p2) = if p2_first {
                    (record(&p, b), record(&first, a))
                } else {
                    (record(&first, a), record(&p, b))
                };
                Ok(PoseMeasurement {
                    index: entry.index,
                    joints_rad: joints,
                    p1,
                    p2: Some(p2),
                })
            }
            Err(Stop::Store(e)) => Err(Stop::Store(e)),
            Err(e) => {
                if matches!(e, Stop::Aborted | Stop::Disarmed) {
                    // stop what moves before the store write below
                    self.stop_devices().await;
                }
                let why = match &e {
                    Stop::Aborted => "aborted".to_owned(),
                    Stop::Disarmed => "disarmed".to_owned(),
                    Stop::Failed(r) | Stop::Fault(r) => r.clone(),
                    Stop::Store(_) => String::new(),
                };
                let taken = if p2_first { "P2" } else { "P1" };
                let note = format!("{taken} of an unfinished pose ({why})");
                self.keep_point(
                    PointKind::Discarded,
                    Some(entry.index),
                    &joints,
                    &first,
                    a,
                    note,
                )
                .await?;
                Err(e)
            }
        }
    }

    /// Setup, the frame reference, every pose not yet done (drift checks between) and the final
    /// drift check. Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// [`guarded`]), never by dropping it.
    async fn measure_all(&mut self) -> Result<(), Stop> {
        let id = self.ctx.campaign_id;
        let done: Vec<usize> = self.store(move |s| s.done_poses(id)).await?;
        let total = self.ctx.plan.poses.len();
        let mut count = done.len();
        if count > 0 {
            self.journal(CampaignEvent::Note {
                text: format!("resuming: {count} of {total} poses already measured"),
            })
            .await?;
        }
        with_operator!(self, self.prepare().await);
        let setup = with_operator!(self, self.setup().await);
        let axis = identify_options(&self.ctx.cfg).obs.stage_axis;
        let p1 = self.ctx.cfg.stage.p1_mm;
        self.aim = frame::Aim::new(&self.ctx.nominal, &setup, axis, p1);
        let baseline = with_operator!(self, self.frame_reference(count).await);
        let every = self.ctx.cfg.campaign.drift_every;
        let s1 = self.ctx.cfg.stage.p1_mm;
        let s2 = s1 + self.ctx.cfg.stage.travel_mm;
        let mut since_drift = 0;
        let mut rule = self.stop_rule().await?;
        let is_ident = |i: usize| {
            self.ctx
                .plan
                .poses
                .iter()
                .any(|p| p.index == i && p.set == PoseSet::Ident)
        };
        let mut ident_done = done.iter().filter(|i| is_ident(**i)).count();
        if let Some(event) = rule.as_ref().and_then(|r| r.stopped_event()) {
            // a stop stored by a run that ended before it journalled it is journalled now
            let journalled: Vec<crate::store::JournalEntry<CampaignEvent>> =
                self.store(move |s| s.events(id)).await?;
            if journalled.iter().any(|e| e.event.kind() == event.kind()) {
                self.journal(CampaignEvent::Note {
                    text: "resuming: the identification poses stay stopped (stop rule); the \
                           skipped ones are not measured"
                        .into(),
                })
                .await?;
            } else {
                self.journal(event).await?;
            }
        }
        for entry in self.ctx.plan.poses.clone() {
            if done.contains(&entry.index) {
                continue;
            }
            self.wait_unpaused().await?;
            if let (Some(rule), PoseSet::Ident) = (rule.as_mut(), entry.set) {
                if with_operator!(self, self.ident_stopped(rule, ident_done).await) {
                    continue;
                }
            }
            self.step = Step::Pose(count + 1);
            let m = with_operator!(self, self.measure_sane_pose(&entry, s1, s2).await);
            let p1_mm = [m.p1.x_mm, m.p1.y_mm, m.p1.z_mm];
            let off = deviation(self.aim.as_ref(), &m);
            // durable before the robot moves again
            self.store(move |s| s.commit_pose(id, &m)).await?;
            count += 1;
            since_drift += 1;
            ident_done += usize::from(entry.set == PoseSet::Ident);
            self.journal(CampaignEvent::Measured {
                pose: entry.index,
                done: count,
                total,
                p1_mm,
                deviation_mm: off.map(|d| d.norm()),
                deviation_xyz_mm: off.map(|d| [d.x, d.y, d.z]),
            })
            .await?;
            if every > 0 && since_drift >= every && count < total {
                since_drift = 0;
                with_operator!(self, self.check_drift(&baseline).await);
            }
        }
        with_operator!(self, self.check_drift(&baseline).await);
        Ok(())
    }
}

impl Run<'_> {
    /// The stop rule of this campaign with its stored checks (`None` unless a calibration
    /// campaign with `stop_when = "predicted"`). Cancel-safe in effect, as [`with_store`].
    async fn stop_rule(&self) -> Result<Option<stop::StopRule>, CampaignError> {
        stored_stop_rule(self.ctx).await
    }
}

/// [`stop::StopRule::of`] the campaign with the checks its store holds. Cancel-safe in
/// effect, as [`with_store`].
async fn stored_stop_rule(ctx: &CampaignContext) -> Result<Option<stop::StopRule>, CampaignError> {
    let id = ctx.campaign_id;
    let checks: Vec<IdentCheck> = with_store(&ctx.store, move |s| s.ident_checks(id)).await?;
    Ok(stop::StopRule::of(
        &ctx.cfg,
        &ctx.nominal,
        &ctx.plan,
        ctx.iso.is_some(),
        checks,
    ))
}

/// Via points from `from` to `q`: the route's, or, with an `approach` pre-pose, the route to
/// the pre-pose and the pre-pose itself, whose direct move to `q` must pass the path check.
fn approached_route(
    router: &mut Router,
    from: &[f64],
    approach: Option<&[f64]>,
    q: &[f64],
) -> Result<Vec<Vec<f64>>, RouteError> {
    let Some(pre) = approach else {
        return router.route(from, q);
    };
    let mut vias = router.route(from, pre)?;
    router
        .checker()
        .check_move(pre, q)
        .map_err(|fault| RouteError::NoRoute {
            end: "target",
            fault,
        })?;
    if pre != from {
        vias.push(pre.to_vec());
    }
    Ok(vias)
}

/// Compute the ISO 9283 figures of the stored visits and store them as the campaign result.
/// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
/// `guarded`), never by dropping it.
pub async fn iso_stored(ctx: &CampaignContext) -> Result<IsoReport, CampaignError> {
    let id = ctx.campaign_id;
    let r = with_store(&ctx.store, move |s| {
        let r = super::iso::iso_report(s, id).map_err(|e| e.to_string());
        if let Ok(report) = &r {
            let json = serde_json::to_string_pretty(report)
                .map_err(|e| StoreError::Invalid(e.to_string()))?;
            s.save_result(id, crate::store::ISO9283_KIND, &json)?;
        }
        Ok(r)
    })
    .await?;
    r.map_err(CampaignError::Iso)
}

/// Identification options of a campaign.
pub fn identify_options(cfg: &CellConfig) -> IdentifyOptions {
    let mut obs = ObsConfig::new(cfg.model(), cfg.stage.travel_mm);
    if let Some(u) = cfg.stage.axis_vector() {
        obs.stage_axis = u;
    }
    IdentifyOptions {
        identify_base: cfg.campaign.identify_base,
        identify_tool: cfg.campaign.identify_tool,
        nongeometric: cfg.campaign.nongeometric_terms(),
        ..IdentifyOptions::new(obs)
    }
}

/// What a campaign identifies with: the nominal model (configured tool) with the setup
/// applied (measured tool and stage axis; the registered base when the base is not
/// identified), the identification options and the stage travel (mm). The one recipe of the
/// campaign and of `cellcal identify --store`.
pub fn campaign_identification(
    cfg: &CellConfig,
    nominal: &RobotModel,
    setup: Option<&SetupResult>,
) -> (RobotModel, IdentifyOptions, f64) {
    let mut opts = identify_options(cfg);
    let mut nominal = nominal.clone();
    if let Some(setup) = setup {
        setup.apply_to_identification(&mut nominal, &mut opts);
    }
    (nominal, opts, cfg.stage.travel_mm)
}

/// What a campaign identifies from: the stored rows (every measured pose), the recipe of
/// [`campaign_identification`] with the stored setup, and the base's source.
struct IdentificationInput {
    nominal: RobotModel,
    rows: Vec<Observation>,
    opts: IdentifyOptions,
    travel: f64,
    base: BaseSource,
}

/// The campaign's identification input as stored now: the one recipe of the final
/// identification and of the stop rule's checks. Cancel-safe in effect, as [`with_store`].
async fn identification_input(ctx: &CampaignContext) -> Result<IdentificationInput, CampaignError> {
    let id = ctx.campaign_id;
    let rows = identification_rows(with_store(&ctx.store, move |s| s.measured(id)).await?);
    let setup = with_store(&ctx.store, move |s| SetupResult::load(s, id)).await?;
    let (nominal, opts, travel) = campaign_identification(&ctx.cfg, &ctx.nominal, setup.as_ref());
    let base = BaseSource::of(
        opts.identify_base,
        setup.as_ref().is_some_and(|s| s.base.is_some()),
    );
    Ok(IdentificationInput {
        nominal,
        rows,
        opts,
        travel,
        base,
    })
}

/// Identify from the stored measurements and store the typed result
/// ([`crate::calibrate::CalibrationResult`]: the contract, per-pose residuals, corrected model)
/// once; returns its contract. With `stop_when = "predicted"` the result's `ident_stop` says
/// how the identification poses ended. Not cancel-safe: one step of the run, ended by the
/// abort token (every device wait is `guarded`), never by dropping it.
pub async fn identify_stored(ctx: &CampaignContext) -> Result<IdentifyReport, CampaignError> {
    let id = ctx.campaign_id;
    let input = identification_input(ctx).await?;
    let ident_measured = input
        .rows
        .iter()
        .filter(|o| o.set == PoseSet::Ident)
        .count();
    let ident_stop = stored_stop_rule(ctx)
        .await?
        .map(|r| r.summary(ident_measured));
    let IdentificationInput {
        nominal,
        rows,
        opts,
        travel,
        base,
    } = input;
    let (mut result, _) =
        tokio::task::spawn_blocking(move || calibrate_result(&nominal, &rows, &opts, travel, base))
            .await
            .map_err(|e| CampaignError::Task(e.to_string()))??;
    result.report.ident_stop = ident_stop;
    // planned against actual, from the journal (the last span closed when identifying began)
    let time = with_store(&ctx.store, move |s| super::time::campaign_time(s, id)).await?;
    result.campaign_time = time;
    let model = result.report.model.clone();
    let report = result.report.clone();
    with_store(&ctx.store, move |s| s.save_result_as(id, &model, &result)).await?;
    Ok(report)
}

/// Run (or resume) a campaign until it is done, aborted or stopped by a fault.
///
/// Whatever ends the run, the stored state is a final one (`done`, `aborted` or `failed` with
/// the reason, journalled and emitted) when this returns: an error after the start
/// (identification refused, a store or task failure) becomes `failed` with the error as the
/// reason and `Ok(Outcome::Failed)`. The one exception is a store that cannot write that
/// state: then the original error is returned and the stored state may still be the last one
/// written (e.g. `running`). Not cancel-safe: dropping it mid-run skips the final state and
/// the robot stop; end a run with `Abort` instead.
pub async fn run_campaign(
    ctx: &CampaignContext,
    devices: &mut Devices,
) -> Result<Outcome, CampaignError> {
    // the ball may be at P1 or at P2 while the robot moves: every leg is checked with both
    let router = campaign_router(&ctx.nominal, &ctx.plan_request, &ctx.plan.drift_reference);
    let mut run = Run {
        ctx,
        dev: devices,
        stage_mm: None,
        drift_q: ctx.plan.drift_reference.clone(),
        router,
        aim: None,
        aim_at: None,
        robot_settled: false,
        hand_at_stage: false,
        step: Step::Setup,
    };
    match run.run_to_end().await {
        Ok(outcome) => Ok(outcome),
        Err(e) => run.fail_on_error(e).await,
    }
}

impl Run<'_> {
    /// The whole run; an `Err` leaves the stored state to [`Run::fail_on_error`]. Not
    /// cancel-safe (as [`run_campaign`]).
    async fn run_to_end(&mut self) -> Result<Outcome, CampaignError> {
        let ctx = self.ctx;
        let armed = ctx.control.is_armed();
        self.set_state(if armed {
            CampaignState::Armed
        } else {
            CampaignState::Idle
        })
        .await?;
        let result = match self.wait_start(armed).await {
            Ok(()) => {
                self.set_state(CampaignState::Running).await?;
                self.measure_all().await
            }
            Err(e) => Err(e),
        };
        match result {
            Ok(()) => {
                self.set_state(CampaignState::Identifying).await?;
                let (json, outcome) = if ctx.iso.is_some() {
                    let report = iso_stored(ctx).await?;
                    (
                        serde_json::to_value(&report),
                        Outcome::Iso(Box::new(report)),
                    )
                } else {
                    let report = identify_stored(ctx).await?;
                    (
                        serde_json::to_value(&report),
                        Outcome::Done(Box::new(report)),
                    )
                };
                self.journal(CampaignEvent::Result {
                    json: json.unwrap_or(serde_json::Value::Null),
                })
                .await?;
                self.set_state(CampaignState::Done).await?;
                Ok(outcome)
            }
            Err(Stop::Aborted) => {
                self.halt("abort").await?;
                self.set_state(CampaignState::Aborted).await?;
                Ok(Outcome::Aborted)
            }
            Err(Stop::Disarmed) => {
                // every disarm inside a step pauses; one outside a step ends the run resumable
                self.halt("disarm").await?;
                let reason = DISARMED.to_owned();
                self.set_state(CampaignState::Failed {
                    reason: reason.clone(),
                })
                .await?;
                Ok(Outcome::Failed(reason))
            }
            Err(Stop::Failed(reason) | Stop::Fault(reason)) => {
                self.halt("fault").await?;
                self.set_state(CampaignState::Failed {
                    reason: reason.clone(),
                })
                .await?;
                Ok(Outcome::Failed(reason))
            }
            Err(Stop::Store(e)) => Err(e),
        }
    }

    /// Tell the robot and the stage to stop, both at once (each bounded by [`STOP_BOUND`]; the
    /// outcome does not depend on them); returns what each answered (`stopped`, `manual`, or
    /// why not). Cancel-safe: a dropped stop only means a device was not told again.
    async fn stop_devices(&mut self) -> (String, String) {
        self.robot_settled = false;
        self.stage_mm = None;
        let manual = self.dev.stage.is_manual();
        let dev = &mut *self.dev;
        let (robot, stage) = tokio::join!(
            tokio::time::timeout(STOP_BOUND, dev.robot.stop()),
            tokio::time::timeout(STOP_BOUND, dev.stage.stop()),
        );
        let said = |r: Result<Result<(), CellError>, _>| match r {
            Ok(Ok(())) => "stopped".to_owned(),
            Ok(Err(e)) => e.message,
            Err(_) => format!("no answer within {} ms", STOP_BOUND.as_millis()),
        };
        let stage = match (manual, stage) {
            (true, Ok(Ok(()))) => "manual".to_owned(),
            (_, r) => said(r),
        };
        (said(robot), stage)
    }

    /// [`Run::stop_devices`], then journal what each device answered (a `stopped` event with
    /// `why`). Not cancel-safe: a drop after the stops leaves the event unwritten.
    async fn halt(&mut self, why: &str) -> Result<(), CampaignError> {
        let (robot, stage) = self.stop_devices().await;
        self.journal(CampaignEvent::Stopped {
            reason: why.to_owned(),
            robot,
            stage,
        })
        .await
    }

    /// End a run that failed with `e`: stop the robot and store `failed` with the reason.
    /// Returns `Outcome::Failed`, or `e` itself when even that state cannot be written.
    /// Not cancel-safe: dropped before the state is written, the run keeps its last state.
    async fn fail_on_error(&mut self, e: CampaignError) -> Result<Outcome, CampaignError> {
        self.stop_devices().await;
        let reason = e.to_string();
        let failed = CampaignState::Failed {
            reason: reason.clone(),
        };
        match self.set_state(failed).await {
            Ok(()) => Ok(Outcome::Failed(reason)),
            Err(_) => Err(e),
        }
    }
}
