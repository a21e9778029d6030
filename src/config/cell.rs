//! The cell configuration file. See `config/cell.example.toml` for every key.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::Deserialize;

use crate::identify::ObsModel;

/// Why a configuration could not be loaded (names the file and the key).
pub type ConfigError = crate::model::file::FileError;

/// Simulated device (started in-process from `[sim]`) or real device at an address.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceMode {
    /// Part of the simulated cell.
    Sim,
    /// A real device at the configured address or path.
    Real,
}

/// `[tracker]`: the laser tracker and the measurement quality gate.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerSection {
    /// `sim` or `real`.
    pub mode: DeviceMode,
    /// emScon server address (real mode), e.g. `192.168.0.1:700`.
    pub address: String,
    /// Stationary measuring time (ms).
    pub measure_ms: u32,
    /// Reflector id for SetReflector (emScon), if it must be set.
    pub reflector_id: Option<i32>,
    /// Quality gate: a point whose total standard deviation exceeds this is measured again (mm).
    pub max_std_total_mm: f64,
    /// Measurement attempts per point before the campaign pauses.
    pub max_attempts: u32,
    /// Tracker position in the robot base frame, for the line-of-sight check in planning (mm).
    pub position_mm: [f64; 3],
}

impl Default for TrackerSection {
    fn default() -> Self {
        TrackerSection {
            mode: DeviceMode::Sim,
            address: "127.0.0.1:700".into(),
            measure_ms: 1000,
            reflector_id: None,
            max_std_total_mm: 0.05,
            max_attempts: 5,
            position_mm: [2550.0, 0.0, 0.0],
        }
    }
}

/// `[robot]`: the robot controller.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotSection {
    /// `sim` or `real`.
    pub mode: DeviceMode,
    /// robotlink server address (real mode).
    pub address: String,
    /// Speed (percent of the controller's maximum).
    pub speed_pct: f64,
    /// Time allowed for a move to settle (ms).
    pub settle_timeout_ms: u64,
    /// Attempts per move before the campaign pauses.
    pub max_attempts: u32,
}

impl Default for RobotSection {
    fn default() -> Self {
        RobotSection {
            mode: DeviceMode::Sim,
            address: "127.0.0.1:11000".into(),
            speed_pct: 20.0,
            settle_timeout_ms: 60_000,
            max_attempts: 3,
        }
    }
}

/// How the stage moves between P1 and P2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
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
#[derive(Debug, Clone, PartialEq, Deserialize)]
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
    /// Microsteps per mm of the motorised stage.
    pub microsteps_per_mm: f64,
    /// Stage position at P1 (mm).
    pub p1_mm: f64,
    /// Travel from P1 to P2 (mm).
    pub travel_mm: f64,
    /// Stage axis in the flange frame: `+x`, `-x`, `+y` or `-y`.
    pub axis: String,
    /// Accepted difference between requested and read stage position (mm).
    pub tolerance_mm: f64,
}

impl Default for StageSection {
    fn default() -> Self {
        StageSection {
            mode: DeviceMode::Sim,
            kind: StageMode::Serial,
            serial_path: "/dev/ttyUSB0".into(),
            gauge_path: "/dev/ttyUSB1".into(),
            microsteps_per_mm: 20_997.0,
            p1_mm: 0.0,
            travel_mm: 10.0,
            axis: "+y".into(),
            tolerance_mm: 0.02,
        }
    }
}

impl StageSection {
    /// The stage axis as a unit vector in the flange frame.
    pub fn axis_vector(&self) -> Option<Vector3<f64>> {
        match self.axis.as_str() {
            "+x" => Some(Vector3::x()),
            "-x" => Some(-Vector3::x()),
            "+y" => Some(Vector3::y()),
            "-y" => Some(-Vector3::y()),
            _ => None,
        }
    }
}

/// `[campaign]`: defaults of a campaign.
#[derive(Debug, Clone, PartialEq, Deserialize)]
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
    pub model: String,
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
}

impl Default for CampaignSection {
    fn default() -> Self {
        CampaignSection {
            box_center_mm: [550.0, 0.0, 550.0],
            box_size_mm: [1000.0, 1000.0, 1000.0],
            poses: 300,
            ident: 100,
            seed: 4802,
            model: "op".into(),
            wrist_min_deg: 10.0,
            floor_z_mm: -300.0,
            path_margin_mm: 100.0,
            line_of_sight_max_deg: 180.0,
            drift_every: 50,
            drift_max_mm: 0.1,
            identify_base: true,
            identify_tool: false,
            tool_mm: [0.0, 0.0, 0.0],
        }
    }
}

/// `[setup]`: the cell setup steps run once per campaign before the first pose.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SetupSection {
    /// Run the tool-frame procedure of METHOD §4 (jogs along flange x/y, rotations about them,
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

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CellFile {
    robot: Option<PathBuf>,
    store: Option<PathBuf>,
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
    sim: Option<toml::Table>,
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
    /// The `[sim]` table, if any (the simulated world's own configuration).
    pub sim: Option<toml::Table>,
}

