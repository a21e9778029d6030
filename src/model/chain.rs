//! The modified Denavit–Hartenberg (Hayati) chain with base and tool transforms.
//!
//! Link transform: `A_i = RotZ(θ_i + q_i) · TransZ(d_i) · TransX(a_i) · RotX(α_i) · RotY(β_i)`;
//! measured point: `T_meas = T_base · A_1 ⋯ A_n · T_tool` (tool = translation of the ball in
//! the flange frame). Units: mm and rad.

use nalgebra::{Matrix3, Vector3};

use super::pose::Pose;

/// One joint's MDH parameters (θ offset and angles in rad, lengths in mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mdh {
    /// Joint-zero offset θ (rad).
    pub theta: f64,
    /// Offset along the previous z axis (mm).
    pub d: f64,
    /// Length along the common normal (mm).
    pub a: f64,
    /// Twist about x (rad).
    pub alpha: f64,
    /// Hayati twist about y (rad).
    pub beta: f64,
}

impl Mdh {
    /// Parameter value by kind.
    pub fn get(&self, kind: ParamKind) -> f64 {
        match kind {
            ParamKind::Theta => self.theta,
            ParamKind::D => self.d,
            ParamKind::A => self.a,
            ParamKind::Alpha => self.alpha,
            ParamKind::Beta => self.beta,
        }
    }

    /// Mutable parameter by kind.
    pub fn get_mut(&mut self, kind: ParamKind) -> &mut f64 {
        match kind {
            ParamKind::Theta => &mut self.theta,
            ParamKind::D => &mut self.d,
            ParamKind::A => &mut self.a,
            ParamKind::Alpha => &mut self.alpha,
            ParamKind::Beta => &mut self.beta,
        }
    }
}

/// The five MDH parameter kinds, in the per-joint order `[θ, d, a, α, β]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParamKind {
    /// Joint-zero offset (rad).
    Theta,
    /// Offset along z (mm).
    D,
    /// Length along x (mm).
    A,
    /// Twist about x (rad).
    Alpha,
    /// Twist about y (rad).
    Beta,
}

impl ParamKind {
    /// All kinds in the per-joint order.
    pub const ALL: [ParamKind; 5] = [
        ParamKind::Theta,
        ParamKind::D,
        ParamKind::A,
        ParamKind::Alpha,
        ParamKind::Beta,
    ];

    /// Name stem used in parameter names (`theta`, `d`, `a`, `alpha`, `beta`).
    pub fn stem(self) -> &'static str {
        match self {
            ParamKind::Theta => "theta",
            ParamKind::D => "d",
            ParamKind::A => "a",
            ParamKind::Alpha => "alpha",
            ParamKind::Beta => "beta",
        }
    }

    /// Whether the parameter is an angle (rad) rather than a length (mm).
    pub fn is_angle(self) -> bool {
        !matches!(self, ParamKind::D | ParamKind::A)
    }

    /// Unit of the parameter.
    pub fn unit(self) -> &'static str {
        if self.is_angle() {
            "rad"
        } else {
            "mm"
        }
    }
}

/// Joint limits (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimit {
    /// Lower limit (rad).
    pub min: f64,
    /// Upper limit (rad).
    pub max: f64,
}

impl JointLimit {
    /// Whether `q` (rad) lies inside the limits.
    pub fn contains(&self, q: f64) -> bool {
        q >= self.min && q <= self.max
    }
}

/// A joint's motion limits from the robot file (`max_speed_deg_s`, `max_accel_deg_s2`), in
/// rad/s and rad/s²; `None` where the file gives none (the planner's timing model then uses
/// its stated fallback).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointMotion {
    /// Largest joint speed at 100 % (rad/s).
    pub max_speed: Option<f64>,
    /// Largest joint acceleration (rad/s²).
    pub max_accel: Option<f64>,
}

/// A serial robot: MDH chain, joint limits, base and tool transforms.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotModel {
    /// Display name.
    pub name: String,
    /// MDH parameters per joint.
    pub joints: Vec<Mdh>,
    /// Joint limits per joint.
    pub limits: Vec<JointLimit>,
    /// Speed and acceleration limits per joint (empty or `None`: the fallback).
    pub motion: Vec<JointMotion>,
    /// Rotation of the base transform (robot base → measurement frame).
    pub base_rotation: Matrix3<f64>,
    /// Translation of the base transform (mm).
    pub base_translation: Vector3<f64>,
    /// Target ball position in the flange frame (mm).
    pub tool: Vector3<f64>,
    /// Lumped masses of the gravity model (empty: no gravity torques).
    pub masses: Vec<super::gravity::Mass>,
    /// Direction of gravity in the robot base frame (unit; default −z).
    pub gravity: Vector3<f64>,
    /// Non-geometric terms per joint (empty or all zero: none, §10).
    pub terms: Vec<super::terms::JointTerms>,
    /// The MDH chain the gravity torques are computed on (`None`: `joints`): an identified
    /// model keeps the chain it was identified from, so its compliances mean what they were
    /// fitted to and the torques do not move with the identified geometry (§10).
    pub torque_chain: Option<Vec<Mdh>>,
}

impl RobotModel {
    /// The robot base in the measurement frame (measurement ← base).
    pub fn base(&self) -> Pose {
        Pose {
            r: self.base_rotation,
            p: self.base_translation,
        }
    }

    /// Set the base (measurement ← base).
    pub fn set_base(&mut self, base: Pose) {
        self.base_rotation = base.r;
        self.base_translation = base.p;
    }

    /// Number of joints.
    pub fn dof(&self) -> usize {
        self.joints.len()
    }

    /// Whether every joint value lies inside its limits.
    pub fn within_limits(&self, q: &[f64]) -> bool {
        q.len() == self.dof() && q.iter().zip(&self.limits).all(|(v, l)| l.contains(*v))
    }

    /// Whether any non-geometric coefficient is non-zero.
    pub fn has_terms(&self) -> bool {
        self.terms.iter().any(|t| !t.is_zero())
    }

    /// The MDH chain the gravity torques are computed on: [`torque_chain`](Self::torque_chain)
    /// or else the model's own joints.
    pub fn torque_joints(&self) -> &[Mdh] {
        self.torque_chain.as_deref().unwrap_or(&self.joints)
    }

    /// Whether the gravity torques are computed on the model's own joints.
    pub fn torques_on_own_chain(&self) -> bool {
        self.torque_chain.as_ref().is_none_or(|c| *c == self.joints)
    }

    /// Whether any joint has a non-zero compliance (the gravity torques are needed).
    pub fn has_compliance(&self) -> bool {
        self.terms.iter().any(|t| t.compliance != 0.0)
    }

    /// The coefficient `kind` of joint `joint` (0-based; 0 when the model has none).
    pub fn term(&self, joint: usize, kind: super::terms::TermKind) -> f64 {
        self.terms.get(joint).map_or(0.0, |t| t.get(kind))
    }

    /// The coefficient `kind` of joint `joint` (0-based), to change (the terms grow to one per
    /// joint).
    pub fn term_mut(&mut self, joint: usize, kind: super::terms::TermKind) -> &mut f64 {
        if self.terms.len() < self.dof() {
            self.terms
                .resize(self.dof(), super::terms::JointTerms::default());
        }
        self.terms[joint].get_mut(kind)
    }

    /// The same model with the base set to identity and the tool at the flange origin.
    pub fn bare(&self) -> RobotModel {
        RobotModel {
            base_rotation: Matrix3::identity(),
            base_translation: Vector3::zeros(),
            tool: Vector3::zeros(),
            ..self.clone()
        }
    }
}
