//! In-memory fake devices for the engine's own tests: a [`Tracker`], [`Robot`] and [`Stage`]
//! over one simulated [`World`] (the true robot, the stage and the tracker noise of
//! [`super::world`]; no second kinematics), called in-process — no TCP, no pty — with a
//! *fault script*: rules such as "the 3rd measure finds the beam broken", "the wait after the
//! MOVEJ to this pose times out", "the stage move fails once", "the tracker frame jumps 0.5 mm
//! at the 8th move". Every call is logged ([`Call`]) so that a test can assert what the engine
//! commanded, in which order.
//!
//! Motion is instant (the world's joint speed is effectively infinite, no settle time), so a
//! whole campaign runs in milliseconds; faults are deterministic (counted calls, never timers).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

use async_trait::async_trait;
use emscon::BackendMeasurement;
use nalgebra::Vector3;
use robotlink::{BackendError, ErrorCode};

use super::world::{lock_world, SharedWorld, StageSource, World};
use super::{true_model, SimWorldConfig};
use crate::cell::TrackerPoint;
use crate::cell::{CellError, DeviceKind, FaultKind, PromptContext, Robot, Stage, Tracker};
use crate::model::RobotModel;

/// A device call a script rule can match.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Op {
    /// `Tracker::prepare`.
    TrackerPrepare,
    /// `Tracker::measure`.
    Measure,
    /// `Tracker::relock`.
    Relock,
    /// `Tracker::reconnect`.
    TrackerReconnect,
    /// `Robot::prepare`.
    RobotPrepare,
    /// `Robot::move_joints` (a MOVEJ).
    MoveJ,
    /// `Robot::wait_settled` (the WAIT after a MOVEJ).
    WaitSettled,
    /// `Robot::reconnect`.
    RobotReconnect,
    /// `Stage::prepare`.
    StagePrepare,
    /// `Stage::move_to`.
    StageMove,
    /// `Stage::confirm_clear`.
    ConfirmClear,
}

/// What the engine called, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum Call {
    /// `Tracker::prepare`.
    TrackerPrepare,
    /// `Tracker::measure` and the point it returned (`None`: it failed).
    Measure(Option<Vector3<f64>>),
    /// `Tracker::relock` with the position it was told to look at first.
    Relock(Option<Vector3<f64>>),
    /// `Tracker::reconnect`.
    TrackerReconnect,
    /// `Robot::prepare` (switches arm power on) at this speed (%).
    RobotPrepare(f64),
    /// `Robot::move_joints` to this target (rad); `probe` is what the test's probe said when
    /// the MOVEJ was sent (e.g. the number of poses committed in the store).
    MoveJ {
        /// The target (rad).
        q: Vec<f64>,
        /// The probe's value at the call (0 without a probe).
        probe: usize,
    },
    /// `Robot::wait_settled`.
    WaitSettled,
    /// `Robot::stop`.
    RobotStop,
    /// `Robot::reconnect`.
    RobotReconnect,
    /// `Stage::prepare`.
    StagePrepare,
    /// `Stage::move_to` this position (mm).
    StageMove(f64),
    /// `Stage::stop`.
    StageStop,
    /// `Stage::confirm_clear` (a manual stage's question).
    ConfirmClear,
}

/// What a matching call does instead of (or before) its normal work.
#[derive(Clone)]
pub enum Fault {
    /// Fail with this kind (the device the call belongs to).
    Fail(FaultKind),
    /// `Measure`: return a point with this total standard deviation (mm) (the quality gate).
    Noisy(f64),
    /// `WaitSettled`: report joint `joint` (0-based) `rad` away from where the arm is.
    SettleOff {
        /// Joint (0-based).
        joint: usize,
        /// Offset (rad).
        rad: f64,
    },
    /// Before the call: the robot base moves by this much in the tracker frame (a bumped
    /// tracker); nothing reports it, only measurements show it.
    FrameJump(Vector3<f64>),
    /// `MoveJ`: an E-stop latches (arm power off) and the move is refused; `prepare` fails
    /// until the test releases it ([`FakeCell::release_estop`]).
    EStop,
    /// `StageMove`: the stage ends this far (mm) beyond where it reports (a slip its encoder
    /// does not see).
    Slip(f64),
    /// Before the call: run the closure (an operator's command, e.g. abort or disarm); the call
    /// then proceeds normally.
    Then(Action),
    /// Run the closure, then never answer (the engine must end the wait: abort, disarm).
    ThenHang(Action),
}

