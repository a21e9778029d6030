//! Campaign planning: poses in the workspace box that the tracker can see, the fixed
//! identification/verification split, a drift reference pose, and a measuring order that
//! shortens the campaign's time ([`order_plan`]). Pure and seeded.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::motion::MotionLimits;
use super::order::{order_by_time, tour_s, travel, Legs};
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
    /// `Some(k)`: the identification poses first, in blocks of `k` in index order (a
    /// selection's ranking), each block in time order, then the verification poses; `None`:
    /// one tour over all poses.
    pub ident_block: Option<usize>,
    /// Robot speed setting the legs are timed at (%, `robot_controller.speed_pct`).
    pub speed_pct: f64,
    /// Every joint's speed at 100 % (rad/s), reached at once, when the robot moves so (a
    /// realistic simulated robot's `[sim] move_speed_deg_s`); `None`: the robot file's speeds and
    /// accelerations ([`MotionLimits::of`]). The legs are timed by these.
    pub move_speed_rad_s: Option<f64>,
    /// Settle time after every move (s).
    pub settle_s: f64,
    /// The ball's displacement from P1 to P2 in the flange frame (mm; stage axis × travel):
    /// the robot moves with the stage at either, so every move is checked with the ball at
    /// both (zero: at P1 only).
    pub stage_offset_mm: Vector3<f64>,
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
    /// Move and settle time of the measuring legs (drift returns included) in sampling order,
    /// identification poses first (s; [`order_times`]); 0 for ISO 9283 plans.
    pub sampling_order_s: f64,
    /// The same in the planned order (s): `sampling_order_s − planned_order_s` is the time
    /// the order saves.
    pub planned_order_s: f64,
}

