//! Campaign planning: poses in the workspace box that the tracker can see, the fixed
//! identification/verification split, a drift reference pose, and a measuring order that
//! shortens the campaign's time ([`order_plan`]). Pure and seeded.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::order::{order_by_time, tour_s, travel, Legs, MotionLimits};
use super::path::{wrist_side, PathChecker};
use super::route::{RouteError, Router};
use super::sampling::{sample_poses_where, PlanError};
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
    /// `Some(k)`: the identification poses first, in blocks of `k` in index order (a
    /// selection's ranking), each block in time order, then the verification poses; `None`:
    /// one tour over all poses.
    pub ident_block: Option<usize>,
    /// Robot speed setting the legs are timed at (%, `robot_controller.speed_pct`).
    pub speed_pct: f64,
    /// Settle time after every move (s).
    pub settle_s: f64,
    /// The ball's displacement from P1 to P2 in the flange frame (mm; stage axis × travel):
    /// the robot moves with the stage at either, so every move is checked with the ball at
    /// both (zero: at P1 only).
    pub stage_offset_mm: Vector3<f64>,
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
    /// Move and settle time of the measuring legs (drift returns included) in sampling order,
    /// identification poses first (s; [`order_times`]); 0 for ISO 9283 plans.
    pub sampling_order_s: f64,
    /// The same in the planned order (s): `sampling_order_s − planned_order_s` is the time
    /// the order saves.
    pub planned_order_s: f64,
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
/// Every move is checked with the ball at P1 and at P2 ([`campaign_checker`]). The first
/// `ident` poses in sampling order identify; the measuring order is [`order_plan`]'s (by time,
/// in the blocks of [`PlanRequest::ident_block`]), and [`Plan::via_points`] counts the via
/// points of every move the engine makes (drift reference first, returns to it every
/// `drift_every` poses and at the end). O(n log n) for the nearest-neighbour order and the
/// neighbour lists of 2-opt, O(n) path checks otherwise (2-opt: a few per pose).
pub fn plan_campaign(model: &RobotModel, req: &PlanRequest) -> Result<Plan, PlanError> {
    let mut rng = ChaCha8Rng::seed_from_u64(req.seed);
    let wanted = req.poses + 1;
    let first = candidates(model, req, wanted, None, &mut rng)?;
    let side = preferred_wrist_side(&first);
    let mut found: Vec<Candidate> = first.into_iter().filter(|c| c.side == side).collect();
    let mut checker = campaign_checker(model, req);
    let hub_i = choose_hub(&mut checker, &found).ok_or(PlanError::Unreachable {
        found: 0,
        wanted,
        tried: wanted,
    })?;
    let drift_reference = found.remove(hub_i).q;
    let mut drawn = wanted;
    let mut kept: Vec<Vec<f64>> = Vec::with_capacity(req.poses);
    loop {
        let need = req.poses - kept.len();
        kept.extend(
            found
                .drain(..)
                .map(|c| c.q)
                .filter(|q| checker.check_move(q, &drift_reference).is_ok())
                .take(need),
        );
        let need = req.poses - kept.len();
        if need == 0 {
            break;
        }
        if drawn > 200 * wanted {
            return Err(PlanError::Unreachable {
                found: kept.len() + 1,
                wanted,
                tried: drawn,
            });
        }
        found = candidates(model, req, need, side, &mut rng)?;
        drawn += need;
    }
    let mut router = campaign_router(model, req, &drift_reference)?;
    let ordered = order_plan(model, req, &mut router, kept);
    let via_points = count_via_points(&mut router, req.drift_every, &ordered.poses)?;
    Ok(Plan {
        poses: ordered.poses,
        drift_reference,
        via_points,
        approach: Default::default(),
        sampling_order_s: ordered.sampling_order_s,
        planned_order_s: ordered.planned_order_s,
    })
}

/// The path checker of a campaign's moves: `req`'s workspace, the ball at P1 and at P2
/// ([`PlanRequest::stage_offset_mm`]).
pub fn campaign_checker(model: &RobotModel, req: &PlanRequest) -> PathChecker {
    PathChecker::new(model, &req.workspace, &req.tool_mm).with_ball_at_p2(&req.stage_offset_mm)
}

