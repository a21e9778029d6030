//! Campaign planning: poses in the workspace box that the tracker can see, the fixed
//! identification/verification split, a drift reference pose, and a move order that shortens
//! robot travel. Pure and seeded.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::sampling::{sample_poses, PlanError, Workspace};
use crate::dataset::PoseSet;
use crate::model::kinematics::forward;
use crate::model::RobotModel;

/// What to plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanRequest {
    /// Region and wrist/floor constraints.
    pub workspace: Workspace,
    /// Total poses.
    pub poses: usize,
    /// Identification poses.
    pub ident: usize,
    /// Seed.
    pub seed: u64,
    /// Tracker position in the robot base frame (mm).
    pub tracker_mm: Vector3<f64>,
    /// Maximum angle between the ball's opening (flange +z) and the line to the tracker (rad).
    pub line_of_sight_max_rad: f64,
    /// Ball position in the flange frame (mm).
    pub tool_mm: Vector3<f64>,
}

/// One planned pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanEntry {
    /// Pose index (stable id; identification poses first).
    pub index: usize,
    /// Identification or verification.
    pub set: PoseSet,
    /// Joint target (rad).
    pub q_rad: Vec<f64>,
}

/// A campaign plan.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Poses in move order.
    pub poses: Vec<PlanEntry>,
    /// Drift reference pose (rad): measured at the start, every N poses and at the end.
    pub drift_reference: Vec<f64>,
}

/// Whether the target ball at `q` faces the tracker within the limit.
pub fn line_of_sight_ok(model: &RobotModel, q: &[f64], req: &PlanRequest) -> bool {
    if req.line_of_sight_max_rad >= std::f64::consts::PI {
        return true;
    }
    let f = forward(model, q);
    let fl = f.flange();
    let ball = fl.transform_point(&req.tool_mm);
    let to_tracker = req.tracker_mm - ball;
    let facing = fl.r.column(2);
    let c = facing.dot(&to_tracker) / to_tracker.norm().max(1e-9);
    c.clamp(-1.0, 1.0).acos() <= req.line_of_sight_max_rad
}

/// Whether a joint target passes every planning constraint (the campaign re-checks each move).
pub fn target_ok(model: &RobotModel, q: &[f64], req: &PlanRequest) -> bool {
    req.workspace.accepts(model, q) && line_of_sight_ok(model, q, req)
}

/// Time-like distance between two joint configurations: the largest joint travel (rad).
fn travel(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Plan a campaign on the nominal model.
pub fn plan_campaign(model: &RobotModel, req: &PlanRequest) -> Result<Plan, PlanError> {
    let mut rng = ChaCha8Rng::seed_from_u64(req.seed);
    let wanted = req.poses + 1;
    let mut found: Vec<Vec<f64>> = Vec::with_capacity(wanted);
    let mut tried = 0usize;
    while found.len() < wanted {
        let batch = sample_poses(model, &req.workspace, wanted - found.len(), &mut rng)?;
        tried += batch.len();
        found.extend(
            batch
                .into_iter()
                .filter(|q| line_of_sight_ok(model, q, req)),
        );
        if tried > 200 * wanted && found.len() < wanted {
            return Err(PlanError::Unreachable {
                found: found.len(),
                wanted,
                tried,
            });
        }
    }
    // drift reference: the candidate closest to the box centre
    let centre = req.workspace.center_mm;
    let (ref_i, _) = found
        .iter()
        .enumerate()
        .map(|(i, q)| (i, (forward(model, q).flange().p - centre).norm()))
        .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
    let drift_reference = found.remove(ref_i);
    // sampling order is random: the first `ident` are the identification set
    let entries: Vec<PlanEntry> = found
        .into_iter()
        .enumerate()
        .map(|(index, q_rad)| PlanEntry {
            index,
            set: if index < req.ident {
                PoseSet::Ident
            } else {
                PoseSet::Verify
            },
            q_rad,
        })
        .collect();
    // greedy nearest-neighbour order from the drift reference
    let mut left = entries;
    let mut order = Vec::with_capacity(left.len());
    let mut at = drift_reference.clone();
    while !left.is_empty() {
        let (k, _) = left
            .iter()
            .enumerate()
            .map(|(k, e)| (k, travel(&at, &e.q_rad)))
            .fold((0, f64::INFINITY), |a, b| if b.1 < a.1 { b } else { a });
        let e = left.swap_remove(k);
        at = e.q_rad.clone();
        order.push(e);
    }
    Ok(Plan {
        poses: order,
        drift_reference,
    })
}

/// Total robot travel of a move order (sum of largest joint travels, rad).
pub fn total_travel(start: &[f64], poses: &[PlanEntry]) -> f64 {
    let mut at = start;
    let mut sum = 0.0;
    for p in poses {
        sum += travel(at, &p.q_rad);
        at = &p.q_rad;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::parse_robot;

    fn req() -> PlanRequest {
        PlanRequest {
            workspace: Workspace::default(),
            poses: 60,
            ident: 20,
            seed: 5,
            tracker_mm: Vector3::new(2550.0, 0.0, 0.0),
            line_of_sight_max_rad: 80f64.to_radians(),
            tool_mm: Vector3::zeros(),
        }
    }

    fn tx60() -> RobotModel {
        parse_robot(
            include_str!("../../config/robots/staubli_tx60.toml"),
            std::path::Path::new("tx60"),
        )
        .unwrap()
    }

    #[test]
    fn plan_respects_constraints_and_split() {
        let m = tx60();
        let r = req();
        let p = plan_campaign(&m, &r).unwrap();
        assert_eq!(p.poses.len(), 60);
        assert_eq!(
            p.poses.iter().filter(|e| e.set == PoseSet::Ident).count(),
            20
        );
        let mut idx: Vec<usize> = p.poses.iter().map(|e| e.index).collect();
        idx.sort_unstable();
        assert_eq!(idx, (0..60).collect::<Vec<_>>());
        for e in &p.poses {
            assert!(target_ok(&m, &e.q_rad, &r));
        }
        assert!(target_ok(&m, &p.drift_reference, &r));
        assert_eq!(p, plan_campaign(&m, &r).unwrap(), "deterministic");
    }

    #[test]
    fn ordering_shortens_travel() {
        let m = tx60();
        let p = plan_campaign(&m, &req()).unwrap();
        let mut by_index = p.poses.clone();
        by_index.sort_by_key(|e| e.index);
        let ordered = total_travel(&p.drift_reference, &p.poses);
        let random = total_travel(&p.drift_reference, &by_index);
        assert!(ordered < 0.6 * random, "{ordered} vs {random}");
    }

    #[test]
    fn line_of_sight_rejects_ball_facing_away() {
        let m = tx60();
        let mut r = req();
        r.line_of_sight_max_rad = 1e-3;
        assert!(matches!(
            plan_campaign(&m, &r),
            Err(PlanError::Unreachable { .. })
        ));
    }
}
