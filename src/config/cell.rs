//! The cell configuration file. See `config/cell.example.toml` for every key.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::auth::{Role, TokenDigest};
use crate::identify::{Nongeometric, NongeometricKeep, ObsModel};
use crate::measure::tool_frame::ToolFramePlanRequest;
use crate::model::checked_toml::parse_checked;
use crate::model::{SignedAxis, TermFamily};

use super::protocol::RobotProtocol;
pub use super::rules::InvalidKey;
use super::rules::{positive, rule};
use super::sim::SimWorldConfig;

/// Why a configuration could not be loaded (names the file and the key).
pub type ConfigError = crate::model::file::FileError;

/// Simulated device (started in-process from `[sim]`) or real device at an address.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceMode {
    /// Part of the simulated cell.
    Sim,
    /// A real device at the configured address or path.
    Real,
}

/// A real tracker's stationary measuring time when `[tracker] measure_ms` is unset (ms).
pub const REAL_MEASURE_MS: u32 = 1000;

/// `[tracker]`: the laser tracker and the measurement quality gate.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerSection {
    /// `sim` or `real`.
    pub mode: DeviceMode,
    /// emScon server address (real mode), e.g. `192.168.0.1:700`.
    pub address: String,
    /// Stationary measuring time (ms); unset: [`REAL_MEASURE_MS`] for a real tracker, the
    /// simulated cell's `[sim] measure_ms` for a simulated one ([`CellConfig::tracker_measure_ms`]).
    pub measure_ms: Option<u32>,
    /// Reflector id for SetReflector (emScon), if it must be set.
    pub reflector_id: Option<i32>,
    /// Quality gate: a point whose total standard deviation exceeds this is measured again (mm).
    pub max_std_total_mm: f64,
    /// Measurement attempts per point before the campaign pauses.
    pub max_attempts: u32,
    /// Tracker position in the robot base frame, for the line-of-sight check in planning (mm).
    pub position_mm: [f64; 3],
    /// Measure distances with the ADM (absolute distance meter).
    pub use_adm: bool,
    /// Status codes that mean "beam broken" (or "no target" for a search); unset: the emScon
    /// driver's set (10004, 10009, 10014).
    pub beam_break_codes: Option<Vec<i32>>,
    /// One extra site-specific beam-break status code (e.g. a newer server's "no target").
    pub beam_break_code: Option<i32>,
    /// Approximate distance given to FindReflector when re-locking (mm); unset: 3000 (the
    /// simulated cell: 2500).
    pub search_distance_mm: Option<f64>,
    /// TCP connect timeout (ms); unset: 5000 (the simulated cell: 2000).
    pub connect_timeout_ms: Option<u64>,
    /// Reply timeout of ordinary commands (ms); unset: 30000 (the simulated cell: 2000).
    pub command_timeout_ms: Option<u64>,
    /// Timeout of Initialize (ms); unset: 90000 (the simulated cell: 5000).
    pub initialize_timeout_ms: Option<u64>,
    /// Timeout of FindReflector and GoLastMeasuredPoint (ms); unset: 30000 (the simulated
    /// cell: 2000).
    pub search_timeout_ms: Option<u64>,
    /// Added to the measuring time to get a measurement's result timeout (ms); unset: 5000
    /// (the simulated cell: 2000).
    pub measure_margin_ms: Option<u64>,
}

impl Default for TrackerSection {
    fn default() -> Self {
        TrackerSection {
            mode: DeviceMode::Sim,
            address: "127.0.0.1:700".into(),
            measure_ms: None,
            reflector_id: None,
            max_std_total_mm: 0.05,
            max_attempts: 5,
            position_mm: [2550.0, 0.0, 0.0],
            use_adm: true,
            beam_break_codes: None,
            beam_break_code: None,
            search_distance_mm: None,
            connect_timeout_ms: None,
            command_timeout_ms: None,
            initialize_timeout_ms: None,
            search_timeout_ms: None,
            measure_margin_ms: None,
        }
    }
}

/// `[robot]`: the robot controller.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotSection {
    /// `sim` or `real`.
    pub mode: DeviceMode,
    /// `robotlink` (Stäubli, the default) or `ur` (Universal Robots).
    pub protocol: RobotProtocol,
    /// robotlink: server address (real mode), `host:port`; the controller application listens
    /// on [`robotlink::DEFAULT_PORT`] (11100) unless the site set another port on the pendant.
    /// ur: the controller's host (name or IP address, no port).
    pub address: String,
    /// ur: Dashboard server port; unset: 29999.
    pub dashboard_port: Option<u16>,
    /// ur: RTDE port; unset: 30004.
    pub rtde_port: Option<u16>,
    /// ur: URScript client interface port; unset: 30002 (secondary interface).
    pub script_port: Option<u16>,
    /// Speed (percent of the controller's maximum).
    pub speed_pct: f64,
    /// Time allowed for a move to settle (ms).
    pub settle_timeout_ms: u64,
    /// Attempts per move before the campaign pauses.
    pub max_attempts: u32,
    /// Largest accepted difference between a joint read after settling and its target (deg);
    /// beyond it the move is repeated (then the campaign pauses).
    pub settle_tolerance_deg: f64,
    /// File with the secret shared with the controller (64 hex digits; robotlink v3
    /// authentication), relative to this file; required for a real controller, optional for a
    /// simulated one (else a fresh random secret). Only the path is ever kept or shown.
    pub secret_file: Option<PathBuf>,
    /// TCP connect timeout (ms); unset: 5000 (the simulated cell: 2000).
    pub connect_timeout_ms: Option<u64>,
    /// Reply timeout of every request but WAIT (ms); unset: 5000 (the simulated cell: 2000).
    pub request_timeout_ms: Option<u64>,
    /// Extra client-side time granted to WAIT beyond `settle_timeout_ms` (ms); unset: 2000.
    pub wait_margin_ms: Option<u64>,
    /// Expected settling time after a move (ms), for the campaign time estimate only (the
    /// controller decides when the arm has settled); unset: 500 (the simulated cell: its
    /// `sim.settle_ms`).
    pub settle_ms: Option<u64>,
}

impl Default for RobotSection {
    fn default() -> Self {
        RobotSection {
            mode: DeviceMode::Sim,
            protocol: RobotProtocol::Robotlink,
            address: format!("127.0.0.1:{}", robotlink::DEFAULT_PORT),
            dashboard_port: None,
            rtde_port: None,
            script_port: None,
            speed_pct: 20.0,
            settle_timeout_ms: 60_000,
            max_attempts: 3,
            settle_tolerance_deg: 0.05,
            secret_file: None,
            connect_timeout_ms: None,
            request_timeout_ms: None,
            wait_margin_ms: None,
            settle_ms: None,
        }
    }
}

/// How the stage moves between P1 and P2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StageMode {
    /// A motorised Zaber stage on a serial line.
    Serial,
    /// A micrometer set by the technician, who types the reading.
    Manual,
    /// A micrometer set by the technician and read back over RS-232.
    ManualGauge,
}

/// `[stage]`: the 1D stage carrying the ball.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct StageSection {
    /// `sim` (simulated serial stage) or `real`.
    pub mode: DeviceMode,
    /// `serial`, `manual` or `manual_gauge`.
    pub kind: StageMode,
    /// Serial device of the stage (real serial mode).
    pub serial_path: String,
    /// Serial device of the gauge (real manual_gauge mode).
    pub gauge_path: String,
    /// Optional cross-check of the motorised stage's microsteps per mm: the driver derives the
    /// scale from the device (device.id, peripheral.id, resolution) and refuses to start when
    /// this differs by more than 0.01 %; for a product it does not know, this is the scale.
    pub microsteps_per_mm: Option<f64>,
    /// Stage position at P1 (mm).
    pub p1_mm: f64,
    /// Travel from P1 to P2 (mm).
    pub travel_mm: f64,
    /// Stage axis in the flange frame: `+x`, `-x`, `+y` or `-y`.
    pub axis: SignedAxis,
    /// Accepted difference between requested and read stage position (mm).
    pub tolerance_mm: f64,
    /// Usable range of the stage or micrometer, `[min, max]` (mm): P1 and P1 + travel must lie
    /// inside it, and the Zaber driver refuses targets outside it.
    pub range_mm: [f64; 2],
    /// After a manual stage answer, no robot motion until the technician confirms the cell
    /// clear (its own step); unset = on for manual stages. Only manual stages take it.
    pub confirm_clear: Option<bool>,
    /// Manual stages: how many times the technician is asked before the move fails.
    pub max_tries: u32,
    /// Zaber device address on the daisy chain (1..=99).
    pub device_address: u8,
    /// Zaber axis number of the stage on that device (1..=9).
    pub axis_number: u8,
    /// Zaber serial baud rate.
    pub baud: u32,
    /// Home the Zaber axis when the campaign prepares the devices.
    pub home_on_prepare: bool,
    /// Timeout of one Zaber reply (ms); unset: 500.
    pub reply_timeout_ms: Option<u64>,
    /// Zaber status poll period while a move runs (ms); unset: 20 (the simulated cell: 1).
    pub poll_interval_ms: Option<u64>,
    /// Timeout of a Zaber move (ms); unset: 30000 (the simulated cell: from its stage speed).
    pub move_timeout_ms: Option<u64>,
    /// Timeout of Zaber homing (ms); unset: 60000 (the simulated cell: from its stage speed).
    pub home_timeout_ms: Option<u64>,
    /// Speed of the motorised stage (mm/s), for the campaign time estimate only (the device
    /// moves at its own setting); unset: 5 (the simulated cell: its `sim.stage_speed_mm_s`).
    pub speed_mm_s: Option<f64>,
    /// Manual stages: the technician's time per reading (s): setting the micrometer, typing
    /// the reading and confirming the cell clear; for the campaign time estimate.
    pub technician_s_per_reading: f64,
}

