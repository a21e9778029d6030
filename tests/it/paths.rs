//! Whole-path checks of campaign moves on `config/cell.example.toml` (pure planning: no devices).

use std::path::Path;

use cellcal::campaign::session::plan_request;
use cellcal::config::load_cell_config;
use cellcal::dataset::PoseSet;
use cellcal::model::{load_robot, RobotModel};
use cellcal::plan::{
    campaign_router, count_via_points, plan_campaign, target_ok, PathChecker, Plan, PlanRequest,
    Router,
};
use nalgebra::Vector3;

/// The example cell's nominal model (with its tool) and planning request.
pub(crate) fn example() -> (RobotModel, PlanRequest) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.example.toml");
    let cfg = load_cell_config(&path).expect("example config loads");
    let mut model = load_robot(&cfg.robot).expect("robot model loads");
    model.tool = Vector3::from(cfg.campaign.tool_mm);
    (model, plan_request(&cfg))
}

/// The simulated robot's initial joints (the `[sim]` default, as `config/cell.sim.toml`
/// documents it), rad.
fn sim_start() -> Vec<f64> {
    cellcal::sim::SimWorldConfig::default()
        .initial_joints_deg
        .iter()
        .map(|d| d.to_radians())
        .collect()
}

/// The measurement moves the engine makes, as (from, to): drift reference → poses in move order,
/// back to the drift reference after every `drift_every` poses (not after the last) and at the
/// end.
pub(crate) fn engine_moves(plan: &Plan, drift_every: usize) -> Vec<(Vec<f64>, Vec<f64>)> {
    let hub = &plan.drift_reference;
    let mut moves = Vec::new();
    let mut at = hub.clone();
    for (i, p) in plan.poses.iter().enumerate() {
        moves.push((at, p.q_rad.clone()));
        at = p.q_rad.clone();
        if drift_every > 0 && (i + 1) % drift_every == 0 && i + 1 < plan.poses.len() {
            moves.push((at, hub.clone()));
            at = hub.clone();
        }
    }
    moves.push((at, hub.clone()));
    moves
}

/// Path checkers of the ball at one stage position each: P1 (the tool) and P2 (tool + stage
/// axis × travel).
fn ball_checkers(model: &RobotModel, req: &PlanRequest) -> [PathChecker; 2] {
    [req.tool_mm, req.tool_mm + req.stage_offset_mm]
        .map(|ball| PathChecker::new(model, &req.workspace, &ball))
}

/// Vias of the move `from → to`, after checking that every leg passes the path check of the
/// router and of each of `balls`.
fn routed_legs_pass(
    router: &mut Router,
    balls: &mut [PathChecker],
    from: &[f64],
    to: &[f64],
) -> usize {
    let vias = router
        .route(from, to)
        .unwrap_or_else(|e| panic!("no route {from:?} → {to:?}: {e}"));
    let mut at = from.to_vec();
    for leg_end in vias.iter().chain(std::iter::once(&to.to_vec())) {
        if let Err(f) = router.checker().check_move(&at, leg_end) {
            panic!("leg {at:?} → {leg_end:?} of a route fails: {f}");
        }
        for (k, c) in balls.iter_mut().enumerate() {
            if let Err(f) = c.check_move(&at, leg_end) {
                panic!(
                    "leg {at:?} → {leg_end:?} fails with the ball at P{}: {f}",
                    k + 1
                );
            }
        }
        at.clone_from(leg_end);
    }
    vias.len()
}

