//! [`SimWorldConfig`]: the `[sim]` table of a cell configuration file. Every field has a
//! default; the defaults are FAST (few-ms delays) for tests, `realistic = true` switches the
//! timing fields that are not given explicitly to demo values. Parsed with the rest of the file
//! by [`super::parse_cell_config`] (or alone by [`super::parse_sim_config`] for `cellcal sim`):
//! unknown keys refused, every number finite, every array its exact length, then
//! [`SimWorldConfig::check`].

use serde::{Deserialize, Serialize};

use super::protocol::RobotProtocol;
use super::rules::{positive, rule, InvalidKey};
use crate::model::{RobotModel, SignedAxis};
use crate::plan::MotionLimits;

/// How the target-ball stage is simulated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum StageMode {
    /// A Zaber ASCII stage on a pty (`stage /dev/pts/N`).
    #[default]
    Zaber,
    /// A micrometer moved by the technician (prompts); its position is set on the world.
    Manual,
}

/// The simulated cell (`[sim]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimWorldConfig {
    /// Demo timings for every timing field not given explicitly.
    pub realistic: bool,
    /// Every joint's speed at 100 % (deg/s), reached at once (a constant-speed move); unset:
    /// 3600 in fast mode, the robot file's joint speeds and accelerations when realistic.
    pub move_speed_deg_s: Option<f64>,
    /// Settle time after a move (ms); fast default 0, realistic 1500.
    pub settle_ms: Option<u64>,
    /// Measuring time of a simulated tracker whose `[tracker] measure_ms` is unset (ms); fast
    /// default 5, realistic 1000.
    pub measure_ms: Option<u64>,
    /// The simulated tracker measures for the client's measuring time × this factor (1 = real
    /// time, 0 = instant: zero-delay devices for overhead benchmarks).
    pub measure_time_scale: f64,
    /// Stage speed (mm/s); fast default 1000, realistic 5.
    pub stage_speed_mm_s: Option<f64>,
    /// Time added to every stage move (ms): start-up and settling; 5 in both modes.
    pub stage_settle_ms: u64,
    /// Every simulated duration × this (1 = the times above; 0.05: twenty times faster): the
    /// robot's moves (joint speeds ÷ it, accelerations ÷ its square), its settling, the
    /// tracker's measuring, the stage's moves and settling. Loopback round trips, store commits
    /// and computing are not scaled. > 0.
    pub time_scale: f64,
    /// Tracker position in the measurement frame (mm): the range of the noise model.
    pub tracker_position_mm: [f64; 3],
    /// Tracker noise multiplier (1 = AT960 σ = (15 µm + 6 µm/m)/2 per axis, 0 = none).
    pub tracker_noise_scale: f64,
    /// True base translation (robot base origin in the measurement frame, mm); none = robot file.
    pub base_translation_mm: Option<[f64; 3]>,
    /// True base rotation vector (deg); none = robot file.
    pub base_rotation_vector_deg: Option<[f64; 3]>,
    /// True ball position in the flange frame at stage position 0 (mm); none = robot file.
    pub tool_mm: Option<[f64; 3]>,
    /// Hidden MDH errors: `paper`, `random`, `none`, or a TOML/JSON file of name = value.
    pub errors: String,
    /// Seed of `errors = "random"` and `nongeometric_errors = "typical"`.
    pub error_seed: u64,
    /// True joint compliance of the simulated robot per joint (rad/(N·m)): joint j deflects by
    /// c_j · τ_j, τ_j the gravity torque of the robot file's `[[masses]]`; none = 0.
    pub compliance_rad_per_nm: Option<[f64; 6]>,
    /// True per-joint harmonic errors of the simulated robot (µrad), `[sin q, cos q, sin 2q,
    /// cos 2q]` per joint: joint j deflects by a·sin q_j + b·cos q_j + a2·sin 2q_j + b2·cos 2q_j;
    /// none = 0.
    pub harmonics_urad: Option<[[f64; 4]; 6]>,
    /// Generated non-geometric errors when neither explicit key is given.
    pub nongeometric_errors: NongeometricErrors,
    /// Seed of every random draw in the world (noise, jitter, stage, beam breaks).
    pub seed: u64,
    /// Joint repeatability σ (rad), drawn per move.
    pub joint_jitter_rad: f64,
    /// Nominal stage axis in the flange frame: `+x`, `-x`, `+y`, `-y`, `+z`, `-z` (or `X,Y,Z`).
    pub stage_axis: SignedAxis,
    /// Misalignment of the real stage axis, rotation vector (mrad).
    pub stage_misalignment_mrad: [f64; 3],
    /// Systematic cross-travel deviation (mm per mm of travel).
    pub stage_cross_mm_per_mm: f64,
    /// Stage repeatability σ along the axis (mm), drawn per move.
    pub stage_repeatability_mm: f64,
    /// How the stage is simulated.
    pub stage_mode: StageMode,
    /// Zaber microsteps per mm: resolution / 0.003048 mm (the simulated product's full step),
    /// so a whole resolution (64 → 20997.375…); the simulated device reports that resolution.
    pub stage_microsteps_per_mm: f64,
    /// Stage travel (mm), from 0.
    pub stage_max_mm: f64,
    /// Also simulate an RS-232 gauge reading the true stage position (`gauge /dev/pts/M`).
    pub gauge: bool,
    /// Linear tracker drift (µm per minute).
    pub drift_um_per_min: f64,
    /// Warm-up error at start (µm), decaying exponentially.
    pub warmup_um: f64,
    /// Warm-up time constant (min).
    pub warmup_tau_min: f64,
    /// Direction of the drift in the measurement frame (normalised).
    pub drift_direction: [f64; 3],
    /// Tracker TCP port on 127.0.0.1 (0 = any free port).
    pub tracker_port: u16,
    /// Robot TCP port on 127.0.0.1 (0 = any free port).
    pub robot_port: u16,
    /// Client addresses the simulated controller's robotlink server accepts (its allow-list);
    /// any other peer is refused before it can send a line.
    pub robot_allow: Vec<std::net::IpAddr>,
    /// Robot arm power at start.
    pub robot_power_on: bool,
    /// The simulated controller: `robotlink` (Stäubli) or `ur` (Universal Robots); unset: the
    /// cell's `[robot_controller] protocol` (set when the cell configuration is parsed).
    pub robot_protocol: Option<RobotProtocol>,
    /// Loopback address whose standard ports (29999, 30001–30004) the simulated UR controller
    /// serves.
    pub ur_host: std::net::IpAddr,
    /// The simulated UR controller's software version `[major, minor, bugfix]`: 3.x is a CB3
    /// (no local/remote mode), 5.x an e-Series (`is in remote control` from 5.6 on).
    pub ur_version: [u32; 3],
    /// Initial joints (deg).
    pub initial_joints_deg: [f64; 6],
    /// Fault injection.
    pub faults: SimFaults,
    /// Device address and axis number the simulated Zaber stage answers at: `[stage]
    /// device_address` and `axis_number`, set when the cell configuration is parsed (not a
    /// `[sim]` key).
    #[serde(skip)]
    pub stage_address: (u8, u8),
}