impl Default for StageSection {
    fn default() -> Self {
        StageSection {
            mode: DeviceMode::Sim,
            kind: StageMode::Serial,
            serial_path: "/dev/ttyUSB0".into(),
            gauge_path: "/dev/ttyUSB1".into(),
            microsteps_per_mm: None,
            p1_mm: 0.0,
            travel_mm: 10.0,
            axis: SignedAxis::PLUS_Y,
            tolerance_mm: 0.02,
            range_mm: [0.0, 25.0],
            confirm_clear: None,
            max_tries: 3,
            device_address: 1,
            axis_number: 1,
            baud: 115_200,
            home_on_prepare: true,
            reply_timeout_ms: None,
            poll_interval_ms: None,
            move_timeout_ms: None,
            home_timeout_ms: None,
            speed_mm_s: None,
            technician_s_per_reading: 20.0,
        }
    }
}

impl StageSection {
    /// The stage axis as a unit vector in the flange frame.
    pub fn axis_vector(&self) -> Option<Vector3<f64>> {
        let named = self.axis.is_named_along(0) || self.axis.is_named_along(1);
        named.then(|| self.axis.unit())
    }

    /// Whether the technician confirms the cell clear before the robot moves after a manual
    /// stage answer (`confirm_clear`, on by default for manual stages).
    pub fn confirm_clear(&self) -> bool {
        self.kind != StageMode::Serial && self.confirm_clear.unwrap_or(true)
    }
}

/// `[campaign]`: defaults of a campaign.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct CampaignSection {
    /// Workspace box centre in the robot base frame (mm).
    pub box_center_mm: [f64; 3],
    /// Workspace box edge lengths (mm).
    pub box_size_mm: [f64; 3],
    /// Total poses.
    pub poses: usize,
    /// Identification poses (the rest verify).
    pub ident: usize,
    /// Planning seed.
    pub seed: u64,
    /// Observation model: `position`, `np`, `op` or `full`.
    pub model: ObsModel,
    /// Minimum wrist angle from the singular configuration (deg).
    pub wrist_min_deg: f64,
    /// Every frame origin above this height (mm).
    pub floor_z_mm: f64,
    /// How far beyond the box a move may sweep the flange and the ball (mm).
    pub path_margin_mm: f64,
    /// Maximum angle between the ball's opening (flange +z) and the line to the tracker (deg).
    pub line_of_sight_max_deg: f64,
    /// Measure the drift reference pose every N poses (0 = only at start and end).
    pub drift_every: usize,
    /// Drift that pauses the campaign (mm).
    pub drift_max_mm: f64,
    /// Identify the base transform (the tracker frame is not the robot base frame).
    pub identify_base: bool,
    /// Identify the ball position in the flange.
    pub identify_tool: bool,
    /// Known ball position in the flange frame (mm).
    pub tool_mm: [f64; 3],
    /// How the identification poses are chosen: `random` (the first drawn) or `optimal`
    /// (I-optimal selection from a pool of measurable poses; docs/method.md §9). The
    /// verification poses are random either way.
    pub selection: crate::plan::selection::Selection,
    /// When the campaign stops measuring identification poses.
    pub stop_when: StopWhen,
    /// With `stop_when = "predicted"`: stop once the predicted verification error improves by
    /// less than this fraction from one block of identification poses to the next.
    pub stop_min_gain: f64,
    /// With `stop_when = "predicted"`: stop once the identification poses still planned would,
    /// all together, improve the predicted verification error by less than this fraction.
    pub stop_remaining_gain: f64,
    /// With `stop_when = "predicted"`: stop once the predicted verification error (mm) is at or
    /// below this; unset: only `stop_min_gain` stops.
    pub target_verify_mm: Option<f64>,
    /// With `stop_when = "predicted"`: identification poses per block (an identification after
    /// each); unset: [`CampaignSection::stop_block_for`].
    pub stop_block: Option<usize>,
    /// Families of non-geometric joint terms identified with the MDH errors (§10: `compliance`,
    /// `harmonics`, each at most once); empty: a geometric identification.
    pub nongeometric: Vec<TermFamily>,
    /// With terms, the model handed over: `extended` (always the one with the terms) or
    /// `better` (the one with the lower verification position RMS).
    pub nongeometric_keep: NongeometricKeep,
    /// What a verification pose measures: `p1_p2` (the position and the flange axis, as the
    /// identification poses) or `p1` (the position only).
    pub verify_readings: VerifyReadings,
}

/// `campaign.verify_readings`: the readings taken at each verification pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
pub enum VerifyReadings {
    /// P1 and P2: the position and one flange axis, as at the identification poses.
    #[default]
    #[serde(rename = "p1_p2")]
    P1P2,
    /// P1 only: the position, which is what the verification figures are (the axis error of
    /// the verification set is then not measured); one reading and no stage move per pose.
    #[serde(rename = "p1")]
    P1,
}

/// `campaign.stop_when`: measure every planned identification pose, or stop once the
/// predicted verification error says more would not help.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopWhen {
    /// Every planned pose is measured.
    #[default]
    Planned,
    /// Identify after each block of identification poses; stop measuring them once the
    /// predicted verification error gains less than `stop_min_gain` or reaches
    /// `target_verify_mm` (the verification poses are always measured).
    Predicted,
}

/// Default of `campaign.stop_min_gain`: a block that improves the predicted verification error
/// by less than 2 % stops the identification poses.
pub const DEFAULT_STOP_MIN_GAIN: f64 = 0.02;

/// Default of `campaign.stop_remaining_gain`: once every identification pose still planned
/// would improve the predicted verification error by less than 5 %, they are not measured.
pub const DEFAULT_STOP_REMAINING_GAIN: f64 = 0.05;

impl Default for CampaignSection {
    fn default() -> Self {
        CampaignSection {
            box_center_mm: [550.0, 0.0, 550.0],
            box_size_mm: [1000.0, 1000.0, 1000.0],
            poses: 300,
            ident: 100,
            seed: 4802,
            model: ObsModel::Op,
            wrist_min_deg: 10.0,
            floor_z_mm: -300.0,
            path_margin_mm: 100.0,
            line_of_sight_max_deg: 180.0,
            drift_every: 50,
            drift_max_mm: 0.1,
            identify_base: true,
            identify_tool: false,
            tool_mm: [0.0, 0.0, 0.0],
            selection: crate::plan::selection::Selection::Random,
            stop_when: StopWhen::Planned,
            stop_min_gain: DEFAULT_STOP_MIN_GAIN,
            stop_remaining_gain: DEFAULT_STOP_REMAINING_GAIN,
            target_verify_mm: None,
            stop_block: None,
            nongeometric: Vec::new(),
            nongeometric_keep: NongeometricKeep::Extended,
            verify_readings: VerifyReadings::P1P2,
        }
    }
}

/// `[setup]`: the cell setup steps run once per campaign before the first pose.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SetupSection {
    /// Run the tool-frame procedure of docs/method.md §4 (jogs along flange x/y, rotations about them,
    /// sphere fit): the measured ball position and stage axis replace `campaign.tool_mm` and
    /// `stage.axis` in the identification.
    pub tool_frame: bool,
    /// Register tracker ← robot base from `base_poses` spread poses on the nominal model (a
    /// check of the mounting; the fixed base of the identification when
    /// `campaign.identify_base = false`).
    pub base_registration: bool,
    /// Home pose of the tool-frame procedure (deg); default: the campaign's drift reference
    /// (the planned pose nearest the box centre).
    pub home_deg: Option<Vec<f64>>,
    /// Jog distance along flange x and y (mm).
    pub jog_mm: f64,
    /// Rotations about flange x and about flange y (deg); at least two, none zero.
    pub angles_deg: Vec<f64>,
    /// P1/P2 pairs measured at home for the stage axis.
    pub home_pairs: usize,
    /// Poses of the base registration.
    pub base_poses: usize,
    /// Largest accepted RMS of the sphere fit (mm); above it the campaign pauses.
    pub max_sphere_rms_mm: f64,
    /// Largest accepted RMS of the base registration (mm); above it the campaign pauses.
    pub max_base_rms_mm: f64,
}

impl Default for SetupSection {
    fn default() -> Self {
        SetupSection {
            tool_frame: true,
            base_registration: true,
            home_deg: None,
            jog_mm: 25.0,
            angles_deg: vec![-28.0, -14.0, 14.0, 28.0],
            home_pairs: 3,
            base_poses: 6,
            max_sphere_rms_mm: 0.1,
            max_base_rms_mm: 3.0,
        }
    }
}

/// `[iso9283]`: when present, `cellcal run` measures an ISO 9283 pose accuracy and
/// repeatability campaign (five poses on the cube's diagonal plane, `cycles` cycles) instead of
/// a calibration campaign.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Iso9283Section {
    /// Cycles (ISO 9283: 30; at least 2).
    pub cycles: usize,
    /// Distance of P2…P5 from the cube's corners along the diagonals (fraction of the
    /// diagonal, ISO: 0.1).
    pub diagonal_fraction: f64,
    /// Direction of the last motion into every pose, robot base frame: `+x`, `-x`, `+y`, `-y`,
    /// `+z` or `-z` (`-z`: from above).
    pub approach: SignedAxis,
    /// Length of that last motion from the pre-pose (mm).
    pub approach_mm: f64,
    /// Robot speed of the campaign (percent; ISO uses 100, 50 and 10 % of rated speed); unset:
    /// `robot_controller.speed_pct`.
    pub speed_pct: Option<f64>,
    /// Measure P2 too at every visit (the stage-axis direction figures).
    pub measure_axis: bool,
    /// A corrected robot model (`--model-out`): the joints then come from compensation.
    pub compensated_model: Option<PathBuf>,
    /// Cube centre (mm, robot base frame); unset: `campaign.box_center_mm`.
    pub cube_center_mm: Option<[f64; 3]>,
    /// Cube edge (mm); unset: the smallest edge of the campaign box.
    pub cube_edge_mm: Option<f64>,
    /// Flange orientation at every pose, rotation vector (deg, robot base frame); unset: the
    /// orientation at the drift reference (the hub).
    pub orientation_deg: Option<[f64; 3]>,
}

