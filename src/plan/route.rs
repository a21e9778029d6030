//! Routing of joint moves: the via points (possibly none) that make every leg of a move pass the
//! path check of [`super::path`].
//!
//! A route is, in this order, the first of: the direct move; or `from` → hub → `to`, where each
//! end reaches the hub (a safe pose near the box centre, the campaign's drift reference) directly
//! or by a joint staircase: the joint groups base (joint 1), arm (joints 2–3) and wrist
//! (joints 4–n) move to the hub's values one group at a time, in the first of the six group
//! orders whose legs all pass. Every leg of a returned route has passed
//! [`PathChecker::check_move`]. Pure and deterministic.

use nalgebra::Vector3;

use super::path::{PathCheck, PathChecker, PathFault};
use super::workspace::Workspace;
use crate::model::RobotModel;

/// Why no route was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RouteError {
    /// The start configuration itself fails a path check.
    #[error("the start fails the path check: {0}")]
    Start(PathCheck),
    /// The target configuration itself fails a path check.
    #[error("the target fails the path check: {0}")]
    Target(PathCheck),
    /// The hub fails a path check.
    #[error("the hub pose fails the path check: {0}")]
    Hub(PathCheck),
    /// Neither the direct move nor any staircase reaches the hub from one end.
    #[error("no route from the {end} to the hub (direct move: {fault})")]
    NoRoute {
        /// `start` or `target`.
        end: &'static str,
        /// Why the direct move from that end to the hub fails.
        fault: PathFault,
    },
}

/// Finds routes between configurations through one hub pose.
#[derive(Debug, Clone)]
pub struct Router {
    checker: PathChecker,
    hub: Vec<f64>,
}

impl Router {
    /// A router over `model`'s chain with the ball at `tool_mm` and `hub` as the safe
    /// intermediate pose; the hub must pass the path check.
    pub fn new(
        model: &RobotModel,
        workspace: &Workspace,
        tool_mm: &Vector3<f64>,
        hub: &[f64],
    ) -> Result<Router, RouteError> {
        Router::with_checker(PathChecker::new(model, workspace, tool_mm), hub)
    }

    /// A router whose every leg passes `checker` (e.g. one that also checks the ball at P2,
    /// [`PathChecker::with_ball_at_p2`]), with `hub` as the safe intermediate pose; the hub
    /// must pass the path check.
    pub fn with_checker(mut checker: PathChecker, hub: &[f64]) -> Result<Router, RouteError> {
        checker.check_pose(hub).map_err(RouteError::Hub)?;
        Ok(Router {
            checker,
            hub: hub.to_vec(),
        })
    }

    /// The hub pose (rad).
    pub fn hub(&self) -> &[f64] {
        &self.hub
    }

    /// The path checker the routes are checked with.
    pub fn checker(&mut self) -> &mut PathChecker {
        &mut self.checker
    }

    /// Via points (in move order, ends excluded) such that every leg of
    /// `from → via… → to` passes the path check.
    pub fn route(&mut self, from: &[f64], to: &[f64]) -> Result<Vec<Vec<f64>>, RouteError> {
        match self.checker.check_move(from, to) {
            Ok(()) => return Ok(Vec::new()),
            Err(f) if f.sample == 0 => return Err(RouteError::Start(f.check)),
            Err(_) => self.checker.check_pose(to).map_err(RouteError::Target)?,
        }
        let out = self.to_hub(from).map_err(|fault| RouteError::NoRoute {
            end: "start",
            fault,
        })?;
        let back = self.to_hub(to).map_err(|fault| RouteError::NoRoute {
            end: "target",
            fault,
        })?;
        let mut vias = out;
        vias.push(self.hub.clone());
        vias.extend(back.into_iter().rev());
        vias.retain(|v| v.as_slice() != from && v.as_slice() != to);
        Ok(vias)
    }

    /// Via points from `q` to the hub (hub excluded): none when the direct move passes, else
    /// those of the first passing staircase; the direct move's fault when none passes.
    pub fn to_hub(&mut self, q: &[f64]) -> Result<Vec<Vec<f64>>, PathFault> {
        let hub = self.hub.clone();
        let direct = match self.checker.check_move(q, &hub) {
            Ok(()) => return Ok(Vec::new()),
            Err(fault) => fault,
        };
        for order in GROUP_ORDERS {
            let vias = staircase(q, &hub, order);
            if self.legs_pass(q, &vias, &hub) {
                return Ok(vias);
            }
        }
        Err(direct)
    }

    /// Whether every leg of `from → vias… → to` passes.
    fn legs_pass(&mut self, from: &[f64], vias: &[Vec<f64>], to: &[f64]) -> bool {
        let mut at = from;
        for v in vias.iter().map(Vec::as_slice).chain(std::iter::once(to)) {
            if self.checker.check_move(at, v).is_err() {
                return false;
            }
            at = v;
        }
        true
    }
}