impl Default for SimWorldConfig {
    fn default() -> Self {
        SimWorldConfig {
            realistic: false,
            move_speed_deg_s: None,
            settle_ms: None,
            measure_ms: None,
            measure_time_scale: 1.0,
            stage_speed_mm_s: None,
            stage_settle_ms: 5,
            time_scale: 1.0,
            tracker_position_mm: [2550.0, 0.0, 0.0],
            tracker_noise_scale: 1.0,
            base_translation_mm: None,
            base_rotation_vector_deg: None,
            tool_mm: None,
            errors: "paper".into(),
            error_seed: 1,
            compliance_rad_per_nm: None,
            harmonics_urad: None,
            nongeometric_errors: NongeometricErrors::None,
            seed: 4802,
            joint_jitter_rad: 1.2746e-5,
            stage_axis: SignedAxis::PLUS_Y,
            stage_misalignment_mrad: [0.0; 3],
            stage_cross_mm_per_mm: 0.0,
            stage_repeatability_mm: 0.0,
            stage_mode: StageMode::Zaber,
            stage_microsteps_per_mm: 1.0 / 0.000_047_625,
            stage_max_mm: 50.0,
            gauge: false,
            drift_um_per_min: 0.0,
            warmup_um: 0.0,
            warmup_tau_min: 30.0,
            drift_direction: [1.0, 0.0, 0.0],
            tracker_port: 0,
            robot_port: 0,
            robot_allow: vec![
                std::net::Ipv4Addr::LOCALHOST.into(),
                std::net::Ipv6Addr::LOCALHOST.into(),
            ],
            robot_power_on: false,
            robot_protocol: None,
            ur_host: std::net::Ipv4Addr::LOCALHOST.into(),
            ur_version: [5, 11, 1],
            initial_joints_deg: [0.0, 0.0, 90.0, 0.0, 45.0, 0.0],
            faults: SimFaults::default(),
            stage_address: (1, 1),
        }
    }
}

