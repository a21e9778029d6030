//! Where the cell setup steps move the robot (docs/method.md §4): the tool-frame targets from a
//! planned pose near the box centre and the spread poses of the base registration. The engine
//! measures them; the timing model walks them.

use super::campaign::{target_ok, Plan, PlanRequest};
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

/// The joints of the base registration's `n` spread poses among the planned poses, in the
/// order the engine measures them.
pub fn base_registration_targets(model: &RobotModel, plan: &Plan, n: usize) -> Vec<Vec<f64>> {
    let candidates: Vec<Vec<f64>> = plan.poses.iter().map(|p| p.q_rad.clone()).collect();
    select_spread(model, &candidates, n)
        .into_iter()
        .map(|i| candidates[i].clone())
        .collect()
}