impl Default for Iso9283Section {
    fn default() -> Self {
        Iso9283Section {
            cycles: 30,
            diagonal_fraction: 0.1,
            approach: SignedAxis::MINUS_Z,
            approach_mm: 50.0,
            speed_pct: None,
            measure_axis: true,
            compensated_model: None,
            cube_center_mm: None,
            cube_edge_mm: None,
            orientation_deg: None,
        }
    }
}

impl Iso9283Section {
    /// The approach direction as a unit vector (robot base frame).
    pub fn approach_vector(&self) -> Option<Vector3<f64>> {
        self.approach.name().map(|_| self.approach.unit())
    }

    /// The ISO rules: at least 2 cycles, a fraction in (0, 0.5), a known approach axis, a
    /// positive approach length and cube edge, a speed in (0, 100] %.
    pub fn check(&self) -> Result<(), InvalidKey> {
        rule(
            self.cycles >= 2 && self.cycles <= MAX_POSES / 5,
            "iso9283.cycles",
            format!(
                "must be between 2 and {}, got {}",
                MAX_POSES / 5,
                self.cycles
            ),
        )?;
        rule(
            self.diagonal_fraction > 0.0 && self.diagonal_fraction < 0.5,
            "iso9283.diagonal_fraction",
            format!("must be in (0, 0.5), got {}", self.diagonal_fraction),
        )?;
        rule(
            self.approach_vector().is_some(),
            "iso9283.approach",
            format!("`{}` is not one of +x, -x, +y, -y, +z, -z", self.approach),
        )?;
        positive("iso9283.approach_mm", self.approach_mm)?;
        if let Some(e) = self.cube_edge_mm {
            positive("iso9283.cube_edge_mm", e)?;
        }
        if let Some(v) = self.speed_pct {
            rule(
                v > 0.0 && v <= 100.0,
                "iso9283.speed_pct",
                format!("must be in (0, 100], got {v}"),
            )?;
        }
        Ok(())
    }
}

/// One `[[api.tokens]]` entry as written in the file.
#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct ApiTokenFile {
    name: String,
    role: Role,
    sha256: String,
}

/// `[api]` as written in the file.
#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
struct ApiFile {
    tokens: Vec<ApiTokenFile>,
    tls_cert: Option<PathBuf>,
    tls_key: Option<PathBuf>,
    allowed_hosts: Vec<String>,
    allowed_origins: Vec<String>,
}

/// A REST API token the configuration accepts: who holds it, its role, its SHA-256 digest.
#[derive(Debug, Clone, PartialEq)]
pub struct ApiToken {
    /// Who holds the token (shown in refusals, never the token).
    pub name: String,
    /// What the holder may do.
    pub role: Role,
    /// SHA-256 of the token (the token itself is never stored).
    pub digest: TokenDigest,
}

/// `[api]`: who may use the REST API of `cellcal serve`, and how it is served.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ApiSection {
    /// Accepted tokens; none = `serve` makes a one-time operator token (loopback only).
    pub tokens: Vec<ApiToken>,
    /// TLS certificate chain and private key (PEM, resolved), when served over HTTPS.
    pub tls: Option<(PathBuf, PathBuf)>,
    /// Extra `Host` names the daemon answers to (`name` or `name:port`).
    pub allowed_hosts: Vec<String>,
    /// Extra origins (`scheme://host[:port]`) whose browser requests are accepted.
    pub allowed_origins: Vec<String>,
}

/// Validate `[api]`; `invalid` names the file, `resolve` anchors relative paths.
fn api_section(
    f: ApiFile,
    invalid: impl Fn(&str, String) -> ConfigError,
    resolve: impl Fn(PathBuf) -> PathBuf,
) -> Result<ApiSection, ConfigError> {
    let mut tokens: Vec<ApiToken> = Vec::with_capacity(f.tokens.len());
    for (i, t) in f.tokens.into_iter().enumerate() {
        if t.name.trim().is_empty() {
            return Err(invalid(
                &format!("api.tokens[{i}].name"),
                "must not be empty".into(),
            ));
        }
        if tokens.iter().any(|o| o.name == t.name) {
            return Err(invalid(
                &format!("api.tokens[{i}].name"),
                format!("`{}` is used twice", t.name),
            ));
        }
        let digest = TokenDigest::from_hex(&t.sha256)
            .map_err(|e| invalid(&format!("api.tokens[{i}].sha256"), e.to_string()))?;
        tokens.push(ApiToken {
            name: t.name,
            role: t.role,
            digest,
        });
    }
    let tls = match (f.tls_cert, f.tls_key) {
        (Some(c), Some(k)) => Some((resolve(c), resolve(k))),
        (None, None) => None,
        (Some(_), None) => return Err(invalid("api.tls_key", "missing: tls_cert needs it".into())),
        (None, Some(_)) => return Err(invalid("api.tls_cert", "missing: tls_key needs it".into())),
    };
    if let Some(h) = f
        .allowed_hosts
        .iter()
        .find(|h| h.is_empty() || h.contains(['/', '@', ' ']))
    {
        return Err(invalid(
            "api.allowed_hosts",
            format!("`{h}` is not a host name (`name` or `name:port`)"),
        ));
    }
    if let Some(o) = f.allowed_origins.iter().find(|o| !is_origin(o)) {
        return Err(invalid(
            "api.allowed_origins",
            format!("`{o}` is not an origin (`http://host[:port]` or `https://host[:port]`)"),
        ));
    }
    Ok(ApiSection {
        tokens,
        tls,
        allowed_hosts: f.allowed_hosts,
        allowed_origins: f.allowed_origins,
    })
}

/// Whether `s` is `http://host[:port]` or `https://host[:port]` (no path).
fn is_origin(s: &str) -> bool {
    let rest = s
        .strip_prefix("http://")
        .or_else(|| s.strip_prefix("https://"));
    rest.is_some_and(|r| !r.is_empty() && !r.contains(['/', '@', ' ']))
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct CellFile {
    robot: Option<PathBuf>,
    store: Option<PathBuf>,
    lock_dir: Option<PathBuf>,
    #[serde(default)]
    tracker: TrackerSection,
    #[serde(default, rename = "robot_controller")]
    robot_controller: RobotSection,
    #[serde(default)]
    stage: StageSection,
    #[serde(default)]
    campaign: CampaignSection,
    #[serde(default)]
    setup: SetupSection,
    #[serde(default)]
    api: ApiFile,
    iso9283: Option<Iso9283Section>,
    sim: Option<SimWorldConfig>,
}

/// The whole cell configuration.
#[derive(Debug, Clone)]
pub struct CellConfig {
    /// The file it came from.
    pub path: PathBuf,
    /// The raw file text (stored with each campaign).
    pub text: String,
    /// Robot model file (resolved).
    pub robot: PathBuf,
    /// SQLite store (resolved).
    pub store: PathBuf,
    /// Directory of the host-wide cell locks (resolved; see
    /// [`crate::campaign::cell_lock::lock_dir`]).
    pub lock_dir: Option<PathBuf>,
    /// Tracker.
    pub tracker: TrackerSection,
    /// Robot controller.
    pub robot_controller: RobotSection,
    /// Stage.
    pub stage: StageSection,
    /// Campaign defaults.
    pub campaign: CampaignSection,
    /// Setup steps.
    pub setup: SetupSection,
    /// REST API access (`[api]`).
    pub api: ApiSection,
    /// An ISO 9283 campaign instead of a calibration (`[iso9283]`, paths resolved).
    pub iso9283: Option<Iso9283Section>,
    /// The simulated world (`[sim]`, checked, its `errors` file resolved, its stage kind and
    /// Zaber address those of `[stage]`): set when any device is simulated or the table is
    /// given.
    pub sim: Option<SimWorldConfig>,
}

impl CellConfig {
    /// The configured observation model.
    pub fn model(&self) -> ObsModel {
        self.campaign.model
    }

    /// Which planned poses the engine measures at P2 too: every one unless an ISO 9283 run
    /// says `measure_axis = false`; a verification pose only with `verify_readings = "p1_p2"`.
    pub fn axis_readings(&self) -> crate::plan::timing::AxisReadings {
        let axis = self.iso9283.as_ref().is_none_or(|i| i.measure_axis);
        crate::plan::timing::AxisReadings {
            ident: axis,
            verify: axis && self.campaign.verify_readings == VerifyReadings::P1P2,
        }
    }

    /// The tracker's stationary measuring time (ms): `[tracker] measure_ms` when given, else
    /// the simulated cell's `[sim] measure_ms` (its fast or realistic default) for a simulated
    /// tracker and [`REAL_MEASURE_MS`] for a real one.
    pub fn tracker_measure_ms(&self) -> u32 {
        match (self.tracker.measure_ms, self.tracker.mode) {
            (Some(ms), _) => ms,
            (None, DeviceMode::Sim) => {
                let sim = self.sim.clone().unwrap_or_default();
                u32::try_from(sim.effective_measure_ms()).unwrap_or(u32::MAX)
            }
            (None, DeviceMode::Real) => REAL_MEASURE_MS,
        }
    }

    /// Whether any device is simulated.
    pub fn any_simulated(&self) -> bool {
        self.tracker.mode == DeviceMode::Sim
            || self.robot_controller.mode == DeviceMode::Sim
            || self.stage.mode == DeviceMode::Sim
    }
}

/// Load and validate a cell configuration file.
pub fn load_cell_config(path: &Path) -> Result<CellConfig, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|cause| ConfigError::Read {
        path: path.to_owned(),
        cause,
    })?;
    parse_cell_config(&text, path)
}

