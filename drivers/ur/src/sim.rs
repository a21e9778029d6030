//! The simulated controller behind the servers: robot mode, safety mode, remote control,
//! the running URScript program, and the joints through a [`Motion`] the embedding
//! simulator provides (or [`TrapezoidMotion`]).
//!
//! State changes that take time on a real controller (power on, brake release) happen after
//! configurable delays, applied lazily whenever the state is read.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::watch;
use tracing::{debug, info, warn};

use crate::dashboard::{self, Command, RobotMode, RuntimeState, SafetyMode};
use crate::rtde::Value;
use crate::script::{self, Statement};

/// Joint positions and speeds at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointSample {
    /// Measured positions, rad.
    pub q: [f64; 6],
    /// Measured speeds, rad/s.
    pub qd: [f64; 6],
    /// Commanded positions, rad.
    pub target_q: [f64; 6],
}

/// The joints of the simulated arm. Times are seconds since the controller started.
pub trait Motion: Send + 'static {
    /// The joints at time `t` (non-decreasing between calls).
    fn sample(&mut self, t: f64) -> JointSample;
    /// Starts a joint move to `q` at leading-axis speed `v` and acceleration `a`, taking at
    /// least `min_duration` s. Replaces any move under way.
    fn movej(&mut self, t: f64, q: [f64; 6], a: f64, v: f64, min_duration: f64);
    /// Decelerates every joint to rest at `a` rad/s² (URScript `stopj`).
    fn stopj(&mut self, t: f64, a: f64);
    /// Stops at once (safety stop, power off): the arm holds where it is.
    fn halt(&mut self, t: f64);
    /// Whether the joints still move at `t`.
    fn is_moving(&mut self, t: f64) -> bool;
    /// A safety event the arm's own fault model raised by `t`, reported once (the
    /// controller then halts the arm through [`Motion::halt`] and changes its safety mode).
    fn fault(&mut self, _t: f64) -> Option<MotionFault> {
        None
    }
}

/// A safety event raised by a [`Motion`] (the embedding simulator's fault model).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionFault {
    /// As [`SimController::protective_stop`].
    ProtectiveStop,
    /// As [`SimController::emergency_stop`] with the button pressed.
    EmergencyStop,
}

#[derive(Debug, Clone, Copy)]
enum Segment {
    Rest([f64; 6]),
    Move {
        q0: [f64; 6],
        q1: [f64; 6],
        t0: f64,
        /// leading-axis distance, speed, acceleration, duration of the profile
        dist: f64,
        v: f64,
        a: f64,
        dur: f64,
        /// time stretch (≥ 1) for a minimum duration
        stretch: f64,
    },
    Stop {
        q0: [f64; 6],
        qd0: [f64; 6],
        t0: f64,
        dur: f64,
    },
}

/// Synchronised trapezoidal joint moves (all joints start and end together, the leading
/// axis at `v` and `a`), exact in time; no noise, no dynamics.
#[derive(Debug, Clone)]
pub struct TrapezoidMotion {
    seg: Segment,
}

impl TrapezoidMotion {
    /// An arm at rest at `q`.
    pub fn new(q: [f64; 6]) -> Self {
        TrapezoidMotion {
            seg: Segment::Rest(q),
        }
    }

    /// Position along the leading axis and its speed at `tau` s into a profile.
    fn profile(dist: f64, v: f64, a: f64, tau: f64) -> (f64, f64) {
        let ta = v / a;
        if dist <= v * ta {
            // triangular
            let tp = (dist / a).sqrt();
            if tau <= tp {
                (0.5 * a * tau * tau, a * tau)
            } else if tau <= 2.0 * tp {
                let r = 2.0 * tp - tau;
                (dist - 0.5 * a * r * r, a * r)
            } else {
                (dist, 0.0)
            }
        } else {
            let dur = dist / v + ta;
            if tau <= ta {
                (0.5 * a * tau * tau, a * tau)
            } else if tau <= dur - ta {
                (0.5 * a * ta * ta + v * (tau - ta), v)
            } else if tau <= dur {
                let r = dur - tau;
                (dist - 0.5 * a * r * r, a * r)
            } else {
                (dist, 0.0)
            }
        }
    }

