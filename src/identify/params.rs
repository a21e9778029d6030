//! Parameter identifiers and the parameter state (the robot model being corrected).
//!
//! MDH parameters are additive; the base rotation is updated by a left rotation
//! `R ← exp([δ]×) · R` about the robot base origin, expressed in the measurement frame;
//! base translation and tool are additive.

use nalgebra::Vector3;

use crate::model::rotation::from_rotation_vector;
use crate::model::{ParamKind, RobotModel};

/// One identifiable parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParamId {
    /// MDH parameter of joint `joint` (0-based).
    Mdh {
        /// Joint index (0-based).
        joint: usize,
        /// Parameter kind.
        kind: ParamKind,
    },
    /// Base translation component 0..3 (x, y, z; mm, measurement frame).
    BaseTranslation(usize),
    /// Base rotation component 0..3 (rotation about x, y, z of the measurement frame; rad).
    BaseRotation(usize),
    /// Tool (ball) translation component 0..3 in the flange frame (mm).
    Tool(usize),
    /// Rotation of the stage axis about flange axis 0..3 (x, y, z; rad), the ball staying put:
    /// a setup quantity the identification holds (the measured stage axis), never a
    /// candidate ([`all_params`] does not list it); only the setup-relative analysis
    /// ([`crate::identify::identifiability::setup_relative`]) takes its column. The robot model
    /// holds no stage axis, so [`retract`] leaves the model as it is for it.
    StageAxis(usize),
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl ParamId {
    /// Public name: `theta1`, `d2`, …, `base_tx`, `base_rz`, `tool_x`, `stage_axis_rx`.
    pub fn name(&self) -> String {
        match self {
            ParamId::Mdh { joint, kind } => format!("{}{}", kind.stem(), joint + 1),
            ParamId::BaseTranslation(i) => format!("base_t{}", AXES[*i]),
            ParamId::BaseRotation(i) => format!("base_r{}", AXES[*i]),
            ParamId::Tool(i) => format!("tool_{}", AXES[*i]),
            ParamId::StageAxis(i) => format!("stage_axis_r{}", AXES[*i]),
        }
    }

    /// Human name with Greek letters (`θ1`, `β2`), for printed tables.
    pub fn label(&self) -> String {
        match self {
            ParamId::Mdh { joint, kind } => {
                let s = match kind {
                    ParamKind::Theta => "θ",
                    ParamKind::D => "d",
                    ParamKind::A => "a",
                    ParamKind::Alpha => "α",
                    ParamKind::Beta => "β",
                };
                format!("{s}{}", joint + 1)
            }
            other => other.name(),
        }
    }

    /// Whether the parameter is an angle (rad).
    pub fn is_angle(&self) -> bool {
        match self {
            ParamId::Mdh { kind, .. } => kind.is_angle(),
            ParamId::BaseRotation(_) | ParamId::StageAxis(_) => true,
            _ => false,
        }
    }

    /// Unit (`mm` or `rad`).
    pub fn unit(&self) -> &'static str {
        if self.is_angle() {
            "rad"
        } else {
            "mm"
        }
    }

    /// Joint number (1-based) for MDH parameters.
    pub fn joint_number(&self) -> Option<usize> {
        match self {
            ParamId::Mdh { joint, .. } => Some(joint + 1),
            _ => None,
        }
    }

    /// Kind label for reports: `theta`, `d`, `a`, `alpha`, `beta`, `base_translation`, ….
    pub fn kind_name(&self) -> &'static str {
        match self {
            ParamId::Mdh { kind, .. } => kind.stem(),
            ParamId::BaseTranslation(_) => "base_translation",
            ParamId::BaseRotation(_) => "base_rotation",
            ParamId::Tool(_) => "tool_translation",
            ParamId::StageAxis(_) => "stage_axis_rotation",
        }
    }

    /// Current value in a model (base rotation and stage axis: 0, local perturbations).
    pub fn value(&self, m: &RobotModel) -> f64 {
        match self {
            ParamId::Mdh { joint, kind } => m.joints[*joint].get(*kind),
            ParamId::BaseTranslation(i) => m.base_translation[*i],
            ParamId::BaseRotation(_) | ParamId::StageAxis(_) => 0.0,
            ParamId::Tool(i) => m.tool[*i],
        }
    }
}

/// Every candidate parameter for a chain of `dof` joints, optionally with base and tool.
pub fn all_params(dof: usize, base: bool, tool: bool) -> Vec<ParamId> {
    let mut v: Vec<ParamId> = (0..dof)
        .flat_map(|joint| ParamKind::ALL.map(|kind| ParamId::Mdh { joint, kind }))
        .collect();
    if base {
        v.extend((0..3).map(ParamId::BaseTranslation));
        v.extend((0..3).map(ParamId::BaseRotation));
    }
    if tool {
        v.extend((0..3).map(ParamId::Tool));
    }
    v
}

/// Apply a step `delta` (one entry per `params`) to a model.
pub fn retract(model: &RobotModel, params: &[ParamId], delta: &[f64]) -> RobotModel {
    let mut m = model.clone();
    let mut rot = Vector3::zeros();
    for (p, d) in params.iter().zip(delta) {
        match p {
            ParamId::Mdh { joint, kind } => *m.joints[*joint].get_mut(*kind) += d,
            ParamId::BaseTranslation(i) => m.base_translation[*i] += d,
            ParamId::BaseRotation(i) => rot[*i] += d,
            ParamId::Tool(i) => m.tool[*i] += d,
            ParamId::StageAxis(_) => {}
        }
    }
    if rot != Vector3::zeros() {
        m.base_rotation = from_rotation_vector(&rot) * m.base_rotation;
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names() {
        let v = all_params(6, true, true);
        assert_eq!(v.len(), 39);
        assert_eq!(v[0].name(), "theta1");
        assert_eq!(v[29].name(), "beta6");
        assert_eq!(v[30].name(), "base_tx");
        assert_eq!(v[35].name(), "base_rz");
        assert_eq!(v[38].name(), "tool_z");
    }
}
