//! Robot model: MDH chain, robot model files, forward kinematics, analytic Jacobians and
//! numerical inverse kinematics of the flange.
//!
//! Pure code: no I/O except [`file::load_robot`], which reads one TOML file.

pub mod axis;
pub mod chain;
pub mod checked_toml;
pub mod file;
pub mod gravity;
pub mod ik;
pub mod kinematics;
pub mod pose;
pub mod rotation;
pub mod terms;

pub use axis::{AxisError, SignedAxis};
pub use chain::{JointLimit, JointMotion, Mdh, ParamKind, RobotModel};
pub use file::{load_robot, parse_robot, write_robot, FileError, RobotFileError};
pub use gravity::Mass;
pub use ik::{solve_flange, solve_motion, FlangeMotion, IkError, IkOptions, IkSolution};
pub use kinematics::{forward, Frames, Pose};
pub use kinematics::{gravity_levers, gravity_torques};
pub use terms::{JointTerms, TermFamily, TermKind};

/// The nominal Stäubli TX60 of `config/robots/staubli_tx60.toml`, built in at compile time: the
/// shared fixture of tests, benches and examples. A cell loads its robot from its config instead.
///
/// Never panics: the built-in file parses (test `model::tests::built_in_tx60_is_the_shipped_file`).
pub fn tx60() -> RobotModel {
    parse_robot(
        TX60_TOML,
        std::path::Path::new("config/robots/staubli_tx60.toml"),
    )
    .expect("the built-in TX60 model file parses")
}

/// The text of `config/robots/staubli_tx60.toml`, as [`tx60`] parses it.
const TX60_TOML: &str = include_str!("../../config/robots/staubli_tx60.toml");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_tx60_is_the_shipped_file() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/robots/staubli_tx60.toml");
        assert_eq!(tx60(), load_robot(&path).expect("the shipped TX60 loads"));
        assert_eq!(tx60().joints.len(), 6);
    }
}