    fn duration(dist: f64, v: f64, a: f64) -> f64 {
        let ta = v / a;
        if dist <= v * ta {
            2.0 * (dist / a).sqrt()
        } else {
            dist / v + ta
        }
    }
}

impl Motion for TrapezoidMotion {
    fn sample(&mut self, t: f64) -> JointSample {
        match self.seg {
            Segment::Rest(q) => JointSample {
                q,
                qd: [0.0; 6],
                target_q: q,
            },
            Segment::Move {
                q0,
                q1,
                t0,
                dist,
                v,
                a,
                dur,
                stretch,
            } => {
                let tau = ((t - t0) / stretch).max(0.0);
                if tau >= dur || dist == 0.0 {
                    self.seg = Segment::Rest(q1);
                    return self.sample(t);
                }
                let (s, sd) = Self::profile(dist, v, a, tau);
                let f = s / dist;
                let fd = sd / dist / stretch;
                let q = std::array::from_fn(|i| q0[i] + (q1[i] - q0[i]) * f);
                let qd = std::array::from_fn(|i| (q1[i] - q0[i]) * fd);
                JointSample { q, qd, target_q: q }
            }
            Segment::Stop { q0, qd0, t0, dur } => {
                let tau = (t - t0).max(0.0);
                if tau >= dur {
                    let q = std::array::from_fn(|i| q0[i] + qd0[i] * dur / 2.0);
                    self.seg = Segment::Rest(q);
                    return self.sample(t);
                }
                let k = 1.0 - tau / dur;
                let q = std::array::from_fn(|i| q0[i] + qd0[i] * (tau - tau * tau / (2.0 * dur)));
                let qd = std::array::from_fn(|i| qd0[i] * k);
                JointSample { q, qd, target_q: q }
            }
        }
    }

    fn movej(&mut self, t: f64, q: [f64; 6], a: f64, v: f64, min_duration: f64) {
        let q0 = self.sample(t).q;
        let dist = (0..6).map(|i| (q[i] - q0[i]).abs()).fold(0.0, f64::max);
        let dur = Self::duration(dist, v, a);
        let stretch = if min_duration > dur && dur > 0.0 {
            min_duration / dur
        } else {
            1.0
        };
        self.seg = Segment::Move {
            q0,
            q1: q,
            t0: t,
            dist,
            v,
            a,
            dur,
            stretch,
        };
    }

    fn stopj(&mut self, t: f64, a: f64) {
        let s = self.sample(t);
        let peak = s.qd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        self.seg = if peak == 0.0 {
            Segment::Rest(s.q)
        } else {
            Segment::Stop {
                q0: s.q,
                qd0: s.qd,
                t0: t,
                dur: peak / a,
            }
        };
    }

    fn halt(&mut self, t: f64) {
        let q = self.sample(t).q;
        self.seg = Segment::Rest(q);
    }

    fn is_moving(&mut self, t: f64) -> bool {
        self.sample(t);
        !matches!(self.seg, Segment::Rest(_))
    }
}

/// What the simulated controller reports about itself and how fast it changes state.
#[derive(Debug, Clone)]
pub struct ControllerConfig {
    /// RTDE `v` reply: major, minor, bugfix, build (5.x = e-Series).
    pub version: [u32; 4],
    /// Dashboard `PolyscopeVersion` reply.
    pub polyscope_version: String,
    /// Dashboard `get robot model` reply (`UR5`, `UR10`).
    pub robot_model: String,
    /// Dashboard `get serial number` reply.
    pub serial_number: String,
    /// Highest RTDE output rate, Hz (500 on e-Series, 125 on CB3).
    pub max_rtde_hz: f64,
    /// From `power on` to IDLE.
    pub power_on_delay: Duration,
    /// From `brake release` to RUNNING.
    pub brake_release_delay: Duration,
    /// How long after a protective stop `unlock protective stop` is refused (5 s on a
    /// controller).
    pub unlock_delay: Duration,
    /// Deceleration of the joints when a program is stopped (Dashboard `stop`), rad/s².
    pub program_stop_decel: f64,
    /// Whether the pendant is in remote control (scripts and remote-only commands accepted).
    pub remote_control: bool,
    /// The robot mode at start.
    pub initial_mode: RobotMode,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        ControllerConfig {
            version: [5, 11, 1, 108318],
            polyscope_version: "URSoftware 5.11.1.108318 (Jan 05 2021)".into(),
            robot_model: "UR5".into(),
            serial_number: "20185500001".into(),
            max_rtde_hz: 500.0,
            power_on_delay: Duration::from_millis(300),
            brake_release_delay: Duration::from_millis(300),
            unlock_delay: Duration::from_secs(5),
            program_stop_decel: 4.0,
            remote_control: true,
            initial_mode: RobotMode::PowerOff,
        }
    }
}