impl PlanRequest {
    /// The joint limits the legs are timed by: [`PlanRequest::move_speed_rad_s`] for every
    /// joint when given, else the robot file's, at [`PlanRequest::speed_pct`].
    pub fn motion_limits(&self, model: &RobotModel) -> MotionLimits {
        match self.move_speed_rad_s {
            Some(v) => MotionLimits::uniform(model.dof(), v).at_speed_pct(self.speed_pct),
            None => MotionLimits::of(model, self.speed_pct),
        }
    }
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
/// on leg time by [`PlanRequest::motion_limits`] with `req.settle_s` per stop, routes included), in the blocks
/// of [`PlanRequest::ident_block`].
pub fn order_plan(
    model: &RobotModel,
    req: &PlanRequest,
    router: &mut Router,
    kept: Vec<Vec<f64>>,
) -> OrderedPlan {
    let limits = req.motion_limits(model);
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
    let limits = req.motion_limits(model);
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
    let mut checker = campaign_checker(model, req);
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
    let mut checker = campaign_checker(model, req);
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
pub const POOL_PER_IDENT: usize = 10;
/// Least and largest pool of a campaign (poses).
pub const POOL_RANGE: (usize, usize) = (500, 1000);
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
pub const REFERENCE_SEED: u64 = 0x005e_1ec7_ed0f_u64;

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
            move_speed_rad_s: None,
            settle_s: 1.5,
            stage_offset_mm: Vector3::new(0.0, 10.0, 0.0),
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

    /// 2-opt starts from the nearest-neighbour order and keeps a move only when it shortens
    /// the tour: never longer, over seeds, drift intervals and identification blocks.
    #[test]
    fn two_opt_never_lengthens_the_nearest_neighbour_order() {
        let m = tx60();
        let mut shorter = 0;
        for (seed, drift_every, block) in [
            (1, 0, None),
            (2, 7, None),
            (3, 20, Some(8)),
            (4, 1, Some(5)),
            (5, 13, Some(30)),
        ] {
            let mut r = req();
            r.seed = seed;
            r.drift_every = drift_every;
            r.ident_block = block;
            let p = plan_campaign(&m, &r).unwrap();
            let hub = p.drift_reference.clone();
            let mut kept: Vec<PlanEntry> = p.poses.clone();
            kept.sort_by_key(|e| e.index);
            let kept = kept.into_iter().map(|e| e.q_rad).collect();
            let mut router = campaign_router(&m, &r, &hub).unwrap();
            let o = order_plan(&m, &r, &mut router, kept);
            assert!(
                o.planned_order_s <= o.nearest_neighbour_s + 1e-9,
                "seed {seed}: {} s after 2-opt, {} s before",
                o.planned_order_s,
                o.nearest_neighbour_s
            );
            assert_eq!(o.planned_order_s, p.planned_order_s);
            assert_eq!(o.sampling_order_s, p.sampling_order_s);
            // the reported times are those of the order (and of the sampling order)
            let (sampling, planned) = order_times(&m, &r, &mut router, &p.poses);
            assert!((planned - p.planned_order_s).abs() < 1e-9, "{planned}");
            assert!((sampling - p.sampling_order_s).abs() < 1e-9, "{sampling}");
            if o.planned_order_s < o.nearest_neighbour_s - 1.0 {
                shorter += 1;
            }
        }
        assert!(shorter >= 3, "2-opt shortened {shorter} of 5 orders");
    }

    /// `ident_block = Some(k)`: the identification poses first, block by block in index order
    /// (each block in its own time order), then the verification poses; `None`: one tour that
    /// mixes both.
    #[test]
    fn identification_blocks_come_first_each_ordered_by_time() {
        let m = tx60();
        let mut r = req();
        r.ident_block = Some(7);
        let p = plan_campaign(&m, &r).unwrap();
        let idx: Vec<usize> = p.poses.iter().map(|e| e.index).collect();
        for (lo, hi) in [(0, 7), (7, 14), (14, 20)] {
            let mut block = idx[lo..hi].to_vec();
            assert_ne!(
                block,
                (lo..hi).collect::<Vec<_>>(),
                "ordered, not as sampled"
            );
            block.sort_unstable();
            assert_eq!(block, (lo..hi).collect::<Vec<_>>());
        }
        assert!(idx[20..].iter().all(|&i| i >= 20));
        assert!(p.poses[..20].iter().all(|e| e.set == PoseSet::Ident));
        assert!(p.planned_order_s < p.sampling_order_s);
        let one_tour = plan_campaign(&m, &req()).unwrap();
        let first_verify = one_tour
            .poses
            .iter()
            .position(|e| e.set == PoseSet::Verify)
            .unwrap();
        assert!(first_verify < 20, "one tour over both sets");
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
    /// `selection = "optimal"` chooses only the identification poses: the verification poses
    /// are the random plan's, and every pose keeps to the plan's constraints.
    #[test]
    fn optimal_selection_keeps_the_random_verification_poses() {
        let m = tx60();
        let random = plan_campaign(&m, &req()).unwrap();
        let opt_req = PlanRequest {
            selection: Selection::Optimal,
            ..req()
        };
        let optimal = plan_campaign(&m, &opt_req).unwrap();
        let of = |p: &Plan, set: PoseSet| {
            let mut v: Vec<(usize, Vec<f64>)> = p
                .poses
                .iter()
                .filter(|e| e.set == set)
                .map(|e| (e.index, e.q_rad.clone()))
                .collect();
            v.sort_by_key(|e| e.0);
            v
        };
        assert_eq!(of(&random, PoseSet::Verify), of(&optimal, PoseSet::Verify));
        assert_eq!(of(&optimal, PoseSet::Ident).len(), 20);
        assert_ne!(of(&random, PoseSet::Ident), of(&optimal, PoseSet::Ident));
        assert_eq!(random.drift_reference, optimal.drift_reference);
        let mut checker = PathChecker::new(&m, &opt_req.workspace, &opt_req.tool_mm);
        for e in &optimal.poses {
            assert!(target_ok(&m, &e.q_rad, &opt_req));
            assert!(checker
                .check_move(&e.q_rad, &optimal.drift_reference)
                .is_ok());
        }
        assert_eq!(
            optimal,
            plan_campaign(&m, &opt_req).unwrap(),
            "deterministic"
        );
        // predicted: the selected identification poses beat the random ones
        let ident = |p: &Plan| -> Vec<Vec<f64>> {
            of(p, PoseSet::Ident).into_iter().map(|e| e.1).collect()
        };
        let verify: Vec<Vec<f64>> = of(&random, PoseSet::Verify)
            .into_iter()
            .map(|e| e.1)
            .collect();
        let d = plan_design(&m, &opt_req, &verify).unwrap();
        let figure = |set: &[Vec<f64>]| {
            crate::plan::selection::predicted_verification(&d, &d.covariance(set).unwrap(), &verify)
                .mean_mm
        };
        assert!(figure(&ident(&optimal)) < figure(&ident(&random)));
    }
}

/// Tests of `plan::selection` (here: they draw poses with the planner, which names selection).
#[cfg(test)]
mod selection_tests {
    use crate::identify::observation::{predict, ObsConfig, ObsModel};
    use crate::plan::selection::*;
    use nalgebra::DVector;
    use nalgebra::{DMatrix, Matrix3, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// `E‖x‖` against closed forms: isotropic `σ·2√(2/π)`, one axis `σ√(2/π)`, two equal axes
    /// `σ√(π/2)`.
    #[test]
    fn expected_norm_matches_closed_forms() {
        let s = 0.013;
        let iso = expected_norm(&(Matrix3::identity() * s * s));
        assert!((iso / (s * 2.0 * (2.0 / std::f64::consts::PI).sqrt()) - 1.0).abs() < 1e-9);
        let one = expected_norm(&Matrix3::from_diagonal(&Vector3::new(s * s, 0.0, 0.0)));
        assert!((one / (s * (2.0 / std::f64::consts::PI).sqrt()) - 1.0).abs() < 1e-9);
        let two = expected_norm(&Matrix3::from_diagonal(&Vector3::new(s * s, s * s, 0.0)));
        assert!((two / (s * (std::f64::consts::PI / 2.0).sqrt()) - 1.0).abs() < 1e-9);
        assert_eq!(expected_norm(&Matrix3::zeros()), 0.0);
    }

    /// The paper's TX60 setup: OP, stage +y 10 mm, ball at the flange origin, base identified,
    /// an AT960 at (2550, 0, 0) mm, the simulated cell's joint jitter.
    pub(crate) fn paper_design(poses: &[Vec<f64>]) -> Design {
        let mut noise = NoiseModel::at960_scaled(Vector3::new(2550.0, 0.0, 0.0), 0.015);
        noise.joint_jitter_rad = 1.2746e-5;
        Design::new(
            crate::model::tx60(),
            ObsConfig::new(ObsModel::Op, 10.0),
            10.0,
            noise,
            true,
            false,
            poses,
        )
        .unwrap()
    }

    pub(crate) fn random_poses(n: usize, seed: u64) -> Vec<Vec<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        crate::plan::sample_poses(
            &crate::model::tx60(),
            &crate::plan::Workspace::default(),
            n,
            &mut rng,
        )
        .unwrap()
    }

    fn gauss3(rng: &mut ChaCha8Rng) -> Vector3<f64> {
        Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal))
    }