impl CellConfig {
    /// The configured observation model.
    pub fn model(&self) -> ObsModel {
        ObsModel::parse(&self.campaign.model).unwrap_or(ObsModel::Op)
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
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_owned(),
        source,
    })?;
    parse_cell_config(&text, path)
}

/// Parse and validate configuration text; `path` names the file in errors and anchors
/// relative paths.
pub fn parse_cell_config(text: &str, path: &Path) -> Result<CellConfig, ConfigError> {
    let f: CellFile = toml::from_str(text).map_err(|e| ConfigError::Parse {
        path: path.to_owned(),
        message: e.to_string().trim_end().replace('\n', " "),
    })?;
    let invalid = |key: &str, message: String| ConfigError::Invalid {
        path: path.to_owned(),
        key: key.to_owned(),
        message,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let resolve = |p: PathBuf| if p.is_absolute() { p } else { dir.join(p) };
    let c = &f.campaign;
    if ObsModel::parse(&c.model).is_none() {
        return Err(invalid(
            "campaign.model",
            format!("`{}` is not one of position, np, op, full", c.model),
        ));
    }
    if c.ident == 0 || c.ident >= c.poses {
        return Err(invalid(
            "campaign.ident",
            format!(
                "must be between 1 and poses − 1 ({}), got {}",
                c.poses.saturating_sub(1),
                c.ident
            ),
        ));
    }
    if c.box_size_mm.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(invalid(
            "campaign.box_size_mm",
            "must be three positive numbers".into(),
        ));
    }
    if !(c.path_margin_mm.is_finite() && c.path_margin_mm >= 0.0) {
        return Err(invalid(
            "campaign.path_margin_mm",
            "must be a non-negative number".into(),
        ));
    }
    if !(c.line_of_sight_max_deg > 0.0 && c.line_of_sight_max_deg <= 180.0) {
        return Err(invalid(
            "campaign.line_of_sight_max_deg",
            "must be in (0, 180]".into(),
        ));
    }
    if !(c.drift_max_mm.is_finite() && c.drift_max_mm > 0.0) {
        return Err(invalid("campaign.drift_max_mm", "must be positive".into()));
    }
    if f.stage.axis_vector().is_none() {
        return Err(invalid(
            "stage.axis",
            format!("`{}` is not one of +x, -x, +y, -y", f.stage.axis),
        ));
    }
    if !(f.stage.travel_mm.is_finite() && f.stage.travel_mm > 0.0) {
        return Err(invalid("stage.travel_mm", "must be positive".into()));
    }
    if !(f.stage.tolerance_mm.is_finite() && f.stage.tolerance_mm > 0.0) {
        return Err(invalid("stage.tolerance_mm", "must be positive".into()));
    }
    if !(f.robot_controller.speed_pct > 0.0 && f.robot_controller.speed_pct <= 100.0) {
        return Err(invalid(
            "robot_controller.speed_pct",
            "must be in (0, 100]".into(),
        ));
    }
    if f.tracker.measure_ms == 0 {
        return Err(invalid("tracker.measure_ms", "must be positive".into()));
    }
    if !(f.tracker.max_std_total_mm.is_finite() && f.tracker.max_std_total_mm > 0.0) {
        return Err(invalid(
            "tracker.max_std_total_mm",
            "must be positive".into(),
        ));
    }
    let st = &f.setup;
    if !(st.jog_mm.is_finite() && st.jog_mm > 0.0) {
        return Err(invalid("setup.jog_mm", "must be positive".into()));
    }
    if st.angles_deg.len() < 2
        || st
            .angles_deg
            .iter()
            .any(|a| !a.is_finite() || *a == 0.0 || a.abs() > 90.0)
    {
        return Err(invalid(
            "setup.angles_deg",
            "needs at least two non-zero angles within ±90°".into(),
        ));
    }
    if st.home_pairs == 0 {
        return Err(invalid("setup.home_pairs", "must be at least 1".into()));
    }
    if st.base_registration && st.base_poses < 3 {
        return Err(invalid("setup.base_poses", "must be at least 3".into()));
    }
    if st
        .home_deg
        .as_ref()
        .is_some_and(|h| h.iter().any(|v| !v.is_finite()))
    {
        return Err(invalid("setup.home_deg", "must be finite numbers".into()));
    }
    for (key, v) in [
        ("setup.max_sphere_rms_mm", st.max_sphere_rms_mm),
        ("setup.max_base_rms_mm", st.max_base_rms_mm),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(invalid(key, "must be positive".into()));
        }
    }
    if f.tracker.max_attempts == 0 || f.robot_controller.max_attempts == 0 {
        return Err(invalid("max_attempts", "must be at least 1".into()));
    }
    Ok(CellConfig {
        path: path.to_owned(),
        text: text.to_owned(),
        robot: resolve(
            f.robot
                .unwrap_or_else(|| PathBuf::from("robots/staubli_tx60.toml")),
        ),
        store: resolve(f.store.unwrap_or_else(|| PathBuf::from("cellcal.db"))),
        tracker: f.tracker,
        robot_controller: f.robot_controller,
        stage: f.stage,
        campaign: f.campaign,
        setup: f.setup,
        sim: f.sim,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