/// The router of a campaign's moves through `hub` with [`campaign_checker`].
pub fn campaign_router(
    model: &RobotModel,
    req: &PlanRequest,
    hub: &[f64],
) -> Result<Router, RouteError> {
    Router::with_checker(campaign_checker(model, req), hub)
}

/// A measuring order and what it saves.
#[derive(Debug, Clone, PartialEq)]
pub struct OrderedPlan {
    /// Poses in measuring order.
    pub poses: Vec<PlanEntry>,
    /// [`Plan::sampling_order_s`].
    pub sampling_order_s: f64,
    /// Greedy nearest-neighbour order's time (s), before 2-opt.
    pub nearest_neighbour_s: f64,
    /// [`Plan::planned_order_s`].
    pub planned_order_s: f64,
}

/// The blocks of pose indices measured one after the other: one of every pose, or (with
/// [`PlanRequest::ident_block`]) the identification poses `0..ident` in blocks of `k`, then the
/// verification poses.
fn order_blocks(req: &PlanRequest, n: usize) -> Vec<Vec<usize>> {
    let ident = req.ident.min(n);
    match req.ident_block {
        None => vec![(0..n).collect()],
        Some(k) => {
            let mut blocks: Vec<Vec<usize>> = (0..ident)
                .step_by(k.max(1))
                .map(|lo| (lo..(lo + k.max(1)).min(ident)).collect())
                .collect();
            if ident < n {
                blocks.push((ident..n).collect());
            }
            blocks
        }
    }
}

/// Order the poses `kept` (index = pose index; identification poses are those below
/// `req.ident`) by time through `router`'s hub ([`order_by_time`]: nearest neighbour, then 2-opt,
/// on leg time at `req.speed_pct` with `req.settle_s` per stop, routes included), in the blocks
/// of [`PlanRequest::ident_block`].
pub fn order_plan(
    model: &RobotModel,
    req: &PlanRequest,
    router: &mut Router,
    kept: Vec<Vec<f64>>,
) -> OrderedPlan {
    let limits = MotionLimits::of(model, req.speed_pct);
    let blocks = order_blocks(req, kept.len());
    let sampling: Vec<usize> = blocks.iter().flatten().copied().collect();
    let mut legs = Legs::new(&kept, router, &limits, req.settle_s);
    let (nn, order) = order_by_time(&mut legs, &blocks, req.drift_every);
    let sampling_order_s = tour_s(&mut legs, &sampling, req.drift_every);
    let nearest_neighbour_s = tour_s(&mut legs, &nn, req.drift_every);
    let planned_order_s = tour_s(&mut legs, &order, req.drift_every);
    let mut kept = kept;
    let poses = order
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
    OrderedPlan {
        poses,
        sampling_order_s,
        nearest_neighbour_s,
        planned_order_s,
    }
}

/// Move and settle time (s) of the measuring legs of `poses` in sampling order (identification
/// poses first, each set in index order) and in the given order, through `router`'s hub, at
/// `req`'s speed and settle: ([`Plan::sampling_order_s`], [`Plan::planned_order_s`]).
pub fn order_times(
    model: &RobotModel,
    req: &PlanRequest,
    router: &mut Router,
    poses: &[PlanEntry],
) -> (f64, f64) {
    let limits = MotionLimits::of(model, req.speed_pct);
    let points: Vec<Vec<f64>> = poses.iter().map(|p| p.q_rad.clone()).collect();
    let mut sampling: Vec<usize> = (0..poses.len()).collect();
    sampling.sort_by_key(|&k| (poses[k].set != PoseSet::Ident, poses[k].index));
    let planned: Vec<usize> = (0..poses.len()).collect();
    let mut legs = Legs::new(&points, router, &limits, req.settle_s);
    (
        tour_s(&mut legs, &sampling, req.drift_every),
        tour_s(&mut legs, &planned, req.drift_every),
    )
}

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
            ident_block: None,
            speed_pct: 20.0,
            settle_s: 1.5,
            stage_offset_mm: Vector3::new(0.0, 10.0, 0.0),
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
