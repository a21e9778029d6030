//! [`World`]: the one simulated physical state of the cell (true robot, motion, stage, tracker
//! noise and drift, seeded RNG), shared by the device backends behind `Arc<Mutex<World>>`.
//!
//! Frames: the measurement frame is the tracker's output frame. The true ball position is
//! `p = R_b · (T_flange(q_true) · (tool + s·u_actual + s·k·c + r·u_actual)) + t_b` with `s` the
//! stage position, `k` the cross-talk, `c` the cross direction and `r` the stage repeatability
//! draw; the controller reports the commanded joints while the arm sits at jittered ones.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use emscon::{BackendMeasurement, BackendPoint, Meteo, SharedFaults};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use robotlink::{BackendError, ErrorCode};
use tracing::{debug, info};
use zaber::sim::StageSim;

use super::config::SimWorldConfig;
use super::SimError;
use crate::model::kinematics::{forward, Pose};
use crate::model::rotation::from_rotation_vector;
use crate::model::RobotModel;
use crate::plan::timing::{MotionLimits, MoveProfile};
use crate::simulate::TrackerNoise;

/// The world shared by the backends and the test/handle side.
pub type SharedWorld = Arc<Mutex<World>>;

/// Lock a shared world (a poisoned lock is recovered: the state stays usable).
pub fn lock_world(w: &SharedWorld) -> MutexGuard<'_, World> {
    w.lock().unwrap_or_else(|p| p.into_inner())
}

/// World-level faults (the ones the protocol servers cannot express); change them at runtime.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldFaults {
    /// Probability that a measurement loses the beam.
    pub beam_break_probability: f64,
    /// Close the tracker connection at the command after every N-th measurement (0 = never).
    pub disconnect_after_measurements: u64,
    /// Reject the N-th MOVEJ since start (1-based; 0 = never).
    pub reject_move_n: u64,
    /// Error code used by `reject_move_n`.
    pub reject_code: ErrorCode,
    /// Latch an E-stop during the N-th move (1-based; 0 = never).
    pub estop_after_moves: u64,
    /// Delay from that move's start to the E-stop.
    pub estop_delay: Duration,
    /// The laser reports "not warmed up" until this long after start.
    pub not_warmed_up_for: Duration,
    /// The next N stage rests away from 0 mm end `stage_slip_mm` further along the axis than
    /// the stage reports (a mechanical slip its encoder does not see).
    pub stage_slips: u32,
    /// Size of a `stage_slips` slip (mm).
    pub stage_slip_mm: f64,
}

/// Where the stage position comes from.
#[derive(Debug)]
pub enum StageSource {
    /// A Zaber stage simulator (its microstep position).
    Zaber {
        /// The simulator (shared state with the pty server).
        sim: StageSim,
        /// Microsteps per mm.
        microsteps_per_mm: f64,
    },
    /// A micrometer set by hand; tests and scripted prompters set it.
    Manual {
        /// Position (mm).
        position_mm: f64,
    },
}

#[derive(Debug, Clone)]
struct Motion {
    from: Vec<f64>,
    to: Vec<f64>,
    arrival: Vec<f64>,
    start: Instant,
    duration: Duration,
    /// The synchronised trapezoid along the straight joint line.
    profile: MoveProfile,
}

impl Motion {
    fn at(&self, now: Instant) -> Vec<f64> {
        let t = if self.duration.is_zero() {
            1.0
        } else {
            self.profile
                .fraction_at(now.saturating_duration_since(self.start).as_secs_f64())
        };
        self.from
            .iter()
            .zip(&self.to)
            .map(|(a, b)| a + (b - a) * t)
            .collect()
    }
}

