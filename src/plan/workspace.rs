//! The region a campaign's poses live in: a configuration is accepted when it is inside the
//! joint limits, its flange origin lies inside the workspace box (robot base frame), the wrist
//! is at least `wrist_min` away from the singularity (angle between axes 4 and 6 for a 6-axis
//! arm), and every frame origin is above the floor. Sampling, path checks and routes all hold
//! poses to it. Pure.

use nalgebra::Vector3;

use crate::model::kinematics::{forward_into, Frames};
use crate::model::RobotModel;

/// The region poses are sampled in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Workspace {
    /// Box centre in the robot base frame (mm).
    pub center_mm: Vector3<f64>,
    /// Box edge lengths (mm).
    pub size_mm: Vector3<f64>,
    /// Minimum wrist angle from the singular configuration (rad).
    pub wrist_min_rad: f64,
    /// Every frame origin must be above this height (mm).
    pub floor_z_mm: f64,
    /// How far beyond the box a move may sweep the flange and the ball (mm; [`super::path`]).
    pub path_margin_mm: f64,
}

impl Default for Workspace {
    /// The paper's 1000 mm cube at (550, 0, 550) mm, wrist ≥ 10°, floor at −300 mm, moves
    /// within 100 mm of the box.
    fn default() -> Self {
        Workspace {
            center_mm: Vector3::new(550.0, 0.0, 550.0),
            size_mm: Vector3::new(1000.0, 1000.0, 1000.0),
            wrist_min_rad: 10f64.to_radians(),
            floor_z_mm: -300.0,
            path_margin_mm: 100.0,
        }
    }
}

impl Workspace {
    /// Whether a configuration satisfies the workspace constraints (limits included).
    pub fn accepts(&self, model: &RobotModel, q: &[f64]) -> bool {
        self.accepts_into(model, q, &mut Frames::new())
    }

    /// [`Workspace::accepts`] computing the frames into reusable storage `f` (they stay there
    /// for further checks when the limits pass).
    pub fn accepts_into(&self, model: &RobotModel, q: &[f64], f: &mut Frames) -> bool {
        if !model.within_limits(q) {
            return false;
        }
        forward_into(&model.joints, q, f);
        let d = f.flange().p - self.center_mm;
        if (0..3).any(|k| d[k].abs() > 0.5 * self.size_mm[k]) {
            return false;
        }
        if f.frames[1..].iter().any(|fr| fr.p.z <= self.floor_z_mm) {
            return false;
        }
        wrist_angle_rad(f).is_none_or(|angle| angle >= self.wrist_min_rad)
    }
}

/// Angle between the axes of joints 4 and 6 of a 6-axis arm (rad, in [0, π/2]; 0 = singular
/// wrist); `None` for other arms. The same measure as [`Workspace::accepts`].
pub fn wrist_angle_rad(f: &Frames) -> Option<f64> {
    if f.frames.len() != 7 {
        return None;
    }
    let z4 = f.frames[3].r.column(2);
    let z6 = f.frames[5].r.column(2);
    Some(z4.dot(&z6).abs().min(1.0).acos())
}