impl SimWorldConfig {
    /// How the simulated robot's joints move at 100 % (the controller's speed setting scales
    /// the speeds): every joint at `move_speed_deg_s` with instant acceleration when it is
    /// given or in fast mode (3600 deg/s), else (realistic) the robot file's
    /// `max_speed_deg_s` and `max_accel_deg_s2` ([`MotionLimits::of`], with its fallback).
    pub fn motion_limits(&self, model: &RobotModel) -> MotionLimits {
        let at_scale = match (self.move_speed_deg_s, self.realistic) {
            (Some(v), _) => MotionLimits::uniform(model.dof(), v.to_radians()),
            (None, false) => MotionLimits::uniform(model.dof(), 3600f64.to_radians()),
            (None, true) => MotionLimits::of(model, 100.0),
        };
        at_scale.time_scaled(self.time_scale)
    }
    /// The robot's settling after a move (s), [`Self::time_scale`] applied.
    pub fn settle_s(&self) -> f64 {
        self.effective_settle_ms() as f64 / 1000.0 * self.time_scale
    }
    /// The stage's speed (mm/s), [`Self::time_scale`] applied.
    pub fn stage_speed_scaled_mm_s(&self) -> f64 {
        self.effective_stage_speed_mm_s() / self.time_scale
    }
    /// The time added to every stage move (s), [`Self::time_scale`] applied.
    pub fn stage_settle_s(&self) -> f64 {
        self.stage_settle_ms as f64 / 1000.0 * self.time_scale
    }
    /// The simulated tracker's measuring time per ms of the client's: `measure_time_scale`
    /// × [`Self::time_scale`].
    pub fn measuring_scale(&self) -> f64 {
        self.measure_time_scale.max(0.0) * self.time_scale
    }
    /// Effective settle time (ms).
    pub fn effective_settle_ms(&self) -> u64 {
        self.settle_ms
            .unwrap_or(if self.realistic { 1500 } else { 0 })
    }
    /// Effective measuring time (ms).
    pub fn effective_measure_ms(&self) -> u64 {
        self.measure_ms
            .unwrap_or(if self.realistic { 1000 } else { 5 })
    }
    /// Effective stage speed (mm/s).
    pub fn effective_stage_speed_mm_s(&self) -> f64 {
        self.stage_speed_mm_s
            .unwrap_or(if self.realistic { 5.0 } else { 1000.0 })
    }

    /// The `[sim]` rules (keys named from the file's top, `sim.…`): a stage with positive
    /// travel and scale, positive speeds when given, a beam-break probability in [0, 1].
    pub fn check(&self) -> Result<(), InvalidKey> {
        positive("sim.stage_max_mm", self.stage_max_mm)?;
        positive("sim.stage_microsteps_per_mm", self.stage_microsteps_per_mm)?;
        positive("sim.time_scale", self.time_scale)?;
        if let Some(v) = self.move_speed_deg_s {
            positive("sim.move_speed_deg_s", v)?;
        }
        if let Some(v) = self.stage_speed_mm_s {
            positive("sim.stage_speed_mm_s", v)?;
        }
        if let Some(c) = &self.compliance_rad_per_nm {
            for (j, v) in c.iter().enumerate() {
                rule(
                    *v >= 0.0,
                    "sim.compliance_rad_per_nm",
                    format!("joint {}: a compliance cannot be negative, got {v}", j + 1),
                )?;
            }
        }
        rule(
            self.nongeometric_errors == NongeometricErrors::None
                || (self.compliance_rad_per_nm.is_none() && self.harmonics_urad.is_none()),
            "sim.nongeometric_errors",
            "\"typical\" generates the compliance and harmonic errors: give it or \
             compliance_rad_per_nm / harmonics_urad, not both",
        )?;
        rule(
            matches!(self.ur_version[0], 3 | 5),
            "sim.ur_version",
            format!(
                "must be a CB3 (3.x.y) or e-Series (5.x.y) version, got {:?}",
                self.ur_version
            ),
        )?;
        rule(
            self.ur_host.is_loopback(),
            "sim.ur_host",
            format!(
                "must be a loopback address (127.x.y.z or ::1), got {}",
                self.ur_host
            ),
        )?;
        let p = self.faults.tracker.beam_break_probability;
        rule(
            (0.0..=1.0).contains(&p),
            "sim.faults.tracker.beam_break_probability",
            format!("must be in [0, 1], got {p}"),
        )
    }
}