#[derive(Debug)]
struct Program {
    name: String,
    statements: Vec<Statement>,
    /// index of the statement under way (None: the next one has not started)
    current: Option<usize>,
    next: usize,
    sleep_until: f64,
}

struct State {
    motion: Box<dyn Motion>,
    robot_mode: RobotMode,
    safety_mode: SafetyMode,
    remote_control: bool,
    /// robot mode changes under way, in time order
    pending: Vec<(Instant, RobotMode)>,
    program: Option<Program>,
    protective_stop_at: Option<Instant>,
    programs_run: u64,
    programs_refused: u64,
    last_script_error: Option<String>,
}

struct Inner {
    config: ControllerConfig,
    start: Instant,
    state: Mutex<State>,
    disconnect: watch::Sender<u64>,
}

/// Handle on the simulated controller (cheap to clone; every clone is the same controller).
#[derive(Clone)]
pub struct SimController {
    inner: Arc<Inner>,
}

/// A consistent view of the controller at one instant (what RTDE streams).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Snapshot {
    /// Seconds since the controller started.
    pub timestamp: f64,
    /// Joints.
    pub joints: JointSample,
    /// Robot mode.
    pub robot_mode: RobotMode,
    /// Safety mode.
    pub safety_mode: SafetyMode,
    /// Program state.
    pub runtime_state: RuntimeState,
}

impl Snapshot {
    /// `robot_status_bits`: bit 0 power on, bit 1 program running.
    pub fn robot_status_bits(&self) -> u32 {
        let power = matches!(
            self.robot_mode,
            RobotMode::PowerOn | RobotMode::Idle | RobotMode::Running | RobotMode::Backdrive
        );
        u32::from(power) | (u32::from(self.runtime_state == RuntimeState::Playing) << 1)
    }

    /// `safety_status_bits` (RTDE guide: bit 0 normal, 1 reduced, 2 protective stopped,
    /// 3 recovery, 4 safeguard stopped, 5 system e-stop, 6 robot e-stop, 7 e-stopped,
    /// 8 violation, 9 fault, 10 stopped due to safety).
    pub fn safety_status_bits(&self) -> u32 {
        let bit = |b: u32| 1u32 << b;
        match self.safety_mode {
            SafetyMode::Normal => bit(0),
            SafetyMode::Reduced => bit(1),
            SafetyMode::ProtectiveStop => bit(2) | bit(10),
            SafetyMode::Recovery => bit(3),
            SafetyMode::SafeguardStop | SafetyMode::AutomaticModeSafeguardStop => bit(4) | bit(10),
            SafetyMode::SystemEmergencyStop => bit(5) | bit(7) | bit(10),
            SafetyMode::RobotEmergencyStop => bit(6) | bit(7) | bit(10),
            SafetyMode::Violation => bit(8) | bit(10),
            SafetyMode::Fault => bit(9) | bit(10),
            _ => bit(10),
        }
    }