/// A closure a script runs at a call (the operator acting while a device works).
pub type Action = Arc<dyn Fn() + Send + Sync>;

impl std::fmt::Debug for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Fault::Fail(k) => write!(f, "Fail({k:?})"),
            Fault::Noisy(s) => write!(f, "Noisy({s})"),
            Fault::SettleOff { joint, rad } => write!(f, "SettleOff({joint}, {rad})"),
            Fault::FrameJump(v) => write!(f, "FrameJump({v:?})"),
            Fault::EStop => write!(f, "EStop"),
            Fault::Slip(mm) => write!(f, "Slip({mm})"),
            Fault::Then(_) => write!(f, "Then(..)"),
            Fault::ThenHang(_) => write!(f, "ThenHang(..)"),
        }
    }
}

/// Which calls of an [`Op`] a rule matches.
#[derive(Debug, Clone, PartialEq)]
enum When {
    /// Calls number `from ..from + times` of the op (1-based, counted over the whole run).
    Nth { from: u64, times: u64 },
    /// The first `times` calls whose robot target is `q` (MOVEJ to it, or the WAIT after it).
    Target { q: Vec<f64>, times: u64 },
}

#[derive(Debug, Clone)]
struct Rule {
    op: Op,
    when: When,
    fault: Fault,
    /// Calls this rule matched so far (for `Target`).
    hits: u64,
}

/// A probe the fake robot reads at every MOVEJ (e.g. poses committed in the store).
pub type Probe = Arc<dyn Fn() -> usize + Send + Sync>;

#[derive(Default)]
struct Script {
    rules: Vec<Rule>,
    counts: HashMap<Op, u64>,
    log: Vec<Call>,
    probe: Option<Probe>,
    /// The tracker holds its target (false after a beam break until a relock).
    unlocked: bool,
    speed_pct: f64,
    /// The last MOVEJ's target.
    target: Vec<f64>,
}

/// The fake cell: one world, one script, three devices ([`FakeCell::tracker`],
/// [`FakeCell::robot`], [`FakeCell::stage`]) sharing them.
#[derive(Clone)]
pub struct FakeCell {
    world: SharedWorld,
    script: Arc<Mutex<Script>>,
}

/// Why a call ends: its fault, if a rule matched.
enum Fired {
    Fail(FaultKind),
    Noisy(f64),
    SettleOff(usize, f64),
    Hang,
}

impl FakeCell {
    /// A fake cell over `world`.
    pub fn new(world: World) -> FakeCell {
        FakeCell {
            world: Arc::new(Mutex::new(world)),
            script: Arc::new(Mutex::new(Script::default())),
        }
    }

    /// A fake cell whose true robot, base, tool, stage axis and tracker noise are those of the
    /// `[sim]` table `sim` (defaults where absent), with instant motion and a motorised stage
    /// at 0 mm. `nominal` is the robot the controller believes (its base and tool are ignored).
    pub fn from_sim(nominal: &RobotModel, sim: Option<&SimWorldConfig>) -> FakeCell {
        let mut cfg = sim.cloned().unwrap_or_default();
        cfg.move_speed_deg_s = Some(1e12);
        cfg.settle_ms = Some(0);
        let bare = nominal.bare();
        let truth = true_model(&bare, &cfg).expect("the true robot");
        let world = World::new(bare, truth, &cfg, StageSource::Manual { position_mm: 0.0 })
            .expect("the world");
        FakeCell::new(world)
    }

    fn script(&self) -> MutexGuard<'_, Script> {
        self.script.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The shared world (truth, power, E-stop, moves).
    pub fn world(&self) -> SharedWorld {
        Arc::clone(&self.world)
    }

    /// Calls `from ..from + times` of `op` (1-based) do `fault`.
    pub fn on(&self, op: Op, from: u64, times: u64, fault: Fault) -> &FakeCell {
        self.script().rules.push(Rule {
            op,
            when: When::Nth { from, times },
            fault,
            hits: 0,
        });
        self
    }

