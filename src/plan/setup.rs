//! Where the cell setup steps move the robot (docs/method.md §4): the tool-frame targets from a
//! planned pose near the box centre and the spread poses of the base registration. The engine
//! measures them; the timing model walks them.

use super::campaign::{target_ok, Plan, PlanRequest};
use super::motion::MotionLimits;
use crate::measure::{plan_tool_frame, select_spread, SetupTarget, ToolFramePlanRequest};
use crate::model::{forward, RobotModel};

/// How many planned poses nearest the box centre are tried as the tool-frame home.
const HOME_CANDIDATES: usize = 100;

/// Whether `q` passes the joint-limit and workspace checks (line of sight included), as the
/// engine checks every target.
fn target_safe(model: &RobotModel, q: &[f64], req: &PlanRequest) -> bool {
    model.within_limits(q) && target_ok(model, q, req)
}

/// The tool-frame targets from the planned pose (drift reference first) nearest the box
/// centre whose every target solves and passes the safety checks (a pose near a singularity
/// or a box face cannot carry the jogs and rotations); `Err` says why the last one tried
/// could not.
pub fn home_tool_frame_targets(
    model: &RobotModel,
    plan: &Plan,
    req: &PlanRequest,
    tool_frame: &ToolFramePlanRequest,
) -> Result<Vec<SetupTarget>, String> {
    let centre = req.workspace.center_mm;
    let mut homes: Vec<(f64, &Vec<f64>)> = std::iter::once(&plan.drift_reference)
        .chain(plan.poses.iter().map(|p| &p.q_rad))
        .map(|q| ((forward(model, q).flange().p - centre).norm(), q))
        .collect();
    homes.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut last = String::from("no planned pose");
    for (_, q0) in homes.into_iter().take(HOME_CANDIDATES) {
        match plan_tool_frame(model, q0, tool_frame) {
            Ok(t) if t.iter().all(|t| target_safe(model, &t.q_rad, req)) => return Ok(t),
            Ok(_) => last = "a target fails the joint-limit/workspace check".into(),
            Err(e) => last = e.to_string(),
        }
    }
    Err(last)
}

/// The tool-frame targets of a setup with `home` (rad) given, else from the planned poses
/// ([`home_tool_frame_targets`]); `None` when they cannot be planned (the engine then stops
/// with the reason).
pub fn tool_frame_targets(
    model: &RobotModel,
    plan: &Plan,
    req: &PlanRequest,
    tool_frame: &ToolFramePlanRequest,
    home: Option<&[f64]>,
) -> Option<Vec<SetupTarget>> {
    match home {
        Some(q0) => plan_tool_frame(model, q0, tool_frame).ok(),
        None => home_tool_frame_targets(model, plan, req, tool_frame).ok(),
    }
}

/// The joints of the base registration's `n` spread poses among the planned poses on `model`,
/// in the order the engine measures them ([`order_loop`] from and back to the drift
/// reference, timed by `req`'s limits).
pub fn base_registration_targets(
    model: &RobotModel,
    plan: &Plan,
    req: &PlanRequest,
    n: usize,
) -> Vec<Vec<f64>> {
    let candidates: Vec<Vec<f64>> = plan.poses.iter().map(|p| p.q_rad.clone()).collect();
    let spread: Vec<Vec<f64>> = select_spread(model, &candidates, n)
        .into_iter()
        .map(|i| candidates[i].clone())
        .collect();
    order_loop(&req.motion_limits(model), &plan.drift_reference, spread)
}

/// The most poses [`order_loop`] orders by trying every order (8! = 40 320 loops); more keep
/// their order.
const LOOP_EXHAUSTIVE_MAX: usize = 8;

/// `poses` in the order whose loop `hub` → poses → `hub` takes the least move time by `limits`
/// (direct moves; every order tried, the first of equal ones kept), for at most
/// [`LOOP_EXHAUSTIVE_MAX`] poses; more are returned as given. Deterministic: the same poses,
/// the same order.
pub fn order_loop(limits: &MotionLimits, hub: &[f64], poses: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let n = poses.len();
    if !(2..=LOOP_EXHAUSTIVE_MAX).contains(&n) {
        return poses;
    }
    let leg = |a: &[f64], b: &[f64]| limits.move_time_s(a, b);
    let loop_s = |order: &[usize]| {
        let mut t = leg(hub, &poses[order[0]]) + leg(&poses[order[n - 1]], hub);
        for w in order.windows(2) {
            t += leg(&poses[w[0]], &poses[w[1]]);
        }
        t
    };
    let mut order: Vec<usize> = (0..n).collect();
    let mut best = (loop_s(&order), order.clone());
    // Heap's algorithm: every permutation once
    let mut c = vec![0usize; n];
    let mut i = 1;
    while i < n {
        if c[i] < i {
            let j = if i % 2 == 0 { 0 } else { c[i] };
            order.swap(j, i);
            let t = loop_s(&order);
            if t < best.0 {
                best = (t, order.clone());
            }
            c[i] += 1;
            i = 1;
        } else {
            c[i] = 0;
            i += 1;
        }
    }
    let mut poses: Vec<Option<Vec<f64>>> = poses.into_iter().map(Some).collect();
    best.1.into_iter().filter_map(|k| poses[k].take()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_base_registration_loop_is_the_shortest_and_keeps_every_pose() {
        let limits = MotionLimits::uniform(2, 1.0);
        let hub = vec![0.0, 0.0];
        // sampled zig-zag: 0 → 3 → 1 → 2 → 0 takes 3 + 2 + 1 + 2 = 8 s; in order 1 2 3: 6 s
        let p = |x: f64| vec![x, 0.0];
        let given = vec![p(3.0), p(1.0), p(2.0)];
        let ordered = order_loop(&limits, &hub, given.clone());
        let loop_s = |o: &[Vec<f64>]| {
            let mut t = limits.move_time_s(&hub, &o[0]) + limits.move_time_s(&o[o.len() - 1], &hub);
            for w in o.windows(2) {
                t += limits.move_time_s(&w[0], &w[1]);
            }
            t
        };
        assert_eq!(loop_s(&given), 8.0);
        assert_eq!(loop_s(&ordered), 6.0);
        let mut sorted = ordered.clone();
        sorted.sort_by(|a, b| a[0].total_cmp(&b[0]));
        assert_eq!(sorted, vec![p(1.0), p(2.0), p(3.0)], "every pose once");
        assert_eq!(
            order_loop(&limits, &hub, ordered.clone()),
            ordered,
            "stable"
        );
    }
}
