//! Parameter identifiers and the parameter state (the robot model being corrected).
//!
//! MDH parameters are additive; the base rotation is updated by a left rotation
//! `R ← exp([δ]×) · R` about the robot base origin, expressed in the measurement frame;
//! base translation and tool are additive.

use nalgebra::Vector3;

use crate::model::rotation::from_rotation_vector;
use crate::model::{ParamKind, RobotModel, TermFamily, TermKind};

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
    /// A non-geometric coefficient of joint `joint` (0-based, §10): compliance or a harmonic.
    Term {
        /// Joint index (0-based).
        joint: usize,
        /// Which coefficient.
        kind: TermKind,
    },
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
            ParamId::Term { joint, kind } => format!("{}{}", kind.name(), joint + 1),
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

    /// Whether the parameter is an angle (rad); a compliance is not (rad/(N·m)).
    pub fn is_angle(&self) -> bool {
        match self {
            ParamId::Mdh { kind, .. } => kind.is_angle(),
            ParamId::BaseRotation(_) | ParamId::StageAxis(_) => true,
            ParamId::Term { kind, .. } => *kind != TermKind::Compliance,
            _ => false,
        }
    }

    /// Whether the parameter turns the chain (its column moves directions): every angle and
    /// every non-geometric term.
    pub fn is_rotation(&self) -> bool {
        self.is_angle() || matches!(self, ParamId::Term { .. })
    }

    /// Unit: `mm`, `rad` or, for a compliance, `rad/(N·m)`.
    pub fn unit(&self) -> &'static str {
        match self {
            ParamId::Term { kind, .. } => kind.unit(),
            _ if self.is_angle() => "rad",
            _ => "mm",
        }
    }

    /// Joint number (1-based) for MDH parameters and non-geometric terms.
    pub fn joint_number(&self) -> Option<usize> {
        match self {
            ParamId::Mdh { joint, .. } | ParamId::Term { joint, .. } => Some(joint + 1),
            _ => None,
        }
    }

    /// Whether the parameter is a non-geometric term (§10).
    pub fn is_term(&self) -> bool {
        matches!(self, ParamId::Term { .. })
    }

    /// Kind label for reports: `theta`, `d`, `a`, `alpha`, `beta`, `base_translation`, ….
    pub fn kind_name(&self) -> &'static str {
        match self {
            ParamId::Mdh { kind, .. } => kind.stem(),
            ParamId::BaseTranslation(_) => "base_translation",
            ParamId::BaseRotation(_) => "base_rotation",
            ParamId::Tool(_) => "tool_translation",
            ParamId::StageAxis(_) => "stage_axis_rotation",
            ParamId::Term { kind, .. } => kind.name(),
        }
    }

    /// The parameter of public name `name` ([`ParamId::name`]), `None` for no parameter.
    pub fn from_name(name: &str) -> Option<ParamId> {
        let axis = |t: &str| AXES.iter().position(|a| *a == t);
        if let Some(t) = name.strip_prefix("base_t") {
            return axis(t).map(ParamId::BaseTranslation);
        }
        if let Some(t) = name.strip_prefix("base_r") {
            return axis(t).map(ParamId::BaseRotation);
        }
        if let Some(t) = name.strip_prefix("tool_") {
            return axis(t).map(ParamId::Tool);
        }
        if let Some(t) = name.strip_prefix("stage_axis_r") {
            return axis(t).map(ParamId::StageAxis);
        }
        // longest names first: `sin_2q` before `sin_q` would not matter, `compliance` is unique
        for kind in TermKind::ALL {
            if let Some(number) = name.strip_prefix(kind.name()) {
                let joint = number.parse::<usize>().ok()?.checked_sub(1)?;
                let id = ParamId::Term { joint, kind };
                return (id.name() == name).then_some(id);
            }
        }
        let digits = name.find(|c: char| c.is_ascii_digit())?;
        let (stem, number) = name.split_at(digits);
        let kind = ParamKind::ALL.into_iter().find(|k| k.stem() == stem)?;
        let joint: usize = number.parse().ok()?;
        let joint = joint.checked_sub(1)?;
        // the name of what was parsed is the name given (no leading zeros, no sign)
        let id = ParamId::Mdh { joint, kind };
        (id.name() == name).then_some(id)
    }

    /// Current value in a model (base rotation and stage axis: 0, local perturbations).
    pub fn value(&self, m: &RobotModel) -> f64 {
        match self {
            ParamId::Mdh { joint, kind } => m.joints[*joint].get(*kind),
            ParamId::BaseTranslation(i) => m.base_translation[*i],
            ParamId::BaseRotation(_) | ParamId::StageAxis(_) => 0.0,
            ParamId::Tool(i) => m.tool[*i],
            ParamId::Term { joint, kind } => m.term(*joint, *kind),
        }
    }
}

/// Stored and sent by its public name ([`ParamId::name`]).
impl serde::Serialize for ParamId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.name())
    }
}

impl<'de> serde::Deserialize<'de> for ParamId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        ParamId::from_name(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("no parameter is named `{name}`")))
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

/// The non-geometric terms of `families` for every joint of a chain of `dof` joints (joint by
/// joint, in [`TermKind::ALL`] order); the identifiability analysis holds back those the poses
/// do not determine.
pub fn term_params(dof: usize, families: &[TermFamily]) -> Vec<ParamId> {
    (0..dof)
        .flat_map(|joint| {
            TermKind::ALL
                .into_iter()
                .filter(|k| families.contains(&k.family()))
                .map(move |kind| ParamId::Term { joint, kind })
        })
        .collect()
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
            ParamId::Term { joint, kind } => *m.term_mut(*joint, *kind) += d,
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
    fn every_name_parses_back_and_nothing_else_does() {
        for p in all_params(7, true, true)
            .into_iter()
            .chain((0..3).map(ParamId::StageAxis))
            .chain(term_params(7, &TermFamily::ALL))
        {
            assert_eq!(ParamId::from_name(&p.name()), Some(p), "{}", p.name());
        }
        for bad in [
            "",
            "theta",
            "theta0",
            "theta01",
            "theta+1",
            "base_tw",
            "tool_",
            "gamma1",
            "compliance",
            "compliance0",
            "sin_q01",
            "cos_2q",
            "sin_3q1",
        ] {
            assert_eq!(ParamId::from_name(bad), None, "{bad}");
        }
    }

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