    /// The value of RTDE output `name` of type `ty` (zero for what is not simulated).
    pub fn output(&self, name: &str, ty: crate::rtde::RtdeType) -> Value {
        let running = self.robot_mode == RobotMode::Running;
        let v = match name {
            "timestamp" => Value::Double(self.timestamp),
            "actual_q" => Value::Vector6d(self.joints.q),
            "actual_qd" | "target_qd" => Value::Vector6d(self.joints.qd),
            "target_q" => Value::Vector6d(self.joints.target_q),
            "robot_mode" => Value::Int32(self.robot_mode.code()),
            "safety_mode" | "safety_status" => Value::Int32(self.safety_mode.code()),
            "runtime_state" => Value::Uint32(self.runtime_state.code()),
            "robot_status_bits" => Value::Uint32(self.robot_status_bits()),
            "safety_status_bits" => Value::Uint32(self.safety_status_bits()),
            "speed_scaling" | "target_speed_fraction" => Value::Double(1.0),
            // JOINT_RUNNING_MODE 253, JOINT_IDLE_MODE 255, JOINT_POWER_OFF_MODE 239
            "joint_mode" => Value::Vector6Int32(
                [match self.robot_mode {
                    RobotMode::Running => 253,
                    RobotMode::Idle | RobotMode::PowerOn => 255,
                    _ => 239,
                }; 6],
            ),
            "actual_main_voltage" => Value::Double(48.0),
            "actual_robot_voltage" => Value::Double(if running { 48.0 } else { 0.0 }),
            _ => Value::zero(ty),
        };
        if v.ty() == ty {
            v
        } else {
            Value::zero(ty)
        }
    }
}

