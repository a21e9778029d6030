//! [`RobotProtocol`]: which interface the robot controller speaks. Its own module because both
//! `[robot_controller] protocol` (cell.rs) and `[sim] robot_protocol` (sim.rs) name it.

use serde::{Deserialize, Serialize};

/// How cellcal talks to the robot controller (`[robot_controller] protocol`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RobotProtocol {
    /// robotlink, served by the cellcal VAL3 application on a Stäubli controller.
    #[default]
    Robotlink,
    /// A Universal Robots controller's own Dashboard, RTDE and URScript interfaces.
    Ur,
}

impl RobotProtocol {
    /// The name in the configuration file.
    pub fn name(self) -> &'static str {
        match self {
            RobotProtocol::Robotlink => "robotlink",
            RobotProtocol::Ur => "ur",
        }
    }
}
