//! Cell configuration (TOML): devices, robot model, stage, tracker gate, campaign defaults,
//! store path, and the simulated world. Unknown keys are errors, every number must be finite,
//! every array has its exact length, and each key has a rule (see `config/cell.example.toml`);
//! every error names the file and the key. Relative paths are resolved against the configuration file's folder.

pub mod cell;
pub mod diff;
mod protocol;
mod rules;
pub mod sim;

pub use cell::{
    load_cell_config, parse_cell_config, parse_sim_config, ApiSection, ApiToken, CampaignSection,
    CellConfig, ConfigError, DeviceMode, InvalidKey, Iso9283Section, RobotSection, SetupSection,
    StageMode, StageSection, StopWhen, TrackerSection, DEFAULT_STOP_MIN_GAIN, MAX_DEVICE_MS,
    MAX_POSES, REAL_MEASURE_MS,
};
pub use protocol::RobotProtocol;
pub use sim::SimWorldConfig;
