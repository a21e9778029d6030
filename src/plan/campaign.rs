//! Campaign planning: poses in the workspace box that the tracker can see, the fixed
//! identification/verification split, a drift reference pose, and a move order that shortens
//! robot travel. Pure and seeded.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::order::{nearest_neighbour_order, travel};
use super::path::{wrist_side, PathChecker};
use super::route::{RouteError, Router};
use super::sampling::{sample_poses_where, PlanError};
use super::selection::{select, Design, DesignSetup, NoiseModel, Selection, SelectionError};
use super::workspace::Workspace;
use crate::dataset::PoseSet;
use crate::model::kinematics::{forward, Pose};
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
    /// The drift reference is measured again every this many poses (0 = start and end only);
    /// the return moves count in [`Plan::via_points`].
    pub drift_every: usize,
    /// How the identification poses are chosen (the verification poses are always random).
    pub selection: Selection,
    /// What [`Selection::Optimal`] designs the identification for.
    pub design: DesignSetup,
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
    /// Drift reference pose (rad): measured at the start, every N poses and at the end; the
    /// hub of every route.
    pub drift_reference: Vec<f64>,
    /// Via points the campaign's moves need (for the operator; the engine routes every move
    /// again from the robot's actual joints).
    pub via_points: usize,
    /// Pre-pose of a pose index: the last via point of every move to it, reached by the
    /// route and left by a direct checked move (ISO 9283 unidirectional approach); empty for
    /// calibration plans.
    pub approach: std::collections::BTreeMap<usize, Vec<f64>>,
}

/// Whether the target ball at `q` faces the tracker within the limit.
pub fn line_of_sight_ok(model: &RobotModel, q: &[f64], req: &PlanRequest) -> bool {
    if req.line_of_sight_max_rad >= std::f64::consts::PI {
        return true;
    }
    facing_tracker(forward(model, q).flange(), req)
}