    /// What a held-back parameter leaves, against the kinematics: a true arm off in `a5` alone
    /// by its prior error, read exactly at 40 identification poses, the other parameters
    /// fitted by Gauss–Newton on the solver's rows (from the nominal, to convergence): the
    /// fitted model's ball error at each verification pose is the bias's σ (one parameter:
    /// `B·e`, `e` = the prior). A parameter the kept ones mimic exactly (d1: the base's z
    /// takes it) leaves nothing.
    #[test]
    fn held_back_bias_is_what_the_fitted_parameters_leave_of_a_held_error() {
        use crate::identify::params::{retract, ParamId};
        use crate::model::ParamKind;
        let ident = random_poses(40, 1);
        let verify = random_poses(25, 2);
        let full = paper_design(&random_poses(200, 3));
        let a5 = ParamId::Mdh {
            joint: 4,
            kind: ParamKind::A,
        };
        assert!(full.params.contains(&a5));
        let mut kept = full.clone();
        kept.params.retain(|p| *p != a5);
        let e = prior_error(&a5);
        assert_eq!(e, 0.2);
        let truth = retract(&full.model, &[a5], &[e]);
        let measured: Vec<(Vector3<f64>, Vector3<f64>)> = ident
            .iter()
            .map(|q| {
                let pr = predict(&truth, q);
                (pr.p, pr.r * kept.obs.stage_axis)
            })
            .collect();
        let w = kept.obs.direction_weight_mm;
        let mut model = kept.model.clone();
        for _ in 0..5 {
            let fit = Design {
                model: model.clone(),
                ..kept.clone()
            };
            let k = fit.params.len();
            let (mut a, mut g) = (DMatrix::zeros(k, k), DVector::zeros(k));
            for (q, (p, l)) in ident.iter().zip(&measured) {
                let j = fit.jacobian(q);
                let pr = predict(&model, q);
                let lm = pr.r * fit.obs.stage_axis;
                let r = DVector::from_fn(6, |i, _| {
                    if i < 3 {
                        pr.p[i] - p[i]
                    } else {
                        w * (lm[i - 3] - l[i - 3])
                    }
                });
                a += j.transpose() * &j;
                g += j.transpose() * r;
            }
            let step = -a.cholesky().unwrap().solve(&g);
            model = retract(&model, &fit.params, step.as_slice());
        }
        let bias = held_back_bias(&kept, &[a5], &ident, &verify).unwrap();
        let mut absorbed = 0.0;
        for (q, b) in verify.iter().zip(&bias) {
            let err = (predict(&truth, q).p - predict(&model, q).p).norm();
            let predicted = b.trace().sqrt();
            assert!(
                (err - predicted).abs() < 0.01 * predicted + 1e-6,
                "ball error {err} mm, bias σ {predicted} mm"
            );
            absorbed += predicted
                / (full
                    .position_jacobian(q)
                    .column(full.params.iter().position(|p| *p == a5).unwrap())
                    .norm()
                    * e);
        }
        // the others absorb all but about 1 % of it (θ5 with the ball on the flange axis)
        let absorbed = absorbed / verify.len() as f64;
        assert!(absorbed > 1e-3 && absorbed < 0.05, "{absorbed}");
        // d1 is the base's z on every pose: nothing stays
        let d1 = ParamId::Mdh {
            joint: 0,
            kind: ParamKind::D,
        };
        assert!(!full.params.contains(&d1));
        let none = held_back_bias(&full, &[d1], &ident, &verify).unwrap();
        assert!(
            none.iter().all(|b| b.trace().sqrt() < 1e-9),
            "{:?}",
            none[0]
        );
    }

