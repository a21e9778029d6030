//! The measuring order: poses ordered by time over safe routes (plan), and each pose read
//! starting where the stage stands (engine).

use std::path::Path;
use std::sync::Arc;

use cellcal::campaign::session::plan_request;
use cellcal::cell::{ScriptedPrompter, StagePosition};
use cellcal::config::parse_cell_config;
use cellcal::dataset::PoseSet;
use cellcal::model::load_robot;
use cellcal::plan::timing::MotionLimits;
use cellcal::plan::{campaign_router, order_plan, plan_campaign, PlanRequest};
use cellcal::store::Store;
use nalgebra::Vector3;

use super::campaign::{check_complete, config_text, run_in_process_with};
use super::paths::{engine_moves, example};

/// The example campaign (300 poses, drift every 50): the plan's order is 2-opt on the nearest
/// neighbour by leg time, shorter than both it and the sampling order, and the plan's reported
/// times are those of the moves the engine makes (routes, settles and drift returns included).
#[test]
fn two_opt_shortens_the_nearest_neighbour_time_and_the_plan_reports_the_time_saved() {
    let (model, req) = example();
    let plan = plan_campaign(&model, &req).expect("example campaign plans");
    let mut router = campaign_router(&model, &req, &plan.drift_reference).expect("router");
    let mut by_index = plan.poses.clone();
    by_index.sort_by_key(|p| p.index);
    let kept: Vec<Vec<f64>> = by_index.iter().map(|p| p.q_rad.clone()).collect();
    let o = order_plan(&model, &req, &mut router, kept);
    assert_eq!(o.poses, plan.poses, "the plan's order");
    assert_eq!(
        (o.sampling_order_s, o.planned_order_s),
        (plan.sampling_order_s, plan.planned_order_s)
    );
    eprintln!(
        "example campaign legs: sampling order {:.0} s, nearest neighbour {:.0} s, 2-opt {:.0} s",
        o.sampling_order_s, o.nearest_neighbour_s, o.planned_order_s
    );
    // settles are the same in every order (1.5 s each): the moves are what an order shortens
    assert!(
        o.planned_order_s < o.nearest_neighbour_s - 2.0,
        "2-opt {} s vs nearest neighbour {} s",
        o.planned_order_s,
        o.nearest_neighbour_s
    );
    assert!(
        o.nearest_neighbour_s < 0.6 * o.sampling_order_s,
        "nearest neighbour {} s vs sampling order {} s",
        o.nearest_neighbour_s,
        o.sampling_order_s
    );
    // the reported time is that of the engine's moves, each leg routed as the engine routes it
    let limits = MotionLimits::of(&model, req.speed_pct);
    let mut engine_s = 0.0;
    for (from, to) in engine_moves(&plan, req.drift_every) {
        let vias = router.route(&from, &to).expect("routed");
        let mut at = from.clone();
        for leg_end in vias.into_iter().chain(std::iter::once(to)) {
            engine_s += limits.move_time_s(&at, &leg_end) + req.settle_s;
            at = leg_end;
        }
    }
    assert!(
        (engine_s - plan.planned_order_s).abs() <= 1e-6 * engine_s,
        "engine moves {engine_s} s, plan says {} s",
        plan.planned_order_s
    );
}