/// `[sim] nongeometric_errors`: generated non-geometric errors of the simulated robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum NongeometricErrors {
    /// None (only `compliance_rad_per_nm` / `harmonics_urad` when given).
    #[default]
    None,
    /// [`crate::simulate::truth::typical_terms`], seeded by `error_seed`.
    Typical,
}

/// `[sim.faults]`: faults armed at start (tests can change them at runtime through
/// [`super::RunningSimCell`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct SimFaults {
    /// `[sim.faults.tracker]`.
    pub tracker: TrackerFaults,
    /// `[sim.faults.robot]`.
    pub robot: RobotFaults,
    /// `[sim.faults.stage]`.
    pub stage: StageFaults,
}

/// `[sim.faults.tracker]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerFaults {
    /// Probability that a measurement loses the beam (seeded).
    pub beam_break_probability: f64,
    /// After a break the tracker re-locks by itself after this many ms (none: only a search).
    pub relock_after_ms: Option<u64>,
    /// Next N StartMeasurement commands find the beam broken.
    pub beam_break_before_measure: u32,
    /// Next N measurements break mid-way (Error packet + status change 25, no result).
    pub beam_break_during_measure: u32,
    /// Status of the StartMeasurement reply while the beam is broken.
    pub beam_break_status: i32,
    /// The connection closes (997, then close) at the command after every N-th measurement
    /// (0 = never).
    pub disconnect_after_measurements: u64,
    /// Next N commands get no reply (client timeout).
    pub no_reply: u32,
    /// The laser is not warmed up for this long after start (ms): StartMeasurement → 10012.
    pub not_warmed_up_ms: u64,
    /// Initialize takes this long (ms).
    pub initialize_delay_ms: u64,
}

impl Default for TrackerFaults {
    fn default() -> Self {
        TrackerFaults {
            beam_break_probability: 0.0,
            relock_after_ms: None,
            beam_break_before_measure: 0,
            beam_break_during_measure: 0,
            beam_break_status: 10004,
            disconnect_after_measurements: 0,
            no_reply: 0,
            not_warmed_up_ms: 0,
            initialize_delay_ms: 10,
        }
    }
}

/// `[sim.faults.robot]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotFaults {
    /// The N-th MOVEJ since start (1-based) is rejected with `reject_code` (0 = never).
    pub reject_move_n: u64,
    /// Error code of `reject_move_n`: `E_UNREACHABLE`, `E_LIMIT`, `E_BUSY`, `E_MODE`, …
    pub reject_code: String,
    /// An E-stop latches during the N-th move (1-based; 0 = never); clear it on the world.
    pub estop_after_moves: u64,
    /// Delay between the move's start and that E-stop (ms).
    pub estop_delay_ms: u64,
    /// The next N moves never settle (WAIT → E_TIMEOUT).
    pub never_settle: u32,
    /// The next N moves settle `slow_settle_extra_ms` late.
    pub slow_settle: u32,
    /// Extra settle time of `slow_settle` (ms).
    pub slow_settle_extra_ms: u64,
    /// After accepting the next N moves, the server drops the connection.
    pub disconnect_during_move: u32,
}

impl Default for RobotFaults {
    fn default() -> Self {
        RobotFaults {
            reject_move_n: 0,
            reject_code: "E_UNREACHABLE".into(),
            estop_after_moves: 0,
            estop_delay_ms: 5,
            never_settle: 0,
            slow_settle: 0,
            slow_settle_extra_ms: 200,
            disconnect_during_move: 0,
        }
    }
}

/// `[sim.faults.stage]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StageFaults {
    /// Reject the next N motion commands with `reject_reason`.
    pub reject: u32,
    /// Reason of `reject` (`BADCOMMAND`, `BADDATA`).
    pub reject_reason: String,
    /// The next N moves never finish (BUSY until stopped).
    pub stall: u32,
    /// The next N moves end in a fault flag (`FF`).
    pub fault: u32,
    /// The next N moves end off target (read-back ≠ target).
    pub overshoot: u32,
    /// The stage loses its home at the next command (WR).
    pub lose_home: u32,
    /// The next N moves away from 0 mm slip: the ball ends `slip_mm` further along the axis
    /// than the stage reports (the encoder does not see it).
    pub slip: u32,
    /// Size of a `slip` (mm).
    pub slip_mm: f64,
}

impl Default for StageFaults {
    fn default() -> Self {
        StageFaults {
            reject: 0,
            reject_reason: "BADCOMMAND".into(),
            stall: 0,
            fault: 0,
            overshoot: 0,
            lose_home: 0,
            slip: 0,
            slip_mm: 0.5,
        }
    }
}