    /// The prediction against a Monte Carlo of the campaign's least squares, linearised in
    /// the parameters but with the physical noise: P1 and P2 read with the tracker's σ at
    /// their range, the direction normalised from them, the arm jittered once per pose, the
    /// verification readings with their own noise.
    #[test]
    fn predicted_verification_matches_a_monte_carlo_of_the_least_squares() {
        let ident = random_poses(40, 1);
        let verify = random_poses(30, 2);
        let d = paper_design(&random_poses(200, 3));
        let p = d.params.len();
        assert_eq!(
            p, 28,
            "OP with the base: 24 + 6 − 2 (base_tz ≡ d1, base_rz ≡ θ1)"
        );
        let cov = d.covariance(&ident).unwrap();
        let predicted = predicted_verification(&d, &cov, &verify);
        let js: Vec<DMatrix<f64>> = ident.iter().map(|q| d.jacobian(q)).collect();
        let a = js
            .iter()
            .fold(DMatrix::zeros(p, p), |a, j| a + j.transpose() * j);
        let solve = a.cholesky().unwrap();
        let jitter = |q: &[f64]| d.jitter_rows(q);
        let gi: Vec<DMatrix<f64>> = ident.iter().map(|q| jitter(q)).collect();
        let gv: Vec<DMatrix<f64>> = verify.iter().map(|q| jitter(q)).collect();
        let jv: Vec<DMatrix<f64>> = verify.iter().map(|q| d.position_jacobian(q)).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut sum, mut floor, draws) = (0.0, 0.0, 400);
        let sq = d.noise.joint_jitter_rad;
        let s = d.stage_travel_mm;
        for _ in 0..draws {
            let mut rhs = DVector::zeros(p);
            for (k, q) in ident.iter().enumerate() {
                let pr = predict(&d.model, q);
                let l = pr.r * d.obs.stage_axis;
                let p2 = pr.p + s * l;
                let e1 = gauss3(&mut rng) * d.noise.tracker.sigma_mm(&pr.p);
                let e2 = gauss3(&mut rng) * d.noise.tracker.sigma_mm(&p2);
                let dq = DVector::from_fn(6, |_, _| rng.sample::<f64, _>(StandardNormal) * sq);
                // the arm sits at q + dq: its rows move as the θ columns say
                let moved = &gi[k] * dq;
                let m1 = pr.p + Vector3::new(moved[0], moved[1], moved[2]) + e1;
                let lm = l + Vector3::new(moved[3], moved[4], moved[5]) / d.obs.direction_weight_mm;
                let m2 = m1 - e1 + s * lm + e2;
                let dir = (m2 - m1).normalize();
                let mut r = DVector::zeros(6);
                for i in 0..3 {
                    r[i] = pr.p[i] - m1[i];
                    r[3 + i] = d.obs.direction_weight_mm * (l[i] - dir[i]);
                }
                rhs += js[k].transpose() * r;
            }
            // the residual is model − measurement: the fitted correction is −(JᵀJ)⁻¹Jᵀr,
            // and the model's error after it is its negative
            let delta = solve.solve(&rhs);
            let (mut m, mut f) = (0.0, 0.0);
            for (k, q) in verify.iter().enumerate() {
                let dq = DVector::from_fn(6, |_, _| rng.sample::<f64, _>(StandardNormal) * sq);
                let moved = gv[k].rows(0, 3) * dq;
                let noise = Vector3::new(moved[0], moved[1], moved[2])
                    + gauss3(&mut rng) * d.tracker_sigma_mm(q);
                let par = &jv[k] * &delta;
                m += (Vector3::new(par[0], par[1], par[2]) + noise).norm();
                f += noise.norm();
            }
            sum += m / verify.len() as f64;
            floor += f / verify.len() as f64;
        }
        let (mc, mc_floor) = (sum / draws as f64, floor / draws as f64);
        assert!(
            (predicted.mean_mm / mc - 1.0).abs() < 0.02,
            "predicted {} mm, Monte Carlo {mc} mm",
            predicted.mean_mm
        );
        assert!(
            (predicted.noise_floor_mm / mc_floor - 1.0).abs() < 0.02,
            "predicted floor {} mm, Monte Carlo {mc_floor} mm",
            predicted.noise_floor_mm
        );
        assert!(predicted.mean_mm > 1.05 * predicted.noise_floor_mm);
    }
    /// The paper's cell: the pool, a reference draw and a verification draw, each measurable
    /// (line of sight unlimited, as `[campaign]`'s default).
    /// Pool, reference and verification joints.
    type Cell = (Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>);

    fn paper_cell(pool: usize) -> Cell {
        use crate::plan::campaign::{measurable_pool, more_measurable};
        let req = crate::plan::PlanRequest {
            workspace: crate::plan::Workspace::default(),
            poses: pool,
            ident: 1,
            seed: 4802,
            tracker_mm: Vector3::new(2550.0, 0.0, 0.0),
            line_of_sight_max_rad: std::f64::consts::PI,
            tool_mm: Vector3::zeros(),
            drift_every: 0,
            ident_block: None,
            speed_pct: 20.0,
            move_speed_rad_s: None,
            settle_s: 0.0,
            stage_offset_mm: Vector3::new(0.0, 10.0, 0.0),
            selection: Selection::Random,
            design: DesignSetup::default(),
        };
        let m = crate::model::tx60();
        let mut rng = ChaCha8Rng::seed_from_u64(4802);
        let p = measurable_pool(&m, &req, pool, &mut rng).unwrap();
        let mut r1 = ChaCha8Rng::seed_from_u64(1);
        let reference = more_measurable(&m, &req, &p.hub, p.side, 300, &mut r1).unwrap();
        let mut r2 = ChaCha8Rng::seed_from_u64(2);
        let verify = more_measurable(&m, &req, &p.hub, p.side, 200, &mut r2).unwrap();
        (p.poses, reference, verify)
    }

    /// The figure as a fast check of the predicted figures (the benchmark of measured
    /// ones is `cellcal predict`'s): on the paper's setup 40 selected poses predict a
    /// verification error within 5 % of 100 random ones, selection beats random at equal
    /// count, 100 selected beat 100 random, and the exchanges never make the greedy design
    /// worse.
    #[test]
    fn forty_selected_poses_predict_the_verification_error_of_a_hundred_random() {
        let (pool, reference, verify) = paper_cell(1000);
        let d = paper_design(&pool);
        let figure =
            |set: &[Vec<f64>]| predicted_verification(&d, &d.covariance(set).unwrap(), &verify);
        let random100 = figure(&pool[..100]);
        let mut seen = Vec::new();
        for count in [40, 100] {
            let s = select(&d, &pool, count, &reference).unwrap();
            assert_eq!(s.indices.len(), count);
            let mut unique = s.indices.clone();
            unique.sort_unstable();
            unique.dedup();
            assert_eq!(unique.len(), count, "no pose twice");
            assert!(
                s.criterion_mm2 <= s.greedy_criterion_mm2 * (1.0 + 1e-9),
                "{count}: exchange {} > greedy {}",
                s.criterion_mm2,
                s.greedy_criterion_mm2
            );
            let chosen: Vec<Vec<f64>> = s.indices.iter().map(|&k| pool[k].clone()).collect();
            let selected = figure(&chosen);
            let random = figure(&pool[..count]);
            assert!(
                selected.mean_mm < random.mean_mm,
                "{count}: selection beats random"
            );
            seen.push(selected.mean_mm);
        }
        assert!(
            seen[0] <= 1.05 * random100.mean_mm,
            "40 selected {} mm vs 100 random {} mm",
            seen[0],
            random100.mean_mm
        );
        assert!(seen[1] < random100.mean_mm, "100 selected beat 100 random");
    }

    #[test]
    fn selection_refuses_too_few_poses_and_an_empty_pool() {
        let pool = random_poses(50, 9);
        let d = paper_design(&pool);
        assert_eq!(d.min_poses(), 6, "28 parameters, 6 rows: 5 + 1");
        assert!(matches!(
            select(&d, &pool, 5, &pool),
            Err(SelectionError::TooFew { needed: 6, .. })
        ));
        assert_eq!(
            select(&d, &[], 6, &pool).unwrap_err(),
            SelectionError::EmptyPool
        );
        assert!(matches!(
            select(&d, &pool, 51, &pool),
            Err(SelectionError::PoolTooSmall { .. })
        ));
    }
}