/// The robot moves with the stage at P1 or at P2 (a pose reads P2 first when the last one
/// ended there): every leg passes with the ball at either.
#[test]
fn every_move_of_the_example_campaign_passes_the_path_check() {
    let (model, req) = example();
    // stage axis +y, travel 10 mm
    assert_eq!(req.stage_offset_mm, Vector3::new(0.0, 10.0, 0.0));
    let plan = plan_campaign(&model, &req).expect("example campaign plans");
    let mut router = campaign_router(&model, &req, &plan.drift_reference)
        .expect("the drift reference passes the path check");
    let mut balls = ball_checkers(&model, &req);
    // from the robot's start to the drift reference, as the engine's first measurement move
    routed_legs_pass(&mut router, &mut balls, &sim_start(), &plan.drift_reference);
    let moves = engine_moves(&plan, req.drift_every);
    assert_eq!(moves.len(), 300 + 1 + (300 - 1) / req.drift_every);
    let mut vias = 0;
    let mut direct_failures = 0;
    for (from, to) in &moves {
        if router.checker().check_move(from, to).is_err() {
            direct_failures += 1;
        }
        vias += routed_legs_pass(&mut router, &mut balls, from, to);
    }
    assert_eq!(vias, plan.via_points);
    assert!(
        vias >= direct_failures && vias <= 3 * direct_failures,
        "{vias} vias for {direct_failures} failing direct moves"
    );
    // the drift reference reaches every pose directly: returns never need a via
    for p in &plan.poses {
        router
            .checker()
            .check_move(&plan.drift_reference, &p.q_rad)
            .unwrap_or_else(|f| panic!("pose {}: {f}", p.index));
    }
}

#[test]
fn a_thirty_thousand_pose_plan_is_complete_and_routable() {
    let (model, mut req) = example();
    req.poses = 30_000;
    req.ident = 10_000;
    let plan = plan_campaign(&model, &req).expect("30 000 poses plan");
    assert_eq!(plan.poses.len(), 30_000);
    let mut idx: Vec<usize> = plan.poses.iter().map(|e| e.index).collect();
    idx.sort_unstable();
    assert!(idx.iter().copied().eq(0..30_000), "every index once");
    let ident = plan.poses.iter().filter(|e| e.set == PoseSet::Ident);
    assert!(ident.clone().all(|e| e.index < 10_000));
    assert_eq!(ident.count(), 10_000);
    let mut router = campaign_router(&model, &req, &plan.drift_reference)
        .expect("the drift reference passes the path check");
    for p in &plan.poses {
        assert!(target_ok(&model, &p.q_rad, &req), "pose {}", p.index);
        router
            .checker()
            .check_move(&plan.drift_reference, &p.q_rad)
            .unwrap_or_else(|f| panic!("pose {}: {f}", p.index));
    }
    assert_eq!(
        count_via_points(&mut router, req.drift_every, &plan.poses),
        Ok(plan.via_points)
    );
}

/// The engine routes every move from the robot's joints: a robot standing outside the grown box
/// (arm stretched along −y) has no safe path, so the campaign fails before anything moves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_outside_the_grown_box_is_refused_before_any_motion() {
    use cellcal::campaign::{run_campaign, CampaignCommand, FaultPolicy, Outcome};
    use cellcal::sim::lock_world;

    let text = super::campaign::config_text("", "", "")
        .replace("poses = 300", "poses = 20")
        .replace("ident = 100", "ident = 14")
        .replace(
            "initial_joints_deg = [0.0, 0.0, 90.0, 0.0, 45.0, 0.0]",
            "initial_joints_deg = [90.0, 90.0, 0.0, 0.0, 30.0, 0.0]",
        );
    assert!(text.contains("[90.0, 90.0, 0.0"), "cell.sim.toml changed");
    let dir = tempfile::tempdir().expect("tempdir");
    let session = super::campaign::sim_session(dir.path(), &text).await;
    let mut ctx = session.ctx;
    ctx.on_fault = FaultPolicy::Fail;
    let mut devices = session.devices;
    let sim = session.sim.expect("sim");
    let moves_before = lock_world(&sim.world).moves();
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = tokio::time::timeout(
        std::time::Duration::from_secs(30),
        run_campaign(&ctx, &mut devices),
    )
    .await
    .expect("the run ends")
    .expect("runs");
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(
        reason.contains("no safe path") && reason.contains("start"),
        "{reason}"
    );
    assert_eq!(
        lock_world(&sim.world).moves(),
        moves_before,
        "the robot moved"
    );
    sim.stop().await;
}