/// The simulated cell's physical state.
#[derive(Debug)]
pub struct World {
    nominal: RobotModel,
    truth: RobotModel,
    noise: TrackerNoise,
    noise_scale: f64,
    rng: ChaCha8Rng,
    start: Instant,
    /// Joint limits at 100 % (the move's speed setting scales the speeds).
    limits: MotionLimits,
    settle: Duration,
    joint_jitter_rad: f64,
    commanded: Vec<f64>,
    actual: Vec<f64>,
    motion: Option<Motion>,
    settled_at: Instant,
    power: bool,
    power_on_requests: u64,
    estop: bool,
    estop_at: Option<Instant>,
    moves: u64,
    stage: StageSource,
    stage_seen: Option<f64>,
    stage_offset_mm: f64,
    stage_repeatability_mm: f64,
    stage_cross_mm_per_mm: f64,
    u_nominal: Vector3<f64>,
    u_actual: Vector3<f64>,
    cross_dir: Vector3<f64>,
    drift_um_per_min: f64,
    warmup_um: f64,
    warmup_tau_min: f64,
    drift_dir: Vector3<f64>,
    measurements: u64,
    tracker_faults: Option<SharedFaults>,
    /// World-level faults (change at runtime).
    pub faults: WorldFaults,
}

fn gauss<R: Rng>(rng: &mut R) -> f64 {
    StandardNormal.sample(rng)
}

/// VAL3 `trsf` angles (deg) of a rotation: `R = Rx(rx)·Ry(ry)·Rz(rz)`.
pub fn val3_angles_deg(r: &Matrix3<f64>) -> [f64; 3] {
    let ry = r[(0, 2)].clamp(-1.0, 1.0).asin();
    let rx = (-r[(1, 2)]).atan2(r[(2, 2)]);
    let rz = (-r[(0, 1)]).atan2(r[(0, 0)]);
    [rx.to_degrees(), ry.to_degrees(), rz.to_degrees()]
}

impl World {
    /// A world from the nominal model, the true model and the configuration.
    pub fn new(
        nominal: RobotModel,
        truth: RobotModel,
        cfg: &SimWorldConfig,
        stage: StageSource,
    ) -> Result<World, SimError> {
        let u = cfg.stage_axis.unit();
        let mis = Vector3::from(cfg.stage_misalignment_mrad) / 1000.0;
        let u_actual = from_rotation_vector(&mis) * u;
        let cross_dir = {
            let v = Vector3::z().cross(&u);
            if v.norm() > 1e-9 {
                v.normalize()
            } else {
                Vector3::x()
            }
        };
        let drift = Vector3::from(cfg.drift_direction);
        let drift_dir = if drift.norm() > 1e-12 {
            drift.normalize()
        } else {
            Vector3::x()
        };
        let q0: Vec<f64> = cfg
            .initial_joints_deg
            .iter()
            .map(|d| d.to_radians())
            .collect();
        if q0.len() != nominal.dof() {
            return Err(SimError::Config(format!(
                "initial_joints_deg has {} values, the robot {} joints",
                q0.len(),
                nominal.dof()
            )));
        }
        let now = Instant::now();
        Ok(World {
            noise: TrackerNoise::at960(Vector3::from(cfg.tracker_position_mm)),
            noise_scale: cfg.tracker_noise_scale.max(0.0),
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            start: now,
            limits: cfg.motion_limits(&nominal),
            settle: Duration::from_secs_f64(cfg.settle_s()),
            joint_jitter_rad: cfg.joint_jitter_rad.max(0.0),
            commanded: q0.clone(),
            actual: q0,
            motion: None,
            settled_at: now,
            power: cfg.robot_power_on,
            power_on_requests: 0,
            estop: false,
            estop_at: None,
            moves: 0,
            stage,
            stage_seen: None,
            stage_offset_mm: 0.0,
            stage_repeatability_mm: cfg.stage_repeatability_mm.max(0.0),
            stage_cross_mm_per_mm: cfg.stage_cross_mm_per_mm,
            u_nominal: u,
            u_actual,
            cross_dir,
            drift_um_per_min: cfg.drift_um_per_min,
            warmup_um: cfg.warmup_um,
            warmup_tau_min: cfg.warmup_tau_min.max(1e-9),
            drift_dir,
            measurements: 0,
            tracker_faults: None,
            faults: WorldFaults {
                beam_break_probability: cfg.faults.tracker.beam_break_probability,
                disconnect_after_measurements: cfg.faults.tracker.disconnect_after_measurements,
                reject_move_n: cfg.faults.robot.reject_move_n,
                reject_code: ErrorCode::parse(&cfg.faults.robot.reject_code).map_err(|_| {
                    SimError::Config(format!(
                        "faults.robot.reject_code `{}`: expected an E_* code such as E_UNREACHABLE",
                        cfg.faults.robot.reject_code
                    ))
                })?,
                estop_after_moves: cfg.faults.robot.estop_after_moves,
                estop_delay: Duration::from_millis(cfg.faults.robot.estop_delay_ms),
                not_warmed_up_for: Duration::from_millis(cfg.faults.tracker.not_warmed_up_ms),
                stage_slips: cfg.faults.stage.slip,
                stage_slip_mm: cfg.faults.stage.slip_mm,
            },
            nominal,
            truth,
        })
    }