/// Joint groups moved one at a time by a staircase: base, arm, wrist.
#[derive(Debug, Clone, Copy)]
enum Group {
    Base,
    Arm,
    Wrist,
}

impl Group {
    /// The joint indices of the group on an arm of `dof` joints.
    fn joints(self, dof: usize) -> std::ops::Range<usize> {
        let arm_end = dof.min(3);
        match self {
            Group::Base => 0..dof.min(1),
            Group::Arm => dof.min(1)..arm_end,
            Group::Wrist => arm_end..dof,
        }
    }
}

/// The six orders of the three groups, retracting the arm first when possible.
const GROUP_ORDERS: [[Group; 3]; 6] = [
    [Group::Arm, Group::Base, Group::Wrist],
    [Group::Arm, Group::Wrist, Group::Base],
    [Group::Wrist, Group::Arm, Group::Base],
    [Group::Base, Group::Arm, Group::Wrist],
    [Group::Wrist, Group::Base, Group::Arm],
    [Group::Base, Group::Wrist, Group::Arm],
];

/// The two intermediate configurations of moving from `q` to `hub` group by group in `order`
/// (a configuration equal to its predecessor is left out).
fn staircase(q: &[f64], hub: &[f64], order: [Group; 3]) -> Vec<Vec<f64>> {
    let mut at = q.to_vec();
    let mut out = Vec::with_capacity(2);
    for g in &order[..2] {
        for j in g.joints(q.len()) {
            at[j] = hub[j];
        }
        if out
            .last()
            .map_or(at.as_slice() != q, |l: &Vec<f64>| *l != at)
            && at != hub
        {
            out.push(at.clone());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tx60;

    fn rad(deg: [f64; 6]) -> Vec<f64> {
        deg.iter().map(|d| d.to_radians()).collect()
    }

    fn router() -> Router {
        let hub = rad([-173.0, -33.0, -21.0, -42.0, 20.0, 149.0]);
        let tool = Vector3::new(0.0, 0.0, 60.0);
        Router::new(&tx60(), &Workspace::default(), &tool, &hub).unwrap()
    }

    /// Every leg of `from → vias… → to` passes the path check.
    fn legs_pass(r: &mut Router, from: &[f64], vias: &[Vec<f64>], to: &[f64]) {
        let mut at = from.to_vec();
        for v in vias.iter().chain(std::iter::once(&to.to_vec())) {
            r.checker().check_move(&at, v).unwrap();
            at.clone_from(v);
        }
    }

    #[test]
    fn a_move_leaving_the_box_is_routed_through_the_hub() {
        let mut r = router();
        let a = rad([64.0, 96.0, -77.0, 71.0, 47.0, -84.0]);
        let b = rad([66.0, 14.0, 108.0, -52.0, 47.0, 50.0]);
        assert!(r.checker().check_move(&a, &b).is_err());
        let vias = r.route(&a, &b).unwrap();
        assert_eq!(vias, vec![r.hub().to_vec()]);
        legs_pass(&mut r, &a, &vias, &b);
        assert_eq!(r.route(&a, &b).unwrap(), vias, "deterministic");
    }

    #[test]
    fn a_passing_move_needs_no_via_and_a_staircase_is_checked_leg_by_leg() {
        let mut r = router();
        let a = rad([64.0, 96.0, -77.0, 71.0, 47.0, -84.0]);
        let mut near = a.clone();
        near[5] += 0.3;
        assert_eq!(r.route(&a, &near).unwrap(), Vec::<Vec<f64>>::new());
        let hub = r.hub().to_vec();
        for order in GROUP_ORDERS {
            let stairs = staircase(&a, &hub, order);
            assert_eq!(stairs.len(), 2);
            for (s, g) in stairs.iter().zip(order) {
                // after each step the moved group holds the hub's values
                assert!(g.joints(6).all(|j| s[j] == hub[j]));
            }
        }
    }

    #[test]
    fn no_route_across_the_wrist_singularity_and_bad_ends_are_named() {
        let mut r = router();
        let a = rad([64.0, 96.0, -77.0, 71.0, 47.0, -84.0]);
        let mut flipped = a.clone();
        flipped[4] = -47f64.to_radians();
        match r.route(&a, &flipped) {
            Err(RouteError::NoRoute {
                end: "target",
                fault,
            }) => {
                assert!(matches!(fault.check, PathCheck::Wrist { .. }), "{fault}")
            }
            other => panic!("{other:?}"),
        }
        // arm stretched out along −y, far past the box
        let outside = rad([90.0, 90.0, 0.0, 0.0, 30.0, 0.0]);
        assert!(
            matches!(r.route(&outside, &a), Err(RouteError::Start(_))),
            "{:?}",
            r.route(&outside, &a)
        );
        assert!(matches!(r.route(&a, &outside), Err(RouteError::Target(_))));
        let tool = Vector3::zeros();
        assert!(matches!(
            Router::new(&tx60(), &Workspace::default(), &tool, &outside),
            Err(RouteError::Hub(_))
        ));
    }
}
