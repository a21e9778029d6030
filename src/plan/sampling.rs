//! Joint-space sampling with rejection: a configuration is kept when it is inside the joint
//! limits, its flange origin lies inside the workspace box (robot base frame), the wrist is at
//! least `wrist_min` away from the singularity (angle between axes 4 and 6 for a 6-axis arm),
//! and every frame origin is above the floor. Pure and seeded.

use nalgebra::Vector3;
use rand::Rng;

use crate::model::kinematics::forward;
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
}

impl Default for Workspace {
    /// The paper's 1000 mm cube at (550, 0, 550) mm, wrist ≥ 10°, floor at −300 mm.
    fn default() -> Self {
        Workspace {
            center_mm: Vector3::new(550.0, 0.0, 550.0),
            size_mm: Vector3::new(1000.0, 1000.0, 1000.0),
            wrist_min_rad: 10f64.to_radians(),
            floor_z_mm: -300.0,
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
}

impl Workspace {
    /// Whether a configuration satisfies the workspace constraints (limits included).
    pub fn accepts(&self, model: &RobotModel, q: &[f64]) -> bool {
        if !model.within_limits(q) {
            return false;
        }
        let f = forward(model, q);
        let d = f.flange().p - self.center_mm;
        if (0..3).any(|k| d[k].abs() > 0.5 * self.size_mm[k]) {
            return false;
        }
        if f.frames[1..].iter().any(|fr| fr.p.z <= self.floor_z_mm) {
            return false;
        }
        if model.dof() == 6 {
            let z4 = f.frames[3].r.column(2);
            let z6 = f.frames[5].r.column(2);
            let angle = z4.dot(&z6).abs().min(1.0).acos();
            if angle < self.wrist_min_rad {
                return false;
            }
        }
        true
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
    let mut out = Vec::with_capacity(n);
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
        if ws.accepts(model, &q) {
            out.push(q);
        }
    }
    Ok(out)
}
