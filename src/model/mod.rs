//! Robot model: MDH chain, robot model files, forward kinematics, analytic Jacobians and
//! numerical inverse kinematics of the flange.
//!
//! Pure code: no I/O except [`file::load_robot`], which reads one TOML file.

pub mod chain;
pub mod checked_toml;
pub mod file;
pub mod ik;
pub mod kinematics;
pub mod rotation;

pub use chain::{JointLimit, Mdh, ParamKind, RobotModel};
pub use file::{load_robot, parse_robot, FileError, RobotFileError};
pub use ik::{solve_flange, solve_motion, FlangeMotion, IkError, IkOptions, IkSolution};
pub use kinematics::{forward, Frames, Pose};

/// The Stäubli TX60 of `config/robots/staubli_tx60.toml` (unit tests).
#[cfg(test)]
pub(crate) fn tx60() -> RobotModel {
    parse_robot(
        include_str!("../../config/robots/staubli_tx60.toml"),
        std::path::Path::new("tx60"),
    )
    .expect("the TX60 model file parses")
}