    /// The first `times` calls of `op` (MOVEJ or WAIT) whose robot target is `q` do `fault`.
    pub fn on_target(&self, op: Op, q: &[f64], times: u64, fault: Fault) -> &FakeCell {
        self.script().rules.push(Rule {
            op,
            when: When::Target {
                q: q.to_vec(),
                times,
            },
            fault,
            hits: 0,
        });
        self
    }

    /// Read `probe` at every MOVEJ and log its value with the call.
    pub fn probe_at_move(&self, probe: Probe) {
        self.script().probe = Some(probe);
    }

    /// Every call so far, in order.
    pub fn calls(&self) -> Vec<Call> {
        self.script().log.clone()
    }

    /// How many calls of `op` were made.
    pub fn count(&self, op: Op) -> u64 {
        self.script().counts.get(&op).copied().unwrap_or(0)
    }

    /// The operator releases the E-stop (power stays off until the next `prepare`).
    pub fn release_estop(&self) {
        lock_world(&self.world).set_estop(false);
    }

    /// The boxed tracker.
    pub fn tracker(&self) -> Box<dyn Tracker> {
        Box::new(FakeTracker(self.clone()))
    }

    /// The boxed robot.
    pub fn robot(&self) -> Box<dyn Robot> {
        Box::new(FakeRobot(self.clone()))
    }

    /// The boxed stage: motorised, or manual (asks the technician to confirm the cell clear
    /// before the robot moves again).
    pub fn stage(&self, manual: bool) -> Box<dyn Stage> {
        Box::new(FakeStage {
            cell: self.clone(),
            manual,
        })
    }

    /// Count the call, log it, apply the rules that match; returns what ends the call.
    fn call(&self, op: Op, entry: Call) -> Option<Fired> {
        let mut actions = Vec::new();
        let fired = {
            let mut s = self.script();
            let n = {
                let c = s.counts.entry(op).or_insert(0);
                *c += 1;
                *c
            };
            if let Call::MoveJ { q, .. } = &entry {
                s.target.clone_from(q);
            }
            s.log.push(entry);
            let target = s.target.clone();
            let mut fired = None;
            for rule in s.rules.iter_mut().filter(|r| r.op == op) {
                let hit = match &rule.when {
                    When::Nth { from, times } => n >= *from && n < from + times,
                    When::Target { q, times } => *q == target && rule.hits < *times,
                };
                if !hit {
                    continue;
                }
                rule.hits += 1;
                match &rule.fault {
                    Fault::Fail(k) => fired = Some(Fired::Fail(*k)),
                    Fault::Noisy(s) => fired = Some(Fired::Noisy(*s)),
                    Fault::SettleOff { joint, rad } => fired = Some(Fired::SettleOff(*joint, *rad)),
                    Fault::FrameJump(v) => lock_world(&self.world).bump_base(*v),
                    Fault::EStop => {
                        lock_world(&self.world).set_estop(true);
                        fired = Some(Fired::Fail(FaultKind::EmergencyStop));
                    }
                    Fault::Slip(mm) => {
                        let mut w = lock_world(&self.world);
                        w.faults.stage_slips += 1;
                        w.faults.stage_slip_mm = *mm;
                    }
                    Fault::Then(a) => actions.push(Arc::clone(a)),
                    Fault::ThenHang(a) => {
                        actions.push(Arc::clone(a));
                        fired = Some(Fired::Hang);
                    }
                }
            }
            fired
        };
        for a in actions {
            a();
        }
        fired
    }

    fn log(&self, entry: Call) {
        self.script().log.push(entry);
    }
}

fn error(device: DeviceKind, kind: FaultKind) -> CellError {
    CellError::new(
        device,
        kind,
        format!("fake {} fault {kind:?}", device.name()),
    )
}

/// A scripted failure, or a wait that never ends (dropped by the engine's abort or disarm).
/// Cancel-safe: it holds nothing.
async fn fail<T>(device: DeviceKind, fired: Fired) -> Result<T, CellError> {
    match fired {
        Fired::Hang => std::future::pending().await,
        Fired::Fail(k) => Err(error(device, k)),
        Fired::Noisy(_) | Fired::SettleOff(..) => Err(error(device, FaultKind::Device)),
    }
}