/// Parse and validate configuration text; `path` names the file in errors and anchors
/// relative paths. Every number in the file (the `[sim]` table included) is finite and every
/// array has its exact length ([`parse_checked`]); then each section's rules apply.
pub fn parse_cell_config(text: &str, path: &Path) -> Result<CellConfig, ConfigError> {
    let f: CellFile = parse_checked(text, path)?;
    let invalid = |e: InvalidKey| ConfigError::Invalid {
        path: path.to_owned(),
        key: e.key,
        message: e.message,
    };
    f.tracker.check().map_err(invalid)?;
    f.robot_controller.check().map_err(invalid)?;
    f.stage.check().map_err(invalid)?;
    f.campaign.check().map_err(invalid)?;
    f.setup.check().map_err(invalid)?;
    if let Some(iso) = &f.iso9283 {
        iso.check().map_err(invalid)?;
        rule(
            f.setup.base_registration || iso.compensated_model.is_some(),
            "iso9283",
            "the figures are given in the robot base frame: needs setup.base_registration = true \
             (or a compensated_model, whose base is used)",
        )
        .map_err(invalid)?;
        rule(
            f.campaign.stop_when == StopWhen::Planned,
            "campaign.stop_when",
            "an ISO 9283 campaign measures every planned visit: \"predicted\" applies to \
             calibration campaigns only",
        )
        .map_err(invalid)?;
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let resolve = |p: PathBuf| if p.is_absolute() { p } else { dir.join(p) };
    let simulated =
        [f.tracker.mode, f.robot_controller.mode, f.stage.mode].contains(&DeviceMode::Sim);
    let sim = match f.sim {
        Some(s) => Some(s),
        None if simulated => Some(SimWorldConfig::default()),
        None => None,
    }
    .map(|s| simulated_world(s, &f.stage, f.robot_controller.protocol, path))
    .transpose()?;
    let iso9283 = f.iso9283.map(|i| Iso9283Section {
        compensated_model: i.compensated_model.map(resolve),
        ..i
    });
    let api = api_section(
        f.api,
        |key: &str, message: String| ConfigError::Invalid {
            path: path.to_owned(),
            key: key.to_owned(),
            message,
        },
        resolve,
    )?;
    Ok(CellConfig {
        path: path.to_owned(),
        text: text.to_owned(),
        robot: resolve(
            f.robot
                .unwrap_or_else(|| PathBuf::from("robots/staubli_tx60.toml")),
        ),
        store: resolve(f.store.unwrap_or_else(|| PathBuf::from("cellcal.db"))),
        lock_dir: f.lock_dir.map(resolve),
        tracker: f.tracker,
        robot_controller: RobotSection {
            secret_file: f.robot_controller.secret_file.clone().map(resolve),
            ..f.robot_controller
        },
        stage: f.stage,
        campaign: f.campaign,
        setup: f.setup,
        api,
        iso9283,
        sim,
    })
}

/// Parse the `[sim]` table of a cell configuration with its `[stage]` (`cellcal sim`: the
/// simulated stage follows `stage.kind` and the Zaber address as in [`parse_cell_config`]; the
/// other tables are not read, but every number of the file is finite) with the rules of
/// [`parse_cell_config`].
pub fn parse_sim_config(text: &str, path: &Path) -> Result<SimWorldConfig, ConfigError> {
    /// The part of a cell configuration file that `cellcal sim` reads.
    #[derive(Deserialize, Serialize)]
    struct SimFile {
        #[serde(default)]
        stage: StageSection,
        #[serde(default)]
        sim: SimWorldConfig,
        #[serde(default)]
        robot_controller: RobotSection,
    }
    let f: SimFile = parse_checked(text, path)?;
    f.stage.check().map_err(|e| ConfigError::Invalid {
        path: path.to_owned(),
        key: e.key,
        message: e.message,
    })?;
    simulated_world(f.sim, &f.stage, f.robot_controller.protocol, path)
}

/// The checked `[sim]` world of the cell: its rules, its `errors` file resolved against the
/// configuration's folder, the stage kind and Zaber address of `[stage]` (one stage), and a
/// simulated Zaber stage that can reach `stage.range_mm`.
fn simulated_world(
    mut sim: SimWorldConfig,
    stage: &StageSection,
    protocol: RobotProtocol,
    path: &Path,
) -> Result<SimWorldConfig, ConfigError> {
    let invalid = |e: InvalidKey| ConfigError::Invalid {
        path: path.to_owned(),
        key: e.key,
        message: e.message,
    };
    sim.check().map_err(invalid)?;
    rule(
        sim.robot_protocol.is_none_or(|p| p == protocol),
        "sim.robot_protocol",
        format!(
            "contradicts robot_controller.protocol = \"{}\": the simulated controller follows \
             [robot_controller]; delete sim.robot_protocol",
            protocol.name()
        ),
    )
    .map_err(invalid)?;
    sim.robot_protocol = Some(protocol);
    if !matches!(sim.errors.as_str(), "paper" | "random" | "none" | "") {
        let dir = path.parent().unwrap_or(Path::new("."));
        sim.errors = dir.join(&sim.errors).to_string_lossy().into_owned();
    }
    sim.stage_address = (stage.device_address, stage.axis_number);
    if stage.kind == StageMode::Serial {
        rule(
            sim.stage_mode == super::sim::StageMode::Zaber,
            "sim.stage_mode",
            "`manual` contradicts stage.kind = \"serial\": the simulated stage follows [stage]. \
             For a manual stage set stage.kind = \"manual\" (or \"manual_gauge\") and delete \
             sim.stage_mode; for a Zaber stage delete sim.stage_mode",
        )
        .map_err(invalid)?;
        if stage.mode == DeviceMode::Sim {
            let [lo, hi] = stage.range_mm;
            rule(
                lo >= 0.0 && hi <= sim.stage_max_mm,
                "stage.range_mm",
                format!(
                    "[{lo}, {hi}] mm is beyond the simulated stage's travel [0, {}] mm \
                     (sim.stage_max_mm)",
                    sim.stage_max_mm
                ),
            )
            .map_err(invalid)?;
        }
    } else {
        // a manual stage: the simulated micrometer follows the technician's answers
        sim.stage_mode = super::sim::StageMode::Manual;
    }
    Ok(sim)
}

/// Longest device timeout or time a key may give (ms): one day.
pub const MAX_DEVICE_MS: u64 = 86_400_000;

/// A device time in ms, when set: above zero (a zero timeout fails every call) and at most
/// [`MAX_DEVICE_MS`]. (NaN, inf, fractions and negative values are refused by the parser.)
fn device_ms(key: &str, v: Option<u64>) -> Result<(), InvalidKey> {
    match v {
        Some(ms) => rule(
            ms > 0 && ms <= MAX_DEVICE_MS,
            key,
            format!("must be in 1..={MAX_DEVICE_MS} ms, got {ms}"),
        ),
        None => Ok(()),
    }
}

impl TrackerSection {
    /// The tracker rules: measuring time, quality gate and attempts above zero; a search
    /// distance above zero; device times in 1..=[`MAX_DEVICE_MS`] ms; a beam-break code list
    /// that is not empty.
    pub fn check(&self) -> Result<(), InvalidKey> {
        if let Some(ms) = self.measure_ms {
            rule(
                ms > 0 && u64::from(ms) <= MAX_DEVICE_MS,
                "tracker.measure_ms",
                format!("must be in 1..={MAX_DEVICE_MS} ms, got {ms}"),
            )?;
        }
        positive("tracker.max_std_total_mm", self.max_std_total_mm)?;
        rule(
            self.max_attempts > 0,
            "tracker.max_attempts",
            "must be at least 1",
        )?;
        if let Some(d) = self.search_distance_mm {
            positive("tracker.search_distance_mm", d)?;
        }
        rule(
            self.beam_break_codes.as_ref().is_none_or(|c| !c.is_empty()),
            "tracker.beam_break_codes",
            "must list at least one code (unset: the driver's 10004, 10009, 10014)",
        )?;
        for (key, v) in [
            ("tracker.connect_timeout_ms", self.connect_timeout_ms),
            ("tracker.command_timeout_ms", self.command_timeout_ms),
            ("tracker.initialize_timeout_ms", self.initialize_timeout_ms),
            ("tracker.search_timeout_ms", self.search_timeout_ms),
            ("tracker.measure_margin_ms", self.measure_margin_ms),
        ] {
            device_ms(key, v)?;
        }
        Ok(())
    }
}

impl RobotSection {
    /// The robot controller rules: speed in (0, 100] %, attempts and settle tolerance above
    /// zero, device times in 1..=[`MAX_DEVICE_MS`] ms.
    pub fn check(&self) -> Result<(), InvalidKey> {
        rule(
            self.speed_pct > 0.0 && self.speed_pct <= 100.0,
            "robot_controller.speed_pct",
            format!("must be in (0, 100], got {}", self.speed_pct),
        )?;
        rule(
            self.settle_timeout_ms > 0,
            "robot_controller.settle_timeout_ms",
            "must be positive",
        )?;
        rule(
            self.max_attempts > 0,
            "robot_controller.max_attempts",
            "must be at least 1",
        )?;
        rule(
            self.settle_tolerance_deg > 0.0,
            "robot_controller.settle_tolerance_deg",
            "must be positive",
        )?;
        device_ms(
            "robot_controller.settle_timeout_ms",
            Some(self.settle_timeout_ms),
        )?;
        for (key, v) in [
            (
                "robot_controller.connect_timeout_ms",
                self.connect_timeout_ms,
            ),
            (
                "robot_controller.request_timeout_ms",
                self.request_timeout_ms,
            ),
            ("robot_controller.wait_margin_ms", self.wait_margin_ms),
        ] {
            device_ms(key, v)?;
        }
        if let Some(ms) = self.settle_ms {
            rule(
                ms <= MAX_DEVICE_MS,
                "robot_controller.settle_ms",
                format!("must be in 0..={MAX_DEVICE_MS} ms, got {ms}"),
            )?;
        }
        for (key, port) in [
            ("robot_controller.dashboard_port", self.dashboard_port),
            ("robot_controller.rtde_port", self.rtde_port),
            ("robot_controller.script_port", self.script_port),
        ] {
            if let Some(p) = port {
                rule(
                    self.protocol == RobotProtocol::Ur,
                    key,
                    "only a UR controller (protocol = \"ur\") takes it",
                )?;
                rule(p > 0, key, "must be in 1..=65535")?;
            }
        }
        if self.protocol == RobotProtocol::Ur {
            rule(
                self.secret_file.is_none(),
                "robot_controller.secret_file",
                "a UR controller (protocol = \"ur\") has no shared secret: remove the key",
            )?;
            if self.mode == DeviceMode::Real {
                rule(
                    !self.address.trim().is_empty()
                        && self.address.parse::<std::net::SocketAddr>().is_err()
                        && !self.address.contains(' '),
                    "robot_controller.address",
                    format!(
                        "a UR controller's host (name or IP address, no port; ports are \
                         dashboard_port, rtde_port, script_port), got {:?}",
                        self.address
                    ),
                )?;
            }
        }
        Ok(())
    }
}

impl StageSection {
    /// The stage rules: a known axis, positive scale, travel and tolerance, a tolerance below
    /// half the travel (else a stage that did not move passes), `range_mm` = [min, max]
    /// with min < max, at least one try, a Zaber address 1..=99 and axis 1..=9, device times
    /// in 1..=[`MAX_DEVICE_MS`] ms. Whether P1 and P2 lie in the range is a campaign feasibility check.
    pub fn check(&self) -> Result<(), InvalidKey> {
        rule(
            self.axis_vector().is_some(),
            "stage.axis",
            format!("`{}` is not one of +x, -x, +y, -y", self.axis),
        )?;
        if let Some(v) = self.microsteps_per_mm {
            positive("stage.microsteps_per_mm", v)?;
        }
        positive("stage.travel_mm", self.travel_mm)?;
        positive("stage.tolerance_mm", self.tolerance_mm)?;
        rule(
            self.tolerance_mm < 0.5 * self.travel_mm,
            "stage.tolerance_mm",
            format!(
                "must be below half of stage.travel_mm ({} mm), got {}",
                self.travel_mm, self.tolerance_mm
            ),
        )?;
        rule(
            !(self.kind == StageMode::Serial && self.confirm_clear == Some(true)),
            "stage.confirm_clear",
            "applies to manual stages only (nobody's hand is at a motorised stage)",
        )?;
        let [lo, hi] = self.range_mm;
        rule(
            lo < hi,
            "stage.range_mm",
            format!("must be [min, max] with min < max, got [{lo}, {hi}]"),
        )?;
        rule(self.max_tries > 0, "stage.max_tries", "must be at least 1")?;
        rule(
            (1..=99).contains(&self.device_address),
            "stage.device_address",
            format!("must be in 1..=99, got {}", self.device_address),
        )?;
        rule(
            (1..=9).contains(&self.axis_number),
            "stage.axis_number",
            format!("must be in 1..=9, got {}", self.axis_number),
        )?;
        rule(self.baud > 0, "stage.baud", "must be positive")?;
        for (key, v) in [
            ("stage.reply_timeout_ms", self.reply_timeout_ms),
            ("stage.poll_interval_ms", self.poll_interval_ms),
            ("stage.move_timeout_ms", self.move_timeout_ms),
            ("stage.home_timeout_ms", self.home_timeout_ms),
        ] {
            device_ms(key, v)?;
        }
        if let Some(v) = self.speed_mm_s {
            positive("stage.speed_mm_s", v)?;
        }
        rule(
            self.technician_s_per_reading >= 0.0,
            "stage.technician_s_per_reading",
            format!(
                "must be zero or more seconds, got {}",
                self.technician_s_per_reading
            ),
        )?;
        Ok(())
    }
}

/// Most poses a campaign may plan.
pub const MAX_POSES: usize = 100_000;

impl CampaignSection {
    /// The campaign rules: a known model, 1 ≤ ident < poses ≤ [`MAX_POSES`], a box of positive
    /// size, wrist margin in [0, 90)°, line-of-sight angle in (0, 180]°, drift limit above
    /// zero. The daemon applies the same rules to its overrides.
    pub fn check(&self) -> Result<(), InvalidKey> {
        rule(
            self.poses <= MAX_POSES,
            "campaign.poses",
            format!("at most {MAX_POSES}, got {}", self.poses),
        )?;
        rule(
            self.ident > 0 && self.ident < self.poses,
            "campaign.ident",
            format!(
                "must be between 1 and poses − 1 ({}), got {}",
                self.poses.saturating_sub(1),
                self.ident
            ),
        )?;
        for (k, v) in self.box_size_mm.iter().enumerate() {
            positive(&format!("campaign.box_size_mm[{k}]"), *v)?;
        }
        rule(
            (0.0..90.0).contains(&self.wrist_min_deg),
            "campaign.wrist_min_deg",
            format!("must be in [0, 90), got {}", self.wrist_min_deg),
        )?;
        rule(
            self.path_margin_mm >= 0.0,
            "campaign.path_margin_mm",
            format!("must be a non-negative number, got {}", self.path_margin_mm),
        )?;
        rule(
            self.line_of_sight_max_deg > 0.0 && self.line_of_sight_max_deg <= 180.0,
            "campaign.line_of_sight_max_deg",
            format!("must be in (0, 180], got {}", self.line_of_sight_max_deg),
        )?;
        positive("campaign.drift_max_mm", self.drift_max_mm)?;
        rule(
            (0.0..1.0).contains(&self.stop_min_gain),
            "campaign.stop_min_gain",
            format!("must be a fraction in [0, 1), got {}", self.stop_min_gain),
        )?;
        rule(
            (0.0..1.0).contains(&self.stop_remaining_gain),
            "campaign.stop_remaining_gain",
            format!(
                "must be a fraction in [0, 1), got {}",
                self.stop_remaining_gain
            ),
        )?;
        if let Some(t) = self.target_verify_mm {
            positive("campaign.target_verify_mm", t)?;
        }
        if let Some(b) = self.stop_block {
            rule(
                b >= 1 && b <= self.ident,
                "campaign.stop_block",
                format!(
                    "must be between 1 and campaign.ident ({}), got {b}",
                    self.ident
                ),
            )?;
        }
        for (i, f) in self.nongeometric.iter().enumerate() {
            rule(
                !self.nongeometric[..i].contains(f),
                "campaign.nongeometric",
                format!("`{f}` is given twice"),
            )?;
        }
        Ok(())
    }

    /// The non-geometric terms a campaign identifies with ([`Nongeometric`]): the families of
    /// `nongeometric` and the model `nongeometric_keep` hands over.
    pub fn nongeometric_terms(&self) -> Nongeometric {
        Nongeometric {
            keep: self.nongeometric_keep,
            ..Nongeometric::of(&self.nongeometric)
        }
    }

    /// Identification poses per block of the stop rule: `stop_block`, or else the fewest poses
    /// whose independent observations are at least the `candidates` parameters (the first
    /// check comes as soon as the identification can be determined, and the rule looks again
    /// as often), at most `ident`.
    pub fn stop_block_for(&self, candidates: usize) -> usize {
        self.stop_block.unwrap_or_else(|| {
            let per_pose = self.model.observations();
            candidates.div_ceil(per_pose).clamp(1, self.ident.max(1))
        })
    }
}

impl SetupSection {
    /// The tool-frame plan request these settings describe (angles in rad).
    pub fn tool_frame_request(&self) -> ToolFramePlanRequest {
        ToolFramePlanRequest {
            jog_mm: self.jog_mm,
            angles_rad: self.angles_deg.iter().map(|d| d.to_radians()).collect(),
            home_pairs: self.home_pairs,
            ..ToolFramePlanRequest::default()
        }
    }

    /// The setup rules: positive jog, at least two non-zero rotations within ±90°, at least
    /// one home pair, at least three registration poses, RMS limits above zero. Whether
    /// `home_deg` fits the robot is a campaign feasibility check.
    pub fn check(&self) -> Result<(), InvalidKey> {
        positive("setup.jog_mm", self.jog_mm)?;
        rule(
            self.angles_deg.len() >= 2
                && self.angles_deg.iter().all(|a| *a != 0.0 && a.abs() <= 90.0),
            "setup.angles_deg",
            "needs at least two non-zero angles within ±90°",
        )?;
        rule(
            self.home_pairs > 0,
            "setup.home_pairs",
            "must be at least 1",
        )?;
        rule(
            !self.base_registration || self.base_poses >= 3,
            "setup.base_poses",
            "must be at least 3",
        )?;
        positive("setup.max_sphere_rms_mm", self.max_sphere_rms_mm)?;
        positive("setup.max_base_rms_mm", self.max_base_rms_mm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nongeometric_keys_default_to_none_reach_the_identification_and_bad_ones_are_named() {
        let p = Path::new("c.toml");
        let c = parse_cell_config("", p).unwrap().campaign;
        assert!(c.nongeometric.is_empty());
        assert_eq!(c.nongeometric_keep, NongeometricKeep::Extended);
        assert_eq!(c.nongeometric_terms(), Nongeometric::default());
        let c = parse_cell_config(
            "[campaign]\nnongeometric = [\"harmonics\", \"compliance\"]\n\
             nongeometric_keep = \"better\"\n",
            p,
        )
        .unwrap()
        .campaign;
        let terms = c.nongeometric_terms();
        assert!(terms.compliance && terms.harmonics);
        assert_eq!(terms.keep, NongeometricKeep::Better);
        let only = parse_cell_config("[campaign]\nnongeometric = [\"compliance\"]\n", p)
            .unwrap()
            .campaign
            .nongeometric_terms();
        assert_eq!(only.families(), vec![TermFamily::Compliance]);
        for (text, want) in [
            (
                "[campaign]\nnongeometric = [\"gravity\"]\n",
                "unknown variant `gravity`, expected `compliance` or `harmonics`",
            ),
            (
                "[campaign]\nnongeometric = [\"harmonics\", \"compliance\", \"harmonics\"]\n",
                "c.toml: campaign.nongeometric: `harmonics` is given twice",
            ),
            (
                "[campaign]\nnongeometric = \"harmonics\"\n",
                "campaign.nongeometric",
            ),
            (
                "[campaign]\nnongeometric_keep = \"best\"\n",
                "unknown variant `best`, expected `extended` or `better`",
            ),
        ] {
            let e = parse_cell_config(text, p).unwrap_err().to_string();
            let key = text.lines().nth(1).and_then(|l| l.split(' ').next());
            let key = format!("c.toml: campaign.{}", key.unwrap_or_default());
            assert!(e.starts_with(&key) && e.contains(want), "{text}: {e}");
        }
    }

    #[test]
    fn stop_keys_default_to_every_planned_pose_and_their_rules_name_the_key() {
        let p = Path::new("c.toml");
        let c = parse_cell_config("", p).unwrap().campaign;
        assert_eq!(
            (
                c.stop_when,
                c.stop_min_gain,
                c.target_verify_mm,
                c.stop_block
            ),
            (StopWhen::Planned, 0.02, None, None)
        );
        assert_eq!(c.stop_remaining_gain, 0.05);
        // op, 6 joints and the base: 36 candidates, 5 observations a pose → 8
        assert_eq!(c.stop_block_for(36), 8);
        let pos = parse_cell_config("[campaign]\nmodel = \"position\"\n", p).unwrap();
        assert_eq!(pos.campaign.stop_block_for(36), 12);
        let c = parse_cell_config(
            "[campaign]\nstop_when = \"predicted\"\nstop_min_gain = 0.05\n\
             target_verify_mm = 0.03\nstop_block = 10\n",
            p,
        )
        .unwrap()
        .campaign;
        assert_eq!(
            (
                c.stop_when,
                c.stop_min_gain,
                c.target_verify_mm,
                c.stop_block_for(36)
            ),
            (StopWhen::Predicted, 0.05, Some(0.03), 10)
        );
        for (text, key) in [
            ("[campaign]\nstop_min_gain = 1.0\n", "campaign.stop_min_gain"),
            ("[campaign]\nstop_min_gain = -0.01\n", "campaign.stop_min_gain"),
            (
                "[campaign]\nstop_remaining_gain = 1.0\n",
                "campaign.stop_remaining_gain",
            ),
            (
                "[campaign]\nstop_remaining_gain = nan\n",
                "campaign.stop_remaining_gain",
            ),
            ("[campaign]\ntarget_verify_mm = 0.0\n", "campaign.target_verify_mm"),
            ("[campaign]\nstop_block = 0\n", "campaign.stop_block"),
            ("[campaign]\nident = 20\nstop_block = 21\n", "campaign.stop_block"),
            (
                "[campaign]\nstop_when = \"predicted\"\n[iso9283]\ncompensated_model = \"m.toml\"\n",
                "campaign.stop_when",
            ),
        ] {
            match parse_cell_config(text, p) {
                Err(ConfigError::Invalid { key: k, .. }) => assert_eq!(k, key, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
    }

    #[test]
    fn iso9283_section_defaults_and_rules() {
        let p = Path::new("/etc/cellcal/cell.toml");
        assert!(parse_cell_config("", p).unwrap().iso9283.is_none());
        let c = parse_cell_config("[iso9283]\ncompensated_model = \"id.toml\"\n", p).unwrap();
        let iso = c.iso9283.unwrap();
        assert_eq!((iso.cycles, iso.approach_mm), (30, 50.0));
        assert_eq!(iso.approach_vector(), Some(-Vector3::z()));
        assert_eq!(
            iso.compensated_model.as_deref(),
            Some(Path::new("/etc/cellcal/id.toml"))
        );
        for (text, key) in [
            ("[iso9283]\ncycles = 1\n", "iso9283.cycles"),
            ("[iso9283]\napproach = \"down\"\n", "iso9283.approach"),
            (
                "[iso9283]\ndiagonal_fraction = 0.6\n",
                "iso9283.diagonal_fraction",
            ),
            ("[iso9283]\nspeed_pct = 0.0\n", "iso9283.speed_pct"),
            ("[iso9283]\nrepeat = 3\n", "repeat"),
            ("[setup]\nbase_registration = false\n[iso9283]\n", "iso9283"),
        ] {
            let e = parse_cell_config(text, p).unwrap_err().to_string();
            assert!(e.contains(key), "{text}: {e}");
        }
    }

    #[test]
    fn empty_file_gives_defaults() {
        let c = parse_cell_config("", Path::new("/etc/cellcal/cell.toml")).unwrap();
        assert_eq!(c.campaign.poses, 300);
        assert_eq!(c.campaign.box_center_mm, [550.0, 0.0, 550.0]);
        assert_eq!(c.robot, Path::new("/etc/cellcal/robots/staubli_tx60.toml"));
        assert_eq!(c.model(), ObsModel::Op);
    }

    #[test]
    fn unknown_key_named_with_file() {
        let e = parse_cell_config(
            "[campaign]\nposes = 10\npose_count = 3\n",
            Path::new("c.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("c.toml") && e.contains("pose_count"), "{e}");
    }

    #[test]
    fn invalid_values_named() {
        for (text, key) in [
            ("[campaign]\nmodel = \"xyz\"\n", "campaign.model"),
            ("[campaign]\nident = 400\n", "campaign.ident"),
            (
                "[campaign]\npath_margin_mm = -1.0\n",
                "campaign.path_margin_mm",
            ),
            ("[stage]\naxis = \"+z\"\n", "stage.axis"),
            ("[stage]\naxis = \"0,0,0\"\n", "stage.axis"),
            ("[stage]\naxis = \"nan,1,0\"\n", "stage.axis"),
            ("[stage]\naxis = \"0,1,0\"\n", "stage.axis"),
            ("[campaign]\nmodel = \"NP\"\n", "campaign.model"),
            ("[campaign]\nselection = \"best\"\n", "campaign.selection"),
            (
                "[robot_controller]\nspeed_pct = 150\n",
                "robot_controller.speed_pct",
            ),
            ("[tracker]\nmeasure_ms = 0\n", "tracker.measure_ms"),
        ] {
            let e = parse_cell_config(text, Path::new("c.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{text}: {e}");
        }
    }

    /// The error loading `text` as `cell.toml`.
    fn load_error(text: &str) -> String {
        parse_cell_config(text, Path::new("cell.toml"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn non_finite_safety_values_are_named_by_file_and_key() {
        for (text, want) in [
            (
                "[campaign]\nbox_center_mm = [nan, 0, 550]\n",
                "campaign.box_center_mm[0]: nan is not a finite number",
            ),
            (
                "[campaign]\nbox_size_mm = [1000, inf, 1000]\n",
                "campaign.box_size_mm[1]: inf is not a finite number",
            ),
            (
                "[campaign]\nfloor_z_mm = nan\n",
                "campaign.floor_z_mm: nan is not a finite number",
            ),
            (
                "[campaign]\nfloor_z_mm = -inf\n",
                "campaign.floor_z_mm: -inf is not a finite number",
            ),
            (
                "[campaign]\nwrist_min_deg = nan\n",
                "campaign.wrist_min_deg: nan is not a finite number",
            ),
            (
                "[campaign]\nline_of_sight_max_deg = nan\n",
                "campaign.line_of_sight_max_deg: nan is not a finite number",
            ),
            (
                "[campaign]\ntool_mm = [0, 0, inf]\n",
                "campaign.tool_mm[2]: inf is not a finite number",
            ),
            (
                "[tracker]\nposition_mm = [inf, 0, 0]\n",
                "tracker.position_mm[0]: inf is not a finite number",
            ),
            (
                "[stage]\np1_mm = nan\n",
                "stage.p1_mm: nan is not a finite number",
            ),
            (
                "[setup]\nhome_deg = [0, 30, nan, 0, 45, 0]\n",
                "setup.home_deg[2]: nan is not a finite number",
            ),
            (
                "[sim]\ntracker_noise_scale = nan\n",
                "sim.tracker_noise_scale: nan is not a finite number",
            ),
            (
                "[sim.faults.tracker]\nbeam_break_probability = inf\n",
                "sim.faults.tracker.beam_break_probability: inf is not a finite number",
            ),
        ] {
            assert_eq!(load_error(text), format!("cell.toml: {want}"), "{text}");
        }
    }

    #[test]
    fn arrays_have_their_exact_length() {
        for (text, want) in [
            (
                "[campaign]\nbox_center_mm = [550, 0, 550, 1]\n",
                "campaign.box_center_mm: has 4 values; it takes exactly 3",
            ),
            (
                "[tracker]\nposition_mm = [2550, 0, 0, 0]\n",
                "tracker.position_mm: has 4 values; it takes exactly 3",
            ),
            (
                "[stage]\nrange_mm = [0, 25, 50]\n",
                "stage.range_mm: has 3 values; it takes exactly 2",
            ),
        ] {
            assert_eq!(load_error(text), format!("cell.toml: {want}"), "{text}");
        }
        let e = parse_cell_config("[campaign]\nbox_size_mm = [1, 2]\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("c.toml: campaign.box_size_mm: "), "{e}");
    }

    #[test]
    fn values_that_would_switch_a_check_off_are_refused() {
        for (text, key) in [
            (
                "[campaign]\nbox_size_mm = [1000, 0, 1000]\n",
                "campaign.box_size_mm[1]",
            ),
            (
                "[campaign]\nbox_size_mm = [-5, 1000, 1000]\n",
                "campaign.box_size_mm[0]",
            ),
            ("[campaign]\nwrist_min_deg = -1\n", "campaign.wrist_min_deg"),
            ("[campaign]\nwrist_min_deg = 90\n", "campaign.wrist_min_deg"),
            (
                "[campaign]\nline_of_sight_max_deg = 0\n",
                "campaign.line_of_sight_max_deg",
            ),
            (
                "[campaign]\nline_of_sight_max_deg = 181\n",
                "campaign.line_of_sight_max_deg",
            ),
            ("[campaign]\ndrift_max_mm = 0\n", "campaign.drift_max_mm"),
            ("[campaign]\nposes = 200000\nident = 10\n", "campaign.poses"),
            (
                "[robot_controller]\nspeed_pct = 0\n",
                "robot_controller.speed_pct",
            ),
            (
                "[robot_controller]\nsettle_timeout_ms = 0\n",
                "robot_controller.settle_timeout_ms",
            ),
            (
                "[robot_controller]\nmax_attempts = 0\n",
                "robot_controller.max_attempts",
            ),
            ("[tracker]\nmax_attempts = 0\n", "tracker.max_attempts"),
            (
                "[tracker]\nmax_std_total_mm = 0\n",
                "tracker.max_std_total_mm",
            ),
            (
                "[stage]\nmicrosteps_per_mm = 0\n",
                "stage.microsteps_per_mm",
            ),
            ("[stage]\ntravel_mm = -10\n", "stage.travel_mm"),
            ("[stage]\ntolerance_mm = 0\n", "stage.tolerance_mm"),
            ("[stage]\ntolerance_mm = 5\n", "stage.tolerance_mm"),
            ("[stage]\nrange_mm = [5, 5]\n", "stage.range_mm"),
            ("[setup]\njog_mm = 0\n", "setup.jog_mm"),
            ("[setup]\nangles_deg = [10, 0]\n", "setup.angles_deg"),
            (
                "[setup]\nmax_sphere_rms_mm = 0\n",
                "setup.max_sphere_rms_mm",
            ),
            ("[setup]\nmax_base_rms_mm = -1\n", "setup.max_base_rms_mm"),
        ] {
            let e = parse_cell_config(text, Path::new("c.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(&format!("c.toml: {key}: ")), "{text}: {e}");
        }
    }

    #[test]
    fn api_tokens_and_tls_are_read_and_checked() {
        let digest = TokenDigest::of_token("t").to_hex();
        let c = parse_cell_config(
            &format!(
                "[api]\ntls_cert = \"c.pem\"\ntls_key = \"/k.pem\"\nallowed_hosts = [\"cell.lan\"]\n\
                 [[api.tokens]]\nname = \"alice\"\nrole = \"technician\"\nsha256 = \"{digest}\"\n"
            ),
            Path::new("/etc/cellcal/cell.toml"),
        )
        .unwrap();
        assert_eq!(c.api.tokens.len(), 1);
        assert_eq!(c.api.tokens[0].role, Role::Technician);
        assert_eq!(c.api.tokens[0].digest, TokenDigest::of_token("t"));
        assert_eq!(
            c.api.tls,
            Some((PathBuf::from("/etc/cellcal/c.pem"), PathBuf::from("/k.pem")))
        );
        assert!(parse_cell_config("", Path::new("c.toml"))
            .unwrap()
            .api
            .tokens
            .is_empty());
        let entry = |name: &str, role: &str, sha: &str| {
            format!("[[api.tokens]]\nname = \"{name}\"\nrole = \"{role}\"\nsha256 = \"{sha}\"\n")
        };
        for (text, key) in [
            (entry("a", "operator", "abc"), "api.tokens[0].sha256"),
            (entry("", "operator", &digest), "api.tokens[0].name"),
            (
                entry("a", "viewer", &digest) + &entry("a", "viewer", &digest),
                "api.tokens[1].name",
            ),
            (entry("a", "admin", &digest), "admin"),
            (entry("a", "viewer", &digest) + "secret = 1\n", "secret"),
            ("[api]\ntls_cert = \"c.pem\"\n".into(), "api.tls_key"),
            (
                "[api]\nallowed_origins = [\"evil\"]\n".into(),
                "api.allowed_origins",
            ),
            (
                "[api]\nallowed_hosts = [\"a/b\"]\n".into(),
                "api.allowed_hosts",
            ),
            ("[api]\ntoken = 1\n".into(), "token"),
        ] {
            let e = parse_cell_config(&text, Path::new("c.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.contains("c.toml") && e.contains(key), "{text}: {e}");
        }
    }

    #[test]
    fn device_settings_default_to_the_drivers_and_bad_ones_are_named() {
        let c = parse_cell_config("", Path::new("c.toml")).unwrap();
        assert_eq!(c.tracker.command_timeout_ms, None);
        assert_eq!((c.stage.device_address, c.stage.axis_number), (1, 1));
        let c = parse_cell_config(
            "[tracker]\nbeam_break_code = 10050\ncommand_timeout_ms = 300\nuse_adm = false\n\
             [robot_controller]\nrequest_timeout_ms = 250\n\
             [stage]\ndevice_address = 2\naxis_number = 3\nmove_timeout_ms = 9000\n",
            Path::new("c.toml"),
        )
        .unwrap();
        assert_eq!(c.tracker.beam_break_code, Some(10050));
        assert_eq!(c.tracker.command_timeout_ms, Some(300));
        assert!(!c.tracker.use_adm);
        assert_eq!(c.robot_controller.request_timeout_ms, Some(250));
        assert_eq!((c.stage.device_address, c.stage.axis_number), (2, 3));
        assert_eq!(c.stage.move_timeout_ms, Some(9000));
        for (text, want) in [
            (
                "[tracker]\ncommand_timeout_ms = 0\n",
                "tracker.command_timeout_ms: must be in",
            ),
            (
                "[tracker]\nconnect_timeout_ms = -5\n",
                "tracker.connect_timeout_ms: ",
            ),
            (
                "[tracker]\nsearch_timeout_ms = nan\n",
                "tracker.search_timeout_ms: nan is not a finite number",
            ),
            (
                "[tracker]\nmeasure_margin_ms = inf\n",
                "tracker.measure_margin_ms: inf is not a finite number",
            ),
            (
                "[tracker]\ninitialize_timeout_ms = 1.5\n",
                "tracker.initialize_timeout_ms: ",
            ),
            (
                "[tracker]\nmeasure_ms = 100000000\n",
                "tracker.measure_ms: must be in",
            ),
            (
                "[tracker]\nsearch_distance_mm = -1\n",
                "tracker.search_distance_mm: must be positive",
            ),
            (
                "[tracker]\nbeam_break_codes = []\n",
                "tracker.beam_break_codes: must list",
            ),
            (
                "[robot_controller]\nrequest_timeout_ms = 0\n",
                "robot_controller.request_timeout_ms: ",
            ),
            (
                "[robot_controller]\nconnect_timeout_ms = nan\n",
                "robot_controller.connect_timeout_ms: nan",
            ),
            (
                "[robot_controller]\nwait_margin_ms = -1\n",
                "robot_controller.wait_margin_ms: ",
            ),
            (
                "[robot_controller]\nsettle_timeout_ms = 86400001\n",
                "robot_controller.settle_timeout_ms: ",
            ),
            (
                "[stage]\nmove_timeout_ms = 86400001\n",
                "stage.move_timeout_ms: must be in",
            ),
            (
                "[stage]\nreply_timeout_ms = 0\n",
                "stage.reply_timeout_ms: ",
            ),
            (
                "[stage]\nhome_timeout_ms = inf\n",
                "stage.home_timeout_ms: inf",
            ),
            (
                "[stage]\npoll_interval_ms = -20\n",
                "stage.poll_interval_ms: ",
            ),
            (
                "[stage]\ndevice_address = 0\n",
                "stage.device_address: must be in 1..=99",
            ),
            ("[stage]\ndevice_address = 300\n", "stage.device_address: "),
            (
                "[stage]\naxis_number = 10\n",
                "stage.axis_number: must be in 1..=9",
            ),
            ("[stage]\nbaud = 0\n", "stage.baud: "),
            ("[stage]\nmax_tries = 0\n", "stage.max_tries: "),
        ] {
            let e = load_error(text);
            assert!(e.starts_with(&format!("cell.toml: {want}")), "{text}: {e}");
        }
    }

    #[test]
    fn sim_is_read_by_the_same_strict_parser() {
        let p = Path::new("/etc/cellcal/cell.toml");
        // unknown keys, wrong lengths and the world's rules: refused when the file is read, on
        // every path (`run` and `serve` through parse_cell_config, `sim` through
        // parse_sim_config), before any campaign is stored
        for (text, want) in [
            ("[sim]\nbogus = 1\n", "bogus"),
            ("[sim.faults.robot]\nreject_move = 2\n", "reject_move"),
            (
                "[sim]\ntracker_position_mm = [0, 0, 0, 1]\n",
                "sim.tracker_position_mm: has 4 values; it takes exactly 3",
            ),
            (
                "[sim]\nstage_max_mm = 0\n",
                "sim.stage_max_mm: must be positive",
            ),
            (
                "[sim.faults.tracker]\nbeam_break_probability = 1.5\n",
                "sim.faults.tracker.beam_break_probability: must be in [0, 1]",
            ),
            (
                "[sim]\nstage_speed_mm_s = -1\n",
                "sim.stage_speed_mm_s: must be positive",
            ),
            (
                "[sim]\ntime_scale = 0\n",
                "sim.time_scale: must be positive",
            ),
            (
                "[sim]\ncompliance_rad_per_nm = [0, 1e-6, 1e-6, 1e-6, 1e-6]\n",
                "sim.compliance_rad_per_nm: TOML parse error",
            ),
            (
                "[sim]\ncompliance_rad_per_nm = [0, -1e-6, 0, 0, 0, 0]\n",
                "sim.compliance_rad_per_nm: joint 2: a compliance cannot be negative",
            ),
            (
                "[sim]\nharmonics_urad = [[1, 2, 3, 4], [1, 2, 3, 4], [1, 2, 3], [0, 0, 0, 0], \
                 [0, 0, 0, 0], [0, 0, 0, 0]]\n",
                "expected an array of length 4",
            ),
            (
                "[sim]\nharmonics_urad = [[1, 2, 3, 4], [1, 2, 3, 4], [1, 2, 3, nan], [0, 0, 0, 0], \
                 [0, 0, 0, 0], [0, 0, 0, 0]]\n",
                "sim.harmonics_urad[2][3]: nan is not a finite number",
            ),
            (
                "[sim]\nnongeometric_errors = \"typical\"\ncompliance_rad_per_nm = [0, 1e-6, 1e-6, 1e-6, 1e-6, 0]\n",
                "sim.nongeometric_errors: \"typical\" generates",
            ),
            ("[sim]\nnongeometric_errors = \"large\"\n", "nongeometric_errors"),
        ] {
            for e in [
                parse_cell_config(text, p).unwrap_err().to_string(),
                parse_sim_config(text, p).unwrap_err().to_string(),
            ] {
                assert!(
                    e.starts_with("/etc/cellcal/cell.toml: ") && e.contains(want),
                    "{text}: {e}"
                );
            }
        }
        // one stage: the simulated one follows [stage]
        for (text, want) in [
            (
                "[sim]\nstage_mode = \"manual\"\n",
                "cell.toml: sim.stage_mode: `manual` contradicts stage.kind",
            ),
            (
                "[stage]\nrange_mm = [0, 60]\n",
                "cell.toml: stage.range_mm: [0, 60] mm is beyond the simulated stage's travel",
            ),
        ] {
            assert!(
                load_error(text).starts_with(want),
                "{text}: {}",
                load_error(text)
            );
        }
        let c = parse_cell_config(
            "[stage]\nkind = \"manual\"\ndevice_address = 4\naxis_number = 2\n\
             [sim]\nerrors = \"errors.toml\"\n",
            p,
        )
        .unwrap();
        let sim = c.sim.expect("[sim]");
        assert_eq!(sim.stage_mode, super::super::sim::StageMode::Manual);
        assert_eq!(sim.stage_address, (4, 2));
        assert_eq!(sim.errors, "/etc/cellcal/errors.toml");
        // a simulated device without a [sim] table: the default world, checked the same way
        let c = parse_cell_config("", p).unwrap();
        let resolved = SimWorldConfig {
            // unset in the file: it follows `[robot_controller] protocol`
            robot_protocol: Some(RobotProtocol::Robotlink),
            ..SimWorldConfig::default()
        };
        assert_eq!(c.sim, Some(resolved));
        let real = "[tracker]\nmode = \"real\"\n[robot_controller]\nmode = \"real\"\n\
                    [stage]\nmode = \"real\"\nrange_mm = [0, 60]\n";
        assert_eq!(parse_cell_config(real, p).unwrap().sim, None);
    }

    #[test]
    fn the_simulated_stage_follows_stage_kind_in_cellcal_sim_too() {
        let p = Path::new("/etc/cellcal/cell.toml");
        // one key decides: a manual stage.kind makes the simulated stage manual
        let sim = parse_sim_config(
            "[stage]\nkind = \"manual\"\ndevice_address = 2\n[sim]\nstage_mode = \"zaber\"\n",
            p,
        )
        .expect("manual");
        assert_eq!(sim.stage_mode, super::super::sim::StageMode::Manual);
        assert_eq!(sim.stage_address, (2, 1));
        // the other way round is refused, naming both keys and the fix
        for e in [
            parse_sim_config("[sim]\nstage_mode = \"manual\"\n", p),
            parse_cell_config("[sim]\nstage_mode = \"manual\"\n", p).map(|c| c.sim.unwrap()),
        ] {
            let e = e.unwrap_err().to_string();
            assert!(
                e.contains("sim.stage_mode")
                    && e.contains("stage.kind = \"serial\"")
                    && e.contains("set stage.kind = \"manual\"")
                    && e.contains("delete sim.stage_mode"),
                "{e}"
            );
        }
        // [stage] by the same strict rules
        let e = parse_sim_config("[stage]\nbogus = 1\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("bogus"), "{e}");
    }

    #[test]
    fn wrong_type_named() {
        let e = parse_cell_config("[campaign]\nposes = \"many\"\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("poses"), "{e}");
    }
}

#[cfg(test)]
mod shipped_files {
    use super::*;

    /// The field names serde reads for the struct `T` (its `deny_unknown_fields` list).
    fn fields_of<T: serde::de::DeserializeOwned>() -> &'static [&'static str] {
        struct Fields(Option<&'static [&'static str]>);
        impl<'de> serde::Deserializer<'de> for &mut Fields {
            type Error = serde::de::value::Error;
            fn deserialize_any<V: serde::de::Visitor<'de>>(
                self,
                _: V,
            ) -> Result<V::Value, Self::Error> {
                Err(serde::de::Error::custom("not a struct"))
            }
            fn deserialize_struct<V: serde::de::Visitor<'de>>(
                self,
                _: &'static str,
                fields: &'static [&'static str],
                _: V,
            ) -> Result<V::Value, Self::Error> {
                self.0 = Some(fields);
                Err(serde::de::Error::custom("fields read"))
            }
            serde::forward_to_deserialize_any! {
                bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
                byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map enum
                identifier ignored_any
            }
        }
        let mut f = Fields(None);
        let _ = T::deserialize(&mut f);
        f.0.expect("a struct")
    }

    /// Whether `text` sets or shows (commented out) `key` inside `[table]` (`""`: the top).
    fn documents(text: &str, table: &str, key: &str) -> bool {
        let mut current = String::new();
        for line in text.lines() {
            let l = line.trim_start_matches('#').trim();
            if l.starts_with('[') {
                let name = l.trim_start_matches('[');
                if let Some(end) = name.find(']') {
                    current = name[..end].to_owned();
                    continue;
                }
            }
            let Some((k, _)) = l.split_once('=') else {
                continue;
            };
            if current == table && k.trim() == key {
                return true;
            }
        }
        false
    }

    #[test]
    fn every_key_is_documented_in_the_shipped_files() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
        let read = |name: &str| std::fs::read_to_string(dir.join(name)).expect("shipped file");
        let (example, sim) = (read("cell.example.toml"), read("cell.sim.toml"));
        let cell_tables: [(&str, &[&str]); 9] = [
            ("", fields_of::<CellFile>()),
            ("tracker", fields_of::<TrackerSection>()),
            ("robot_controller", fields_of::<RobotSection>()),
            ("stage", fields_of::<StageSection>()),
            ("campaign", fields_of::<CampaignSection>()),
            ("setup", fields_of::<SetupSection>()),
            ("iso9283", fields_of::<Iso9283Section>()),
            ("api", fields_of::<ApiFile>()),
            ("api.tokens", fields_of::<ApiTokenFile>()),
        ];
        let sim_tables: [(&str, &[&str]); 4] = [
            ("sim", fields_of::<SimWorldConfig>()),
            (
                "sim.faults.tracker",
                fields_of::<super::super::sim::TrackerFaults>(),
            ),
            (
                "sim.faults.robot",
                fields_of::<super::super::sim::RobotFaults>(),
            ),
            (
                "sim.faults.stage",
                fields_of::<super::super::sim::StageFaults>(),
            ),
        ];
        let mut missing = Vec::new();
        for (file, text, tables) in [
            ("cell.example.toml", &example, &cell_tables[..]),
            ("cell.sim.toml", &sim, &sim_tables[..]),
        ] {
            for (table, keys) in tables {
                for key in keys.iter() {
                    let is_table = cell_tables.iter().any(|(t, _)| t == key)
                        || ["sim", "faults", "api", "tokens"].contains(key);
                    if !is_table && !documents(text, table, key) {
                        missing.push(format!("{file}: [{table}] {key}"));
                    }
                }
            }
        }
        assert!(missing.is_empty(), "not documented: {missing:?}");
        // the example's values are the defaults (its header says so) where not marked "example"
        let c = load_cell_config(&dir.join("cell.example.toml")).unwrap();
        let d = TrackerSection::default();
        assert_eq!(
            (c.tracker.use_adm, c.tracker.measure_ms),
            (d.use_adm, Some(REAL_MEASURE_MS))
        );
        let d = StageSection::default();
        assert_eq!(
            (
                c.stage.device_address,
                c.stage.axis_number,
                c.stage.baud,
                c.stage.max_tries
            ),
            (d.device_address, d.axis_number, d.baud, d.max_tries)
        );
        assert_eq!(c.stage.home_on_prepare, d.home_on_prepare);
    }

    #[test]
    fn shipped_configurations_parse() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config");
        for name in ["cell.sim.toml", "cell.example.toml"] {
            let p = dir.join(name);
            let c = load_cell_config(&p).unwrap_or_else(|e| panic!("{e}"));
            assert!(c.robot.exists(), "{name}: robot file {}", c.robot.display());
        }
        let real = load_cell_config(&dir.join("cell.example.toml")).unwrap();
        assert!(!real.any_simulated());
        assert!(load_cell_config(&dir.join("cell.sim.toml"))
            .unwrap()
            .any_simulated());
    }
}
