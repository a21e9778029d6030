//! The `[sim]` table's types, which live with the rest of the configuration in
//! [`crate::config::sim`] (parsed once, by the same strict parser).

pub use crate::config::sim::{
    NongeometricErrors, RobotFaults, SimFaults, SimWorldConfig, StageFaults, StageMode,
    TrackerFaults,
};