impl SimController {
    /// A controller with `config` whose joints are `motion`.
    pub fn new(config: ControllerConfig, motion: Box<dyn Motion>) -> Self {
        let (disconnect, _) = watch::channel(0);
        SimController {
            inner: Arc::new(Inner {
                state: Mutex::new(State {
                    motion,
                    robot_mode: config.initial_mode,
                    safety_mode: SafetyMode::Normal,
                    remote_control: config.remote_control,
                    pending: Vec::new(),
                    program: None,
                    protective_stop_at: None,
                    programs_run: 0,
                    programs_refused: 0,
                    last_script_error: None,
                }),
                config,
                start: Instant::now(),
                disconnect,
            }),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ControllerConfig {
        &self.inner.config
    }

    fn t(&self, now: Instant) -> f64 {
        now.duration_since(self.inner.start).as_secs_f64()
    }

    /// The state, with pending transitions and the program advanced to `now`.
    fn state(&self, now: Instant) -> MutexGuard<'_, State> {
        let mut s = self.inner.state.lock().unwrap_or_else(|p| p.into_inner());
        while let Some(&(at, mode)) = s.pending.first() {
            if now < at {
                break;
            }
            s.robot_mode = mode;
            s.pending.remove(0);
        }
        let t = self.t(now);
        match s.motion.fault(t) {
            Some(MotionFault::ProtectiveStop) => Self::apply_protective_stop(&mut s, t, now),
            Some(MotionFault::EmergencyStop) => Self::apply_emergency_stop(&mut s, t),
            None => {}
        }
        Self::advance_program(&mut s, t);
        s
    }

    fn apply_protective_stop(s: &mut State, t: f64, now: Instant) {
        s.motion.halt(t);
        s.program = None;
        s.safety_mode = SafetyMode::ProtectiveStop;
        s.protective_stop_at = Some(now);
        warn!("simulated UR: protective stop");
    }

    fn apply_emergency_stop(s: &mut State, t: f64) {
        s.motion.halt(t);
        s.program = None;
        s.pending.clear();
        s.robot_mode = RobotMode::PowerOff;
        s.safety_mode = SafetyMode::RobotEmergencyStop;
        warn!("simulated UR: emergency stop pressed");
    }

    fn advance_program(s: &mut State, t: f64) {
        loop {
            let Some(p) = s.program.as_mut() else { return };
            if let Some(i) = p.current {
                let busy = match p.statements[i] {
                    Statement::Sleep(_) => t < p.sleep_until,
                    _ => s.motion.is_moving(t),
                };
                if busy {
                    return;
                }
                p.current = None;
            }
            let Some(st) = p.statements.get(p.next).cloned() else {
                debug!("URScript program {} finished", p.name);
                s.program = None;
                return;
            };
            p.current = Some(p.next);
            p.next += 1;
            match st {
                Statement::MoveJ {
                    q, a, v, t: dur, ..
                } => s.motion.movej(t, q, a, v, dur),
                Statement::StopJ { a } => s.motion.stopj(t, a),
                Statement::Sleep(d) => p.sleep_until = t + d,
            }
        }
    }

    /// What RTDE streams now.
    pub fn snapshot(&self) -> Snapshot {
        let now = Instant::now();
        let t = self.t(now);
        let mut s = self.state(now);
        let joints = s.motion.sample(t);
        Snapshot {
            timestamp: t,
            joints,
            robot_mode: s.robot_mode,
            safety_mode: s.safety_mode,
            runtime_state: if s.program.is_some() {
                RuntimeState::Playing
            } else {
                RuntimeState::Stopped
            },
        }
    }

    /// Programs started and refused so far, and the last refusal's reason.
    pub fn script_counts(&self) -> (u64, u64, Option<String>) {
        let s = self.state(Instant::now());
        (
            s.programs_run,
            s.programs_refused,
            s.last_script_error.clone(),
        )
    }

    /// Switches the pendant between remote (`true`) and local control.
    pub fn set_remote_control(&self, on: bool) {
        self.state(Instant::now()).remote_control = on;
    }

    /// A protective stop (what a collision or a limit does): the arm stops at once, the
    /// program ends, safety mode PROTECTIVE_STOP until a Dashboard `unlock protective stop`
    /// at least `unlock_delay` later.
    pub fn protective_stop(&self) {
        let now = Instant::now();
        let t = self.t(now);
        let mut s = self.state(now);
        Self::apply_protective_stop(&mut s, t, now);
    }

    /// Emergency stop button pressed (`true`: arm stops, program ends, power off, safety
    /// mode ROBOT_EMERGENCY_STOP) or released (`false`: safety NORMAL, the arm stays
    /// powered off until `power on` and `brake release`).
    pub fn emergency_stop(&self, pressed: bool) {
        let now = Instant::now();
        let t = self.t(now);
        let mut s = self.state(now);
        if pressed {
            Self::apply_emergency_stop(&mut s, t);
        } else if s.safety_mode.is_emergency_stop() {
            s.safety_mode = SafetyMode::Normal;
            info!("simulated UR: emergency stop released");
        }
    }

    /// Closes every client connection of the servers (a network drop).
    pub fn disconnect_clients(&self) {
        self.inner.disconnect.send_modify(|g| *g += 1);
    }

    /// Changes each time [`SimController::disconnect_clients`] is called.
    pub fn disconnect_signal(&self) -> watch::Receiver<u64> {
        self.inner.disconnect.subscribe()
    }

    /// Runs a received URScript program, replacing the running one. Not run (and counted as
    /// refused) in local control, when it does not compile in the subset, or when the arm is
    /// not RUNNING in safety mode NORMAL/REDUCED.
    pub fn run_script(&self, text: &str) -> Result<(), String> {
        let now = Instant::now();
        let t = self.t(now);
        let mut s = self.state(now);
        let refuse = |s: &mut State, why: String| {
            warn!("simulated UR: program not run: {why}");
            s.programs_refused += 1;
            s.last_script_error = Some(why.clone());
            Err(why)
        };
        // a CB3 has no local/remote mode
        if self.inner.config.version[0] >= 5 && !s.remote_control {
            return refuse(&mut s, "the pendant is in local control".into());
        }
        let statements = match script::parse_program(text) {
            Ok(st) => st,
            Err(e) => return refuse(&mut s, e.to_string()),
        };
        if s.robot_mode != RobotMode::Running
            || !matches!(s.safety_mode, SafetyMode::Normal | SafetyMode::Reduced)
        {
            let why = format!(
                "robot mode {} safety mode {}",
                s.robot_mode.name(),
                s.safety_mode.name()
            );
            return refuse(&mut s, why);
        }
        let name = text
            .lines()
            .find_map(|l| {
                l.trim()
                    .strip_prefix("def ")
                    .or(l.trim().strip_prefix("sec "))
            })
            .and_then(|h| h.split('(').next())
            .map_or("<unnamed>".to_owned(), |n| n.trim().to_owned());
        s.programs_run += 1;
        s.program = Some(Program {
            name,
            statements,
            current: None,
            next: 0,
            sleep_until: 0.0,
        });
        Self::advance_program(&mut s, t);
        Ok(())
    }

    /// The reply to Dashboard command `line` and whether the server closes the connection
    /// after it (`quit`).
    pub fn dashboard(&self, line: &str) -> (String, bool) {
        let Some(cmd) = Command::parse(line) else {
            return (dashboard::not_understood(line), false);
        };
        let now = Instant::now();
        let t = self.t(now);
        let cfg = &self.inner.config;
        let mut s = self.state(now);
        // a CB3 (PolyScope 3) has no local/remote mode; e-Series refuses remote-only commands
        // in Local control, and answers `is in remote control` from 5.6 on
        let e_series = cfg.version[0] >= 5;
        if e_series && cmd.needs_remote_control() && !s.remote_control {
            return (dashboard::LOCAL_CONTROL.into(), false);
        }
        let reply = match cmd {
            Command::PowerOn => {
                if s.robot_mode == RobotMode::PowerOff && !s.safety_mode.is_emergency_stop() {
                    s.robot_mode = RobotMode::PowerOn;
                    s.pending = vec![(now + cfg.power_on_delay, RobotMode::Idle)];
                }
                dashboard::POWERING_ON.into()
            }
            Command::PowerOff => {
                s.motion.halt(t);
                s.program = None;
                s.pending.clear();
                s.robot_mode = RobotMode::PowerOff;
                dashboard::POWERING_OFF.into()
            }
            Command::BrakeRelease => {
                // from POWER_OFF the arm is powered on on the fly (UR's ROS driver documents
                // it for `brake release`); not during an emergency stop
                if s.robot_mode == RobotMode::PowerOff && !s.safety_mode.is_emergency_stop() {
                    s.robot_mode = RobotMode::PowerOn;
                    s.pending = vec![(now + cfg.power_on_delay, RobotMode::Idle)];
                }
                let releasing = s.pending.iter().any(|p| p.1 == RobotMode::Running);
                let powering = s.robot_mode == RobotMode::PowerOn || !s.pending.is_empty();
                if !releasing && (s.robot_mode == RobotMode::Idle || powering) {
                    let from = s.pending.last().map_or(now, |p| p.0);
                    s.pending
                        .push((from + cfg.brake_release_delay, RobotMode::Running));
                }
                dashboard::BRAKE_RELEASING.into()
            }
            Command::RobotMode => format!("Robotmode: {}", s.robot_mode.name()),
            Command::SafetyMode => format!("Safetymode: {}", s.safety_mode.name()),
            Command::SafetyStatus => format!("Safetystatus: {}", s.safety_mode.name()),
            Command::IsInRemoteControl if (cfg.version[0], cfg.version[1]) < (5, 6) => {
                dashboard::not_understood(line)
            }
            Command::IsInRemoteControl => s.remote_control.to_string(),
            Command::Running => format!("Program running: {}", s.program.is_some()),
            Command::ProgramState => match &s.program {
                Some(p) => format!("PLAYING {}", p.name),
                None => "STOPPED <unnamed>".into(),
            },
            Command::Stop => {
                if s.program.take().is_some() {
                    s.motion.stopj(t, cfg.program_stop_decel);
                }
                dashboard::STOPPED.into()
            }
            Command::Pause => "Failed to execute: pause".into(),
            Command::Play => "Failed to execute: play".into(),
            Command::UnlockProtectiveStop => match s.protective_stop_at {
                Some(at) if s.safety_mode == SafetyMode::ProtectiveStop => {
                    if now.duration_since(at) < cfg.unlock_delay {
                        dashboard::CANNOT_UNLOCK_YET.into()
                    } else {
                        s.safety_mode = SafetyMode::Normal;
                        s.protective_stop_at = None;
                        dashboard::PROTECTIVE_STOP_RELEASING.into()
                    }
                }
                _ => dashboard::PROTECTIVE_STOP_RELEASING.into(),
            },
            Command::ClosePopup => dashboard::CLOSING_POPUP.into(),
            Command::CloseSafetyPopup => dashboard::CLOSING_SAFETY_POPUP.into(),
            Command::Popup(_) => "showing popup".into(),
            Command::PolyscopeVersion => cfg.polyscope_version.clone(),
            Command::Version => cfg
                .version
                .iter()
                .map(u32::to_string)
                .collect::<Vec<_>>()
                .join("."),
            Command::GetRobotModel => cfg.robot_model.clone(),
            Command::GetSerialNumber => cfg.serial_number.clone(),
            Command::GetLoadedProgram => "No program loaded".into(),
            Command::Quit => return (dashboard::DISCONNECTED.into(), true),
        };
        (reply, false)
    }
}