/// A simulated robot that moves every joint at one speed (`[sim] move_speed_deg_s`, here the
/// issue's 60 deg/s) is ordered by that speed, not by the robot file's joint limits: the plan's
/// reported time is that of the engine's moves at 60 deg/s, and that order is shorter at
/// 60 deg/s than the order by the robot file's limits.
#[test]
fn a_simulated_robot_is_ordered_by_the_speed_it_moves_at() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml");
    let text = std::fs::read_to_string(&path)
        .expect("config")
        .replacen("# move_speed_deg_s = 3600", "move_speed_deg_s = 60.0", 1)
        .replacen("realistic = false", "realistic = true", 1)
        .replacen("poses = 300", "poses = 120", 1)
        .replacen("ident = 100", "ident = 40", 1);
    let cfg = parse_cell_config(&text, &path).expect("config parses");
    let mut model = load_robot(&cfg.robot).expect("robot");
    model.tool = Vector3::from(cfg.campaign.tool_mm);
    let req = plan_request(&cfg);
    let world = MotionLimits::uniform(6, 60f64.to_radians());
    assert_eq!(req.motion_limits(&model), world, "the world's limits");
    let plan = plan_campaign(&model, &req).expect("plans");
    let mut router = campaign_router(&model, &req, &plan.drift_reference).expect("router");
    let engine_s = |plan: &cellcal::plan::Plan, router: &mut cellcal::plan::Router| {
        let mut t = 0.0;
        for (from, to) in engine_moves(plan, req.drift_every) {
            let vias = router.route(&from, &to).expect("routed");
            let mut at = from.clone();
            for leg_end in vias.into_iter().chain(std::iter::once(to)) {
                t += world.move_time_s(&at, &leg_end) + req.settle_s;
                at = leg_end;
            }
        }
        t
    };
    let at_world = engine_s(&plan, &mut router);
    assert!(
        (at_world - plan.planned_order_s).abs() <= 1e-6 * at_world,
        "engine moves at 60 deg/s {at_world} s, plan says {} s",
        plan.planned_order_s
    );
    let by_file = PlanRequest {
        move_speed_rad_s: None,
        ..req.clone()
    };
    let other = plan_campaign(&model, &by_file).expect("plans");
    let other_s = engine_s(&other, &mut router);
    eprintln!("at 60 deg/s: ordered by it {at_world:.0} s, by the robot file {other_s:.0} s");
    assert!(at_world < other_s, "{at_world} s vs {other_s} s");
}

/// A manual-stage campaign on the simulated cell: the technician sets the stage once per pose
/// (today's order asked twice: to P2 and back to P1), every other pose is read P2 first, the
/// stored P1 is still the reading at `p1_mm` and P2 the one at P1 + travel, and the
/// identification reaches the noise floor as before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_stage_move_per_pose() {
    let text = config_text("", "", "")
        .replace("kind = \"serial\"", "kind = \"manual\"")
        .replace("stage_mode = \"zaber\"", "stage_mode = \"manual\"")
        .replace("tool_frame = true", "tool_frame = false");
    let prompter = Arc::new(ScriptedPrompter::exact());
    let f = run_in_process_with(&text, prompter.clone()).await;
    check_complete(&f.store, f.id, 300);
    let asked = prompter.asked();
    let pose_moves: Vec<_> = asked
        .iter()
        .filter(|p| p.id == "stage_move" && p.context.step.as_deref() == Some("pose"))
        .collect();
    assert_eq!(pose_moves.len(), 300, "one stage setting per pose");
    // the stage goes back and forth: P2, P1, P2, … (a drift check in between sets P1 itself)
    let to_p1 = pose_moves
        .iter()
        .filter(|p| p.context.position == Some(StagePosition::P1))
        .count();
    assert!((140..=150).contains(&to_p1), "{to_p1} of 300 set P1");
    let (p1_mm, travel) = (f.cfg.stage.p1_mm, f.cfg.stage.travel_mm);
    let measured = Store::open(&f.store)
        .expect("store")
        .measured(f.id)
        .expect("poses");
    for m in &measured {
        let p2 = m.p2.as_ref().expect("P2 measured");
        let at = |s: Option<f64>| s.expect("stage recorded");
        assert!((at(m.p1.stage_mm) - p1_mm).abs() < 1e-3, "pose {}", m.index);
        assert!(
            (at(p2.stage_mm) - p1_mm - travel).abs() < 1e-3,
            "pose {}",
            m.index
        );
        let d = (p2.position_mm - m.p1.position_mm).norm();
        assert!(
            (d - travel).abs() < 0.1,
            "pose {}: |P2 − P1| = {d}",
            m.index
        );
    }
    assert_eq!(
        measured.iter().filter(|m| m.set == PoseSet::Ident).count(),
        100
    );
    assert!(
        f.report_after_mm <= 1.10 * f.floor_mm,
        "verification after {:.5} mm vs floor {:.5} mm",
        f.report_after_mm,
        f.floor_mm
    );
}