/// The robot error a world refusal stands for (as the robotlink adapter classifies it).
fn robot_error(e: BackendError) -> CellError {
    let kind = match e.code {
        ErrorCode::EStop | ErrorCode::Power => FaultKind::EmergencyStop,
        ErrorCode::Busy => FaultKind::NotReady,
        _ => FaultKind::Rejected,
    };
    CellError::new(DeviceKind::Robot, kind, e.text)
}

struct FakeTracker(FakeCell);

#[async_trait]
impl Tracker for FakeTracker {
    /// Cancel-safe: no await before it returns.
    async fn prepare(&mut self) -> Result<(), CellError> {
        if let Some(f) = self.0.call(Op::TrackerPrepare, Call::TrackerPrepare) {
            return fail(DeviceKind::Tracker, f).await;
        }
        Ok(())
    }

    /// The world's true ball + noise; a beam break (scripted, or the world losing the target)
    /// leaves the tracker unlocked until a relock or reconnect. Cancel-safe: no await before it
    /// returns, except a scripted hang.
    async fn measure(&mut self) -> Result<TrackerPoint, CellError> {
        let fired = self.0.call(Op::Measure, Call::Measure(None));
        let gate = match fired {
            Some(Fired::Noisy(s)) => Some(s),
            Some(Fired::Fail(FaultKind::BeamBroken)) => {
                self.0.script().unlocked = true;
                return fail(DeviceKind::Tracker, Fired::Fail(FaultKind::BeamBroken)).await;
            }
            Some(f) => return fail(DeviceKind::Tracker, f).await,
            None => None,
        };
        if self.0.script().unlocked {
            return Err(error(DeviceKind::Tracker, FaultKind::BeamBroken));
        }
        let m = lock_world(&self.0.world).measure();
        let BackendMeasurement::Point(p) = m else {
            self.0.script().unlocked = true;
            return Err(error(DeviceKind::Tracker, FaultKind::BeamBroken));
        };
        if let Some(Call::Measure(logged)) = self.0.script().log.last_mut() {
            *logged = Some(Vector3::from(p.xyz_mm));
        }
        let now = SystemTime::now();
        Ok(TrackerPoint {
            p_mm: Vector3::from(p.xyz_mm),
            std_mm: p.std_mm,
            std_total_mm: gate.unwrap_or(p.std_total_mm),
            temperature_c: 20.0,
            pressure_mbar: 1013.25,
            humidity_pct: 50.0,
            sent_at: now,
            received_at: now,
        })
    }

    /// Cancel-safe: no await before it returns.
    async fn relock(&mut self, predicted_mm: Option<Vector3<f64>>) -> Result<(), CellError> {
        if let Some(f) = self.0.call(Op::Relock, Call::Relock(predicted_mm)) {
            return fail(DeviceKind::Tracker, f).await;
        }
        self.0.script().unlocked = false;
        Ok(())
    }

    /// Cancel-safe: no await before it returns.
    async fn reconnect(&mut self) -> Result<(), CellError> {
        if let Some(f) = self.0.call(Op::TrackerReconnect, Call::TrackerReconnect) {
            return fail(DeviceKind::Tracker, f).await;
        }
        self.0.script().unlocked = false;
        Ok(())
    }

    fn identity(&self) -> Option<String> {
        Some("fake tracker".into())
    }
}

struct FakeRobot(FakeCell);

#[async_trait]
impl Robot for FakeRobot {
    /// Switches arm power on (refused during an E-stop). Cancel-safe: no await before it
    /// returns.
    async fn prepare(&mut self, speed_pct: f64) -> Result<(), CellError> {
        if let Some(f) = self.0.call(Op::RobotPrepare, Call::RobotPrepare(speed_pct)) {
            return fail(DeviceKind::Robot, f).await;
        }
        self.0.script().speed_pct = speed_pct;
        lock_world(&self.0.world)
            .set_power(true)
            .map_err(robot_error)
    }