/// [`line_of_sight_ok`] of the flange pose `fl`.
fn facing_tracker(fl: &Pose, req: &PlanRequest) -> bool {
    if req.line_of_sight_max_rad >= std::f64::consts::PI {
        return true;
    }
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

/// Plan a campaign on the nominal model.
///
/// Candidates are sampled until `poses + 1` pass [`target_ok`]; only those with the wrist bent
/// to the positive side (see [`wrist_side`]; TX60: q5 > 0) are kept, since a joint move between
/// the two sides crosses the wrist singularity (a robot starting on the other side gets no
/// route: jog it over first); the drift reference is the hub of every route (see [`choose_hub`]);
/// a pose is kept when the direct move between it and the drift reference passes the path
/// check, so every move of the campaign has a route (direct, or through the drift reference).
/// The first `ident` poses in sampling order identify; the move order is greedy nearest
/// neighbour from the drift reference, and [`Plan::via_points`] counts the via points of every
/// move the engine makes (drift reference first, returns to it every `drift_every` poses and at
/// the end). O(n log n) for the order, O(n) path checks otherwise.
pub fn plan_campaign(model: &RobotModel, req: &PlanRequest) -> Result<Plan, PlanError> {
    let mut rng = ChaCha8Rng::seed_from_u64(req.seed);
    let Pool {
        hub: drift_reference,
        side,
        poses: mut kept,
    } = measurable_pool(model, req, req.poses, &mut rng)?;
    if req.selection == Selection::Optimal {
        let ident = choose_ident(model, req, &drift_reference, side, &mut rng)?;
        for (slot, q) in kept.iter_mut().zip(ident) {
            *slot = q;
        }
    }
    let order = nearest_neighbour_order(&drift_reference, &kept);
    let poses: Vec<PlanEntry> = order
        .into_iter()
        .map(|index| PlanEntry {
            index,
            set: if index < req.ident {
                PoseSet::Ident
            } else {
                PoseSet::Verify
            },
            q_rad: std::mem::take(&mut kept[index]),
        })
        .collect();
    let mut router = Router::new(model, &req.workspace, &req.tool_mm, &drift_reference)?;
    let via_points = count_via_points(&mut router, req.drift_every, &poses)?;
    Ok(Plan {
        poses,
        drift_reference,
        via_points,
        approach: Default::default(),
    })
}

/// Configurations a campaign can measure: each passes [`target_ok`], has its wrist bent to
/// `side` and a direct move to and from `hub` that passes the path check (so a route).
#[derive(Debug, Clone, PartialEq)]
pub struct Pool {
    /// The hub of every route, the drift reference (rad).
    pub hub: Vec<f64>,
    /// The wrist side every pose keeps ([`wrist_side`]; `None`: no wrist check).
    pub side: Option<bool>,
    /// The poses, in sampling order (rad).
    pub poses: Vec<Vec<f64>>,
}

/// `n` measurable configurations and their hub, drawn from `rng` as [`plan_campaign`] draws
/// them (the same seed, the same poses).
pub fn measurable_pool(
    model: &RobotModel,
    req: &PlanRequest,
    n: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Pool, PlanError> {
    let wanted = n + 1;
    let first = candidates(model, req, wanted, None, rng)?;
    let side = preferred_wrist_side(&first);
    let mut found: Vec<Candidate> = first.into_iter().filter(|c| c.side == side).collect();
    let mut checker = PathChecker::new(model, &req.workspace, &req.tool_mm);
    let hub_i = choose_hub(&mut checker, &found).ok_or(PlanError::Unreachable {
        found: 0,
        wanted,
        tried: wanted,
    })?;
    let hub = found.remove(hub_i).q;
    let poses = fill(model, req, &mut checker, &hub, side, found, n, rng)?;
    Ok(Pool { hub, side, poses })
}

/// `n` more measurable configurations around a pool's `hub` and `side`.
pub fn more_measurable(
    model: &RobotModel,
    req: &PlanRequest,
    hub: &[f64],
    side: Option<bool>,
    n: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let mut checker = PathChecker::new(model, &req.workspace, &req.tool_mm);
    fill(model, req, &mut checker, hub, side, Vec::new(), n, rng)
}

/// `n` configurations with a passing direct move to `hub`: those of `found` first, then new
/// draws (at most 200 × (n + 1) in all).
#[allow(clippy::too_many_arguments)]
fn fill(
    model: &RobotModel,
    req: &PlanRequest,
    checker: &mut PathChecker,
    hub: &[f64],
    side: Option<bool>,
    mut found: Vec<Candidate>,
    n: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let wanted = n + 1;
    let mut drawn = wanted;
    let mut kept: Vec<Vec<f64>> = Vec::with_capacity(n);
    loop {
        let need = n - kept.len();
        kept.extend(
            found
                .drain(..)
                .map(|c| c.q)
                .filter(|q| checker.check_move(q, hub).is_ok())
                .take(need),
        );
        let need = n - kept.len();
        if need == 0 {
            return Ok(kept);
        }
        if drawn > 200 * wanted {
            return Err(PlanError::Unreachable {
                found: kept.len() + 1,
                wanted,
                tried: drawn,
            });
        }
        found = candidates(model, req, need, side, rng)?;
        drawn += need;
    }
}

/// Candidate poses per identification pose in a campaign's pool ([`Selection::Optimal`]).
pub const POOL_PER_IDENT: usize = 20;
/// Least and largest pool of a campaign (poses).
pub const POOL_RANGE: (usize, usize) = (500, 2000);
/// Random workspace poses the criterion's weight `W` is the mean over.
pub const REFERENCE_POSES: usize = 300;

/// The design a plan's identification is selected for: the nominal model in the robot base
/// frame (the criterion does not depend on the frame) with the ball as its tool, the tracker
/// at `req.tracker_mm`, parameters identifiable on `poses`.
pub fn plan_design(
    model: &RobotModel,
    req: &PlanRequest,
    poses: &[Vec<f64>],
) -> Result<Design, SelectionError> {
    let mut m = model.clone();
    m.base_rotation = nalgebra::Matrix3::identity();
    m.base_translation = Vector3::zeros();
    m.tool = req.tool_mm;
    let d = &req.design;
    let mut noise = NoiseModel::at960_scaled(req.tracker_mm, d.noise_mm);
    noise.joint_jitter_rad = d.joint_jitter_rad;
    Design::new(
        m,
        d.obs,
        d.stage_travel_mm,
        noise,
        d.identify_base,
        d.identify_tool,
        poses,
    )
}

/// The identification poses of an optimal plan, in rank order: selected from a pool drawn
/// around the plan's hub, weighed by a reference draw of its own seed (never the plan's
/// verification poses).
fn choose_ident(
    model: &RobotModel,
    req: &PlanRequest,
    hub: &[f64],
    side: Option<bool>,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let size = (POOL_PER_IDENT * req.ident).clamp(POOL_RANGE.0, POOL_RANGE.1);
    let pool = more_measurable(model, req, hub, side, size, rng)?;
    let mut ref_rng = ChaCha8Rng::seed_from_u64(req.seed ^ REFERENCE_SEED);
    let reference = more_measurable(model, req, hub, side, REFERENCE_POSES, &mut ref_rng)?;
    let design = plan_design(model, req, &pool).map_err(PlanError::Selection)?;
    let chosen = select(&design, &pool, req.ident, &reference).map_err(PlanError::Selection)?;
    Ok(chosen.indices.iter().map(|&k| pool[k].clone()).collect())
}

/// Mixed into the plan's seed for the criterion's reference draw.
const REFERENCE_SEED: u64 = 0x5e1e_c7ed_0f_u64;

/// A sampled configuration that passes [`target_ok`], with what planning needs of its frames.
struct Candidate {
    /// Joints (rad).
    q: Vec<f64>,
    /// Its wrist side ([`wrist_side`]).
    side: Option<bool>,
    /// Distance of the flange from the box centre (mm).
    centre_mm: f64,
}

/// `n` sampled configurations that pass [`target_ok`] with their wrist bent to `side` (any side
/// when `None`), in sampling order.
fn candidates(
    model: &RobotModel,
    req: &PlanRequest,
    n: usize,
    side: Option<bool>,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Candidate>, PlanError> {
    let centre = req.workspace.center_mm;
    let mut info = Vec::with_capacity(n);
    let max_tries = 1000 * n.max(1) + 100_000;
    let qs = sample_poses_where(model, &req.workspace, n, rng, max_tries, |_, f| {
        let s = wrist_side(f);
        let keep = side.is_none_or(|w| s == Some(w)) && facing_tracker(f.flange(), req);
        if keep {
            info.push((s, (f.flange().p - centre).norm()));
        }
        keep
    })?;
    Ok(qs
        .into_iter()
        .zip(info)
        .map(|(q, (side, centre_mm))| Candidate { q, side, centre_mm })
        .collect())
}

/// The wrist side a plan keeps: the positive side (Stäubli TX60: q5 > 0, where the simulated
/// robot and the usual home poses are) when any candidate is bent to it, else the negative one;
/// `None` for arms without a wrist check.
fn preferred_wrist_side(cs: &[Candidate]) -> Option<bool> {
    if cs.iter().any(|c| c.side == Some(true)) {
        Some(true)
    } else if cs.iter().any(|c| c.side == Some(false)) {
        Some(false)
    } else {
        None
    }
}

/// Candidates tried as the hub: the nearest the box centre.
const HUB_CANDIDATES: usize = 16;
/// Poses each hub candidate is tried against.
const HUB_PROBES: usize = 64;

/// Index of the hub among `qs`: of the [`HUB_CANDIDATES`] configurations whose flange is nearest
/// the box centre, the one with a passing direct move to the most of the first [`HUB_PROBES`]
/// (ties: the nearer the centre).
fn choose_hub(checker: &mut PathChecker, cs: &[Candidate]) -> Option<usize> {
    let mut by_distance: Vec<(f64, usize)> = cs.iter().map(|c| c.centre_mm).zip(0..).collect();
    let k = HUB_CANDIDATES.min(by_distance.len());
    if k == 0 {
        return None;
    }
    by_distance.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    by_distance.truncate(k);
    by_distance.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let probes = &cs[..HUB_PROBES.min(cs.len())];
    let mut best: Option<(usize, usize)> = None;
    for &(_, i) in &by_distance {
        let reached = probes
            .iter()
            .filter(|p| checker.check_move(&cs[i].q, &p.q).is_ok())
            .count();
        if best.is_none_or(|(r, _)| reached > r) {
            best = Some((reached, i));
        }
    }
    best.map(|(_, i)| i)
}

/// Via points of every move the engine makes for `poses` (in move order), the router's hub
/// being the drift reference: hub → first pose, pose to pose, back to the hub after every
/// `drift_every` poses (not after the last) and at the end.
pub fn count_via_points(
    router: &mut Router,
    drift_every: usize,
    poses: &[PlanEntry],
) -> Result<usize, RouteError> {
    let hub = router.hub().to_vec();
    let mut at = hub.clone();
    let mut vias = 0;
    for (done, p) in poses.iter().enumerate().map(|(i, p)| (i + 1, p)) {
        vias += router.route(&at, &p.q_rad)?.len();
        at.clone_from(&p.q_rad);
        if drift_every > 0 && done % drift_every == 0 && done < poses.len() {
            vias += router.route(&at, &hub)?.len();
            at.clone_from(&hub);
        }
    }
    Ok(vias + router.route(&at, &hub)?.len())
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
    use crate::model::tx60;

    fn req() -> PlanRequest {
        PlanRequest {
            workspace: Workspace::default(),
            poses: 60,
            ident: 20,
            seed: 5,
            tracker_mm: Vector3::new(2550.0, 0.0, 0.0),
            line_of_sight_max_rad: 80f64.to_radians(),
            tool_mm: Vector3::zeros(),
            drift_every: 20,
            selection: Selection::Random,
            design: DesignSetup::default(),
        }
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
