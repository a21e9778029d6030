//! Joint-space sampling with rejection: a configuration is kept when it is inside the joint
//! limits, its flange origin lies inside the workspace box (robot base frame), the wrist is at
//! least `wrist_min` away from the singularity (angle between axes 4 and 6 for a 6-axis arm),
//! and every frame origin is above the floor. Pure and seeded.

use nalgebra::Vector3;
use rand::Rng;

use super::path::wrist_angle_rad;
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

/// Why sampling failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// Too few configurations satisfied the constraints.
    #[error(
        "only {found} of {wanted} poses found in {tried} tries: is the workspace box reachable?"
    )]
    Unreachable {
        /// Poses found.
        found: usize,
        /// Poses wanted.
        wanted: usize,
        /// Configurations tried.
        tried: usize,
    },
    /// A move of the plan has no route (see [`super::route`]).
    #[error("no route: {0}")]
    Route(#[from] super::route::RouteError),
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

/// Sample `n` configurations uniformly in the joint limits, keeping those the workspace accepts.
pub fn sample_poses<R: Rng>(
    model: &RobotModel,
    ws: &Workspace,
    n: usize,
    rng: &mut R,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let max_tries = 5000 * n.max(1) + 100_000;
    sample_poses_where(model, ws, n, rng, max_tries, |_, _| true)
}

/// [`sample_poses`] keeping only the accepted configurations that `keep` also accepts (given
/// their frames), within `max_tries` draws. The draws do not depend on `keep`.
pub fn sample_poses_where<R: Rng>(
    model: &RobotModel,
    ws: &Workspace,
    n: usize,
    rng: &mut R,
    max_tries: usize,
    mut keep: impl FnMut(&[f64], &Frames) -> bool,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let mut out = Vec::with_capacity(n);
    let mut frames = Frames::new();
    let mut tried = 0;
    while out.len() < n {
        if tried >= max_tries {
            return Err(PlanError::Unreachable {
                found: out.len(),
                wanted: n,
                tried,
            });
        }
        tried += 1;
        let q: Vec<f64> = model
            .limits
            .iter()
            .map(|l| rng.random_range(l.min..=l.max))
            .collect();
        if ws.accepts_into(model, &q, &mut frames) && keep(&q, &frames) {
            out.push(q);
        }
    }
    Ok(out)
}
