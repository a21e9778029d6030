//! Cell configuration (TOML): devices, robot model, stage, tracker gate, campaign defaults,
//! store path, and the simulated world. Unknown keys are errors; every error names the file
//! and the key. Relative paths are resolved against the configuration file's folder.

pub mod cell;

pub use cell::{
    load_cell_config, parse_cell_config, ApiSection, ApiToken, CampaignSection, CellConfig,
    ConfigError, DeviceMode, RobotSection, StageMode, StageSection, TrackerSection,
};