    /// Starts the move on the world (instant); refused without power. Cancel-safe: no await
    /// before it returns, except a scripted hang.
    async fn move_joints(&mut self, q_rad: &[f64]) -> Result<(), CellError> {
        let probe = self.0.script().probe.clone();
        let call = Call::MoveJ {
            q: q_rad.to_vec(),
            probe: probe.map_or(0, |p| p()),
        };
        if let Some(f) = self.0.call(Op::MoveJ, call) {
            return fail(DeviceKind::Robot, f).await;
        }
        let speed = self.0.script().speed_pct;
        let mut w = lock_world(&self.0.world);
        if !w.power() {
            return Err(CellError::new(
                DeviceKind::Robot,
                FaultKind::EmergencyStop,
                "arm power is off",
            ));
        }
        w.start_move(q_rad.to_vec(), speed).map_err(robot_error)
    }

    /// The read-back joints once the world's move has ended (at once: motion is instant).
    /// Cancel-safe: holds nothing across its awaits.
    async fn wait_settled(&mut self, _timeout: Duration) -> Result<Vec<f64>, CellError> {
        let fired = self.0.call(Op::WaitSettled, Call::WaitSettled);
        let off = match fired {
            Some(Fired::SettleOff(j, rad)) => Some((j, rad)),
            Some(f) => return fail(DeviceKind::Robot, f).await,
            None => None,
        };
        while !lock_world(&self.0.world).is_settled() {
            tokio::task::yield_now().await;
        }
        let mut q = lock_world(&self.0.world).readback_joints_rad();
        if let Some((j, rad)) = off {
            q[j] += rad;
        }
        Ok(q)
    }

    /// Cancel-safe: no await before it returns.
    async fn joints(&mut self) -> Result<Vec<f64>, CellError> {
        Ok(lock_world(&self.0.world).readback_joints_rad())
    }

    /// Cancel-safe: no await before it returns.
    async fn stop(&mut self) -> Result<(), CellError> {
        self.0.log(Call::RobotStop);
        lock_world(&self.0.world).stop();
        Ok(())
    }

    /// Never switches power on. Cancel-safe: no await before it returns.
    async fn reconnect(&mut self) -> Result<(), CellError> {
        if let Some(f) = self.0.call(Op::RobotReconnect, Call::RobotReconnect) {
            return fail(DeviceKind::Robot, f).await;
        }
        Ok(())
    }

    fn identity(&self) -> Option<String> {
        Some("fake robot".into())
    }
}

struct FakeStage {
    cell: FakeCell,
    manual: bool,
}

#[async_trait]
impl Stage for FakeStage {
    fn is_manual(&self) -> bool {
        self.manual
    }

    /// Cancel-safe: no await before it returns.
    async fn prepare(&mut self) -> Result<(), CellError> {
        if let Some(f) = self.cell.call(Op::StagePrepare, Call::StagePrepare) {
            return fail(DeviceKind::Stage, f).await;
        }
        Ok(())
    }

    /// Puts the world's stage at `position_mm` (instant) and reads it back. Cancel-safe: no
    /// await before it returns, except a scripted hang.
    async fn move_to(&mut self, position_mm: f64) -> Result<f64, CellError> {
        if let Some(f) = self.cell.call(Op::StageMove, Call::StageMove(position_mm)) {
            return fail(DeviceKind::Stage, f).await;
        }
        let mut w = lock_world(&self.cell.world);
        w.set_manual_stage_mm(position_mm);
        Ok(w.stage_nominal_mm())
    }

    fn set_prompt_context(&mut self, _context: PromptContext) {}

    /// Cancel-safe: no await before it returns.
    async fn stop(&mut self) -> Result<(), CellError> {
        self.cell.log(Call::StageStop);
        Ok(())
    }

    fn needs_clear(&self) -> bool {
        self.manual
    }

    /// A manual stage's [`crate::cell::CONFIRM_CLEAR`] question, answered at once. Cancel-safe: no await
    /// before it returns, except a scripted hang.
    async fn confirm_clear(&mut self, _context: PromptContext) -> Result<(), CellError> {
        if !self.manual {
            return Ok(());
        }
        if let Some(f) = self.cell.call(Op::ConfirmClear, Call::ConfirmClear) {
            return fail(DeviceKind::Operator, f).await;
        }
        Ok(())
    }

    fn identity(&self) -> Option<String> {
        Some("fake stage".into())
    }
}