    /// Give the world the tracker server's fault handle (for `disconnect_after_measurements`).
    pub fn attach_tracker_faults(&mut self, faults: SharedFaults) {
        self.tracker_faults = Some(faults);
    }

    /// The nominal model (what the controller believes).
    pub fn nominal_model(&self) -> &RobotModel {
        &self.nominal
    }

    /// The true model (nominal + hidden errors, true base and tool).
    pub fn true_model(&self) -> &RobotModel {
        &self.truth
    }

    /// Somebody bumped the tracker (or the robot's base): the robot base now lies `shift_mm`
    /// farther along in the measurement frame. Nothing reports it; only measurements show it.
    pub fn bump_base(&mut self, shift_mm: Vector3<f64>) {
        self.truth.base_translation += shift_mm;
    }

    /// Time since the world started.
    pub fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }

    fn update(&mut self) {
        let now = Instant::now();
        if let Some(t) = self.estop_at {
            if now >= t {
                self.estop_at = None;
                self.estop = true;
                self.power = false;
                info!("sim: E-stop latched");
                self.halt(now);
            }
        }
        if let Some(m) = &self.motion {
            if now >= m.start + m.duration {
                self.commanded = m.to.clone();
                self.actual = m.arrival.clone();
                self.settled_at = m.start + m.duration + self.settle;
                self.motion = None;
            }
        }
    }

    fn halt(&mut self, now: Instant) {
        if let Some(m) = self.motion.take() {
            let q = m.at(now);
            self.commanded = q.clone();
            self.actual = q;
        }
        self.settled_at = now + self.settle;
    }

    /// Joints the controller reports (rad): interpolated while moving, then the commanded target.
    pub fn readback_joints_rad(&mut self) -> Vec<f64> {
        self.update();
        match &self.motion {
            Some(m) => m.at(Instant::now()),
            None => self.commanded.clone(),
        }
    }

    /// Where the arm really is (rad): the commanded target plus the repeatability draw.
    pub fn true_joints_rad(&mut self) -> Vec<f64> {
        self.update();
        match &self.motion {
            Some(m) => m.at(Instant::now()),
            None => self.actual.clone(),
        }
    }

    /// True while a move runs.
    pub fn is_moving(&mut self) -> bool {
        self.update();
        self.motion.is_some()
    }

    /// True when no move runs and the settle time has passed.
    pub fn is_settled(&mut self) -> bool {
        self.update();
        self.motion.is_none() && Instant::now() >= self.settled_at
    }

    /// Arm power.
    pub fn power(&self) -> bool {
        self.power
    }

    /// How many times power was switched on (by anyone) since start.
    pub fn power_on_requests(&self) -> u64 {
        self.power_on_requests
    }

    /// Switch arm power (off stops motion; on fails during an E-stop).
    pub fn set_power(&mut self, on: bool) -> Result<(), BackendError> {
        self.update();
        if on && self.estop {
            return Err(BackendError::new(ErrorCode::EStop, "emergency stop active"));
        }
        if !on {
            self.halt(Instant::now());
        }
        if on {
            self.power_on_requests += 1;
        }
        self.power = on;
        Ok(())
    }

    /// E-stop state.
    pub fn estop(&mut self) -> bool {
        self.update();
        self.estop
    }

    /// Press (true) or release (false) the E-stop; pressing stops motion and drops power.
    pub fn set_estop(&mut self, active: bool) {
        self.update();
        self.estop_at = None;
        self.estop = active;
        if active {
            self.halt(Instant::now());
            self.power = false;
        }
    }

    /// Moves accepted since start.
    pub fn moves(&self) -> u64 {
        self.moves
    }

    /// Check a joint target (rad) against the nominal joint limits.
    pub fn check_target(&self, q: &[f64]) -> Result<(), BackendError> {
        if q.len() != self.nominal.dof() {
            return Err(BackendError::new(ErrorCode::Args, "wrong number of joints"));
        }
        for (i, (v, l)) in q.iter().zip(&self.nominal.limits).enumerate() {
            if !l.contains(*v) {
                return Err(BackendError::new(
                    ErrorCode::Limit,
                    format!(
                        "joint {} at {:.3} deg outside its limits",
                        i + 1,
                        v.to_degrees()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Start a joint move (rad) at `vel_pct` of the joint speed; the repeatability draw is made
    /// now so the sequence of draws does not depend on polling.
    pub fn start_move(&mut self, q: Vec<f64>, vel_pct: f64) -> Result<(), BackendError> {
        self.update();
        let n = self.moves + 1;
        if self.faults.reject_move_n == n {
            self.moves = n;
            return Err(BackendError::new(
                self.faults.reject_code.clone(),
                format!("injected fault on move {n}"),
            ));
        }
        self.check_target(&q)?;
        if self.motion.is_some() {
            return Err(BackendError::new(
                ErrorCode::Busy,
                "a motion is in progress",
            ));
        }
        self.moves = n;
        let now = Instant::now();
        let from = self.commanded.clone();
        let profile = self
            .limits
            .at_speed_pct(vel_pct.clamp(0.01, 100.0))
            .profile(&from, &q);
        let secs = profile.duration_s();
        let secs = if secs.is_finite() {
            secs.clamp(0.0, 3600.0)
        } else {
            3600.0
        };
        let duration = Duration::from_secs_f64(secs);
        let jitter = self.joint_jitter_rad;
        let arrival: Vec<f64> = q
            .iter()
            .map(|v| v + jitter * gauss(&mut self.rng))
            .collect();
        debug!(move_n = n, ?duration, "sim: move started");
        self.motion = Some(Motion {
            from,
            to: q,
            arrival,
            start: now,
            duration,
            profile,
        });
        if self.faults.estop_after_moves == n {
            self.estop_at = Some(now + self.faults.estop_delay);
        }
        Ok(())
    }

    /// Abort the motion where the arm is.
    pub fn stop(&mut self) {
        self.update();
        self.halt(Instant::now());
    }

    /// Controller pose (nominal model, commanded joints): flange in the robot base frame,
    /// position mm and VAL3 angles deg.
    pub fn controller_pose(&mut self) -> robotlink::Pose {
        let q = self.readback_joints_rad();
        let fl = *forward(&self.nominal, &q).flange();
        robotlink::Pose {
            xyz_mm: [fl.p.x, fl.p.y, fl.p.z],
            rxyz_deg: val3_angles_deg(&fl.r),
        }
    }

    /// True flange pose in the measurement frame.
    pub fn true_flange(&mut self) -> Pose {
        let q = self.true_joints_rad();
        let fl = *forward(&self.truth, &q).flange();
        Pose {
            r: self.truth.base_rotation * fl.r,
            p: self.truth.base_rotation * fl.p + self.truth.base_translation,
        }
    }

    /// Stage position commanded / read back (mm), without repeatability.
    pub fn stage_nominal_mm(&self) -> f64 {
        match &self.stage {
            StageSource::Zaber {
                sim,
                microsteps_per_mm,
            } => sim.position_steps() as f64 / microsteps_per_mm,
            StageSource::Manual { position_mm } => *position_mm,
        }
    }

    /// True while the stage moves.
    pub fn stage_moving(&self) -> bool {
        match &self.stage {
            StageSource::Zaber { sim, .. } => sim.is_busy(),
            StageSource::Manual { .. } => false,
        }
    }

    /// Set the manual micrometer (no effect on a Zaber stage).
    pub fn set_manual_stage_mm(&mut self, position_mm: f64) {
        if let StageSource::Manual { position_mm: p } = &mut self.stage {
            *p = position_mm;
        }
    }

    /// True stage position along the real axis (mm): nominal + the repeatability draw of the
    /// current rest position.
    pub fn stage_true_mm(&mut self) -> f64 {
        let s = self.stage_nominal_mm();
        if !self.stage_moving() && self.stage_seen != Some(s) {
            self.stage_seen = Some(s);
            self.stage_offset_mm = self.stage_repeatability_mm * gauss(&mut self.rng);
            if s.abs() > 0.5 && self.faults.stage_slips > 0 {
                self.faults.stage_slips -= 1;
                self.stage_offset_mm += self.faults.stage_slip_mm;
            }
        }
        s + self.stage_offset_mm
    }

    /// Nominal stage axis in the flange frame.
    pub fn stage_axis_nominal(&self) -> Vector3<f64> {
        self.u_nominal
    }

    /// Real (misaligned) stage axis in the flange frame.
    pub fn stage_axis_actual(&self) -> Vector3<f64> {
        self.u_actual
    }

    /// True ball position in the measurement frame (mm), without noise and drift.
    pub fn true_ball_mm(&mut self) -> Vector3<f64> {
        let s_nom = self.stage_nominal_mm();
        let s = self.stage_true_mm();
        let local = self.truth.tool
            + self.u_actual * s
            + self.cross_dir * self.stage_cross_mm_per_mm * s_nom;
        self.true_flange().transform_point(&local)
    }

    /// Tracker drift at time `t` since start (mm, measurement frame).
    pub fn drift_mm_at(&self, t: Duration) -> Vector3<f64> {
        let t_min = t.as_secs_f64() / 60.0;
        let um =
            self.drift_um_per_min * t_min + self.warmup_um * (-t_min / self.warmup_tau_min).exp();
        self.drift_dir * (um / 1000.0)
    }

    /// Per-axis tracker σ (mm) at `p`.
    pub fn sigma_mm(&self, p: &Vector3<f64>) -> f64 {
        self.noise.sigma_mm(p) * self.noise_scale
    }

    /// Tracker measurements taken so far.
    pub fn measurements(&self) -> u64 {
        self.measurements
    }

    /// Whether the tracker sees the reflector (nothing moves).
    pub fn reflector_visible(&mut self) -> bool {
        !self.is_moving() && !self.stage_moving()
    }

    /// Whether the beam aimed at `xyz_mm` (tracker frame) locks onto the ball: visible and within
    /// the tracker's capture radius ([`emscon::backend::CAPTURE_RADIUS_MM`]) of where it is now.
    pub fn reflector_near(&mut self, xyz_mm: [f64; 3]) -> bool {
        let ball = self.true_ball_mm() + self.drift_mm_at(self.start.elapsed());
        self.reflector_visible()
            && (ball - Vector3::from(xyz_mm)).norm() <= emscon::backend::CAPTURE_RADIUS_MM
    }

    /// Whether the laser is warmed up.
    pub fn warmed_up(&self) -> bool {
        self.start.elapsed() >= self.faults.not_warmed_up_for
    }

    /// One stationary measurement: the true ball + drift + noise, or the target lost.
    pub fn measure(&mut self) -> BackendMeasurement {
        self.measurements += 1;
        let n = self.measurements;
        let every = self.faults.disconnect_after_measurements;
        if every > 0 && n.is_multiple_of(every) {
            if let Some(f) = &self.tracker_faults {
                info!(measurement = n, "sim: tracker connection will close");
                f.lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .closing_then_close += 1;
            }
        }
        if !self.reflector_visible() {
            return BackendMeasurement::TargetLost;
        }
        let p = self.faults.beam_break_probability;
        if p > 0.0 && self.rng.random::<f64>() < p {
            info!(measurement = n, "sim: random beam break");
            return BackendMeasurement::TargetLost;
        }
        let ball = self.true_ball_mm() + self.drift_mm_at(self.start.elapsed());
        let sigma = self.sigma_mm(&ball);
        let noise = Vector3::new(
            gauss(&mut self.rng),
            gauss(&mut self.rng),
            gauss(&mut self.rng),
        ) * sigma;
        let m = ball + noise;
        BackendMeasurement::Point(BackendPoint {
            xyz_mm: [m.x, m.y, m.z],
            std_mm: [sigma; 3],
            std_total_mm: sigma * 3f64.sqrt(),
            meteo: Meteo::default(),
        })
    }
}
