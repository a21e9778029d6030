//! ISO 9283:1998 test poses and cycles (§6, §7.2). Pure.
//!
//! The cube (centre, edge) has corners `C1 = (−,−,−)`, `C2 = (+,−,−)`, `C7 = (+,+,+)`,
//! `C8 = (−,+,+)` (signs of the half-edge offsets from the centre, robot base frame); the
//! measuring plane is the diagonal plane `C1–C2–C7–C8`. `P1` is the cube centre; `P2…P5` lie
//! on the plane's diagonals `C1–C7` and `C2–C8` at `diagonal_fraction` of the diagonal length
//! from the corners: `P2` from `C1`, `P3` from `C2`, `P4` from `C7`, `P5` from `C8`.
//! Every pose has one fixed tool orientation. Each cycle visits `P1 → P5 → P4 → P3 → P2`
//! ([`crate::iso9283::CYCLE_ORDER`], §7.2.1) and the next cycle starts at `P1` again; every
//! visit is approached from its pre-pose (`approach_mm` before the target against the
//! approach direction, same orientation) as the last via point of the move, so every pose is
//! reached moving the same way (unidirectional approach). The pre-pose → target leg is a joint
//! move (MOVEJ) like every move of the cell; over `approach_mm` it stays close to the line.
//!
//! Joints come from the nominal model's inverse kinematics by continuation from the hub (the
//! calibration plan's drift reference: the flange pose moved to the target in steps, each solved
//! from the previous; compensated, the [`Compensator`] from that nominal solution), and must stay
//! on the hub's wrist side; every target and pre-pose passes [`target_ok`] and every move of the
//! campaign has a route whose legs pass the path check.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::campaign::{campaign_router, target_ok, Plan, PlanEntry, PlanRequest};
use super::path::wrist_side;
use super::route::{RouteError, Router};
use crate::compensate::{CompensateError, Compensator, Target};
use crate::dataset::PoseSet;
use crate::iso9283::visit_pose;
use crate::model::ik::{solve_flange, IkOptions};
use crate::model::kinematics::{forward, Pose};
use crate::model::rotation::{from_rotation_vector, log_so3};
use crate::model::{IkError, RobotModel};

/// What to plan (robot base frame, mm, rad).
#[derive(Debug, Clone, PartialEq)]
pub struct IsoRequest {
    /// Cube centre (mm).
    pub cube_center_mm: Vector3<f64>,
    /// Cube edge (mm).
    pub cube_edge_mm: f64,
    /// Distance of P2…P5 from the corners, as a fraction of the diagonal (ISO: 0.1 ± 0.02).
    pub diagonal_fraction: f64,
    /// Direction of the last motion into every target (unit; e.g. −z: from above).
    pub approach_dir: Vector3<f64>,
    /// Length of that last motion (mm).
    pub approach_mm: f64,
    /// Flange orientation at every pose; `None`: the hub's.
    pub rotation: Option<Matrix3<f64>>,
    /// Cycles (ISO: 30).
    pub cycles: usize,
}

/// One of the five poses with the joints that command it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoPose {
    /// Pose number (1–5).
    pub pose: usize,
    /// Commanded ball position (mm, robot base frame).
    pub target_mm: [f64; 3],
    /// Joints of the target (rad).
    pub q_rad: Vec<f64>,
    /// Joints of the pre-pose (rad).
    pub approach_q_rad: Vec<f64>,
}

/// A planned ISO 9283 campaign, stored with the campaign (its `kind` JSON).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoPlan {
    /// P1…P5.
    pub poses: Vec<IsoPose>,
    /// Commanded flange orientation, rotation vector (rad, robot base frame).
    pub rotation_vector_rad: [f64; 3],
    /// Drift reference and hub of every route (rad).
    pub hub_q_rad: Vec<f64>,
    /// Cycles.
    pub cycles: usize,
    /// Direction of the last motion into every target (unit, robot base frame).
    pub approach_dir: [f64; 3],
    /// Length of that motion (mm).
    pub approach_mm: f64,
    /// Whether the joints came from a corrected model ([`Compensator`]).
    pub compensated: bool,
    /// Compensated: the corrected model's base (tracker ← robot base), the frame its targets
    /// were placed in and the figures are given in.
    pub model_base: Option<BaseFrame>,
}

/// A robot base frame in the tracker frame (tracker ← robot base).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BaseFrame {
    /// Translation (mm).
    pub translation_mm: [f64; 3],
    /// Rotation vector (rad).
    pub rotation_vector_rad: [f64; 3],
}

impl BaseFrame {
    /// The pose tracker ← robot base.
    pub fn pose(&self) -> Pose {
        Pose::from_rotation_vector(
            &Vector3::from(self.rotation_vector_rad),
            Vector3::from(self.translation_mm),
        )
    }
}

/// Why the ISO poses cannot be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IsoPlanError {
    /// No joints reach a pose (or its pre-pose).
    #[error("ISO pose P{pose}{which}: not reachable: {reason}")]
    Unreachable {
        /// Pose number.
        pose: usize,
        /// `""` or `" pre-pose"`.
        which: &'static str,
        /// Why.
        reason: String,
    },
    /// A pose fails the planning checks (box, line of sight, wrist side).
    #[error("ISO pose P{pose}{which}: {reason}")]
    Refused {
        /// Pose number.
        pose: usize,
        /// `""` or `" pre-pose"`.
        which: &'static str,
        /// The failed check.
        reason: String,
    },
    /// A move of the campaign has no route.
    #[error("ISO campaign: no route: {0}")]
    Route(RouteError),
}

from_cause!(RouteError => IsoPlanError::Route);

/// The five commanded positions P1…P5 (mm, robot base frame) of the cube.
pub fn iso_positions(center: &Vector3<f64>, edge_mm: f64, fraction: f64) -> [Vector3<f64>; 5] {
    let h = 0.5 * edge_mm;
    let corner = |x: f64, y: f64, z: f64| center + Vector3::new(x, y, z) * h;
    let (c1, c2, c7, c8) = (
        corner(-1.0, -1.0, -1.0),
        corner(1.0, -1.0, -1.0),
        corner(1.0, 1.0, 1.0),
        corner(-1.0, 1.0, 1.0),
    );
    let along = |from: Vector3<f64>, to: Vector3<f64>| from + (to - from) * fraction;
    [
        *center,
        along(c1, c7),
        along(c2, c8),
        along(c7, c1),
        along(c8, c2),
    ]
}

/// How the joints of a ball pose are found.
pub enum Targeting<'a> {
    /// The nominal model's inverse kinematics (the controller's own).
    Nominal,
    /// The corrected model's compensation (targets placed in its measurement frame by its
    /// base).
    Compensated(&'a Compensator),
}

/// Steps of the continuation from the start pose to a target (each step's IK starts at the
/// previous step's solution, so a large change of position and orientation stays on the
/// start's branch and converges).
const CONTINUATION_STEPS: usize = 12;

/// Nominal joints of the flange pose `goal` by continuation from `start`: the flange pose is
/// moved from the start's to the goal in [`CONTINUATION_STEPS`] steps (position linearly,
/// orientation along the geodesic), each solved from the previous solution.
fn continued_ik(model: &RobotModel, start: &[f64], goal: &Pose) -> Result<Vec<f64>, IkError> {
    let from = *forward(model, start).flange();
    let turn = log_so3(&(from.r.transpose() * goal.r));
    let mut q = start.to_vec();
    for k in 1..=CONTINUATION_STEPS {
        let t = k as f64 / CONTINUATION_STEPS as f64;
        let step = Pose {
            r: from.r * from_rotation_vector(&(turn * t)),
            p: from.p + (goal.p - from.p) * t,
        };
        q = solve_flange(model, &q, &step, &IkOptions::default())?.q;
    }
    Ok(q)
}

impl Targeting<'_> {
    /// Joints that put the ball (`req.tool_mm`) at `p` with flange orientation `r` (robot base
    /// frame), starting from `start`: the nominal model's by continuation; compensated, the
    /// corrected model's from that nominal solution.
    fn joints(
        &self,
        model: &RobotModel,
        req: &PlanRequest,
        r: &Matrix3<f64>,
        p: &Vector3<f64>,
        start: &[f64],
    ) -> Result<Vec<f64>, String> {
        let flange = Pose {
            r: *r,
            p: p - r * req.tool_mm,
        };
        let nominal = continued_ik(model, start, &flange).map_err(|e| e.to_string())?;
        let Targeting::Compensated(c) = self else {
            return Ok(nominal);
        };
        let id = c.identified();
        let t = Target {
            position_mm: id.base_rotation * p + id.base_translation,
            rotation: Some(id.base_rotation * r),
        };
        let out = c
            .targets(&[t], &nominal)
            .map_err(|e: CompensateError| e.to_string())?;
        let c = out.into_iter().next().ok_or("no solution")?;
        if c.reachable {
            Ok(c.q)
        } else {
            Err(format!(
                "the corrected model misses it by {:.3} mm",
                c.residual_mm
            ))
        }
    }
}

/// Plan the ISO poses on `model` (nominal, with the campaign's tool) around `hub` (the
/// calibration plan's drift reference): joints of every target and pre-pose, each passing
/// [`target_ok`] on the hub's wrist side, and a route for every move of the campaign.
pub fn plan_iso(
    model: &RobotModel,
    req: &PlanRequest,
    iso: &IsoRequest,
    hub: &[f64],
    targeting: &Targeting<'_>,
) -> Result<IsoPlan, IsoPlanError> {
    let r = iso
        .rotation
        .unwrap_or_else(|| forward(model, hub).flange().r);
    let solver = PoseSolver {
        model,
        req,
        targeting,
        r,
        side: wrist_side(&forward(model, hub)),
    };
    let positions = iso_positions(&iso.cube_center_mm, iso.cube_edge_mm, iso.diagonal_fraction);
    let mut poses = Vec::with_capacity(5);
    for (k, p) in positions.iter().enumerate() {
        let pose = k + 1;
        let pre = p - iso.approach_dir * iso.approach_mm;
        let q = solver.joints(p, hub, (pose, ""))?;
        let qa = solver.joints(&pre, &q, (pose, " pre-pose"))?;
        poses.push(IsoPose {
            pose,
            target_mm: (*p).into(),
            q_rad: q,
            approach_q_rad: qa,
        });
    }
    let plan = IsoPlan {
        poses,
        rotation_vector_rad: log_so3(&r).into(),
        hub_q_rad: hub.to_vec(),
        cycles: iso.cycles,
        approach_dir: iso.approach_dir.into(),
        approach_mm: iso.approach_mm,
        compensated: matches!(targeting, Targeting::Compensated(_)),
        model_base: match targeting {
            Targeting::Nominal => None,
            Targeting::Compensated(c) => Some(BaseFrame {
                translation_mm: c.identified().base_translation.into(),
                rotation_vector_rad: log_so3(&c.identified().base_rotation).into(),
            }),
        },
    };
    let mut router = campaign_router(model, req, hub)?;
    plan.via_points(&mut router, req.drift_every)?;
    Ok(plan)
}

/// What every pose of one plan is solved with: the model, the checks, the targeting, the
/// orientation and the wrist side.
struct PoseSolver<'a> {
    model: &'a RobotModel,
    req: &'a PlanRequest,
    targeting: &'a Targeting<'a>,
    r: Matrix3<f64>,
    side: Option<bool>,
}

impl PoseSolver<'_> {
    /// Joints of the ball at `p` (from `start`) that pass [`target_ok`] on the wrist side.
    fn joints(
        &self,
        p: &Vector3<f64>,
        start: &[f64],
        (pose, which): (usize, &'static str),
    ) -> Result<Vec<f64>, IsoPlanError> {
        let q = self
            .targeting
            .joints(self.model, self.req, &self.r, p, start)
            .map_err(|reason| IsoPlanError::Unreachable {
                pose,
                which,
                reason,
            })?;
        let refused = |reason: String| IsoPlanError::Refused {
            pose,
            which,
            reason,
        };
        if !target_ok(self.model, &q, self.req) {
            return Err(refused(format!(
                "at ({:.1}, {:.1}, {:.1}) mm it fails the workspace box, wrist, floor or \
                 line-of-sight check",
                p.x, p.y, p.z
            )));
        }
        if wrist_side(&forward(self.model, &q)) != self.side {
            return Err(refused(
                "its wrist is bent to the other side than the hub's".into(),
            ));
        }
        Ok(q)
    }
}

impl IsoPlan {
    /// The pose P`k` (1–5).
    pub fn pose(&self, k: usize) -> Option<&IsoPose> {
        self.poses.iter().find(|p| p.pose == k)
    }

    /// The commanded flange orientation (robot base frame).
    pub fn rotation(&self) -> Matrix3<f64> {
        from_rotation_vector(&Vector3::from(self.rotation_vector_rad))
    }

    /// The campaign's visits as plan entries in move order (index = visit number; pose and
    /// cycle by [`visit_pose`]); all in the identification set (the set has no meaning here).
    pub fn entries(&self) -> Vec<PlanEntry> {
        (0..5 * self.cycles)
            .filter_map(|i| {
                let (_, k) = visit_pose(i);
                self.pose(k).map(|p| PlanEntry {
                    index: i,
                    set: PoseSet::Ident,
                    q_rad: p.q_rad.clone(),
                })
            })
            .collect()
    }

    /// The pre-pose of every visit (plan index → joints).
    pub fn approaches(&self) -> BTreeMap<usize, Vec<f64>> {
        (0..5 * self.cycles)
            .filter_map(|i| {
                let (_, k) = visit_pose(i);
                self.pose(k).map(|p| (i, p.approach_q_rad.clone()))
            })
            .collect()
    }

    /// Via points of every move of the campaign (hub → pre-pose → target for each visit,
    /// pre-poses counted, returns to the hub every `drift_every` visits and at the end); a
    /// move without a route, or a pre-pose → target leg that fails the path check, is an error.
    pub fn via_points(&self, router: &mut Router, drift_every: usize) -> Result<usize, RouteError> {
        let hub = router.hub().to_vec();
        let mut at = hub.clone();
        let mut vias = 0;
        let entries = self.entries();
        let approaches = self.approaches();
        for (done, e) in entries.iter().enumerate().map(|(i, e)| (i + 1, e)) {
            let pre = &approaches[&e.index];
            vias += router.route(&at, pre)?.len() + 1;
            router
                .checker()
                .check_move(pre, &e.q_rad)
                .map_err(|f| RouteError::NoRoute {
                    end: "target",
                    fault: f,
                })?;
            at.clone_from(&e.q_rad);
            if drift_every > 0 && done % drift_every == 0 && done < entries.len() {
                vias += router.route(&at, &hub)?.len();
                at.clone_from(&hub);
            }
        }
        Ok(vias + router.route(&at, &hub)?.len())
    }

    /// The engine's plan: visits, hub as drift reference, pre-poses.
    pub fn to_plan(&self, via_points: usize) -> Plan {
        Plan {
            poses: self.entries(),
            drift_reference: self.hub_q_rad.clone(),
            via_points,
            approach: self.approaches(),
            sampling_order_s: 0.0,
            planned_order_s: 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::iso9283::CYCLE_ORDER;
    use crate::model::tx60;
    use crate::plan::{plan_campaign, Workspace};

    #[test]
    fn positions_on_the_diagonal_plane() {
        let c = Vector3::new(0.0, 0.0, 0.0);
        let p = iso_positions(&c, 100.0, 0.1);
        assert_eq!(p[0], c);
        // P2 is 10 % of the C1–C7 diagonal from C1 = (−50, −50, −50)
        assert!((p[1] - Vector3::new(-40.0, -40.0, -40.0)).norm() < 1e-12);
        assert!((p[2] - Vector3::new(40.0, -40.0, -40.0)).norm() < 1e-12);
        assert!((p[3] - Vector3::new(40.0, 40.0, 40.0)).norm() < 1e-12);
        assert!((p[4] - Vector3::new(-40.0, 40.0, 40.0)).norm() < 1e-12);
        // all on the plane through C1, C2, C7 (normal (0, 1, −1))
        let n = Vector3::new(0.0, 1.0, -1.0);
        assert!(p.iter().all(|q| q.dot(&n).abs() < 1e-12));
        assert_eq!(CYCLE_ORDER, [1, 5, 4, 3, 2]);
    }

    #[test]
    fn nominal_plan_reaches_every_pose_from_above() {
        let m = tx60();
        let req = PlanRequest {
            workspace: Workspace::default(),
            poses: 300,
            ident: 100,
            seed: 4802,
            tracker_mm: Vector3::new(2500.0, 400.0, 200.0),
            line_of_sight_max_rad: std::f64::consts::PI,
            tool_mm: Vector3::new(0.0, 0.0, 60.0),
            selection: crate::plan::selection::Selection::Random,
            design: crate::plan::selection::DesignSetup::default(),
            drift_every: 50,
            ident_block: None,
            speed_pct: 20.0,
            move_speed_rad_s: None,
            settle_s: 1.5,
            stage_offset_mm: Vector3::new(0.0, 10.0, 0.0),
        };
        let hub = plan_campaign(&m, &req).unwrap().drift_reference;
        let iso = IsoRequest {
            cube_center_mm: Vector3::new(400.0, 0.0, 400.0),
            cube_edge_mm: 200.0,
            diagonal_fraction: 0.1,
            approach_dir: -Vector3::z(),
            approach_mm: 20.0,
            rotation: None,
            cycles: 3,
        };
        let plan = plan_iso(&m, &req, &iso, &hub, &Targeting::Nominal).unwrap();
        let r = plan.rotation();
        for p in &plan.poses {
            let ball = |q: &[f64]| forward(&m, q).flange().transform_point(&req.tool_mm);
            let t = Vector3::from(p.target_mm);
            assert!((ball(&p.q_rad) - t).norm() < 1e-6, "{p:?}");
            let pre = ball(&p.approach_q_rad);
            assert!((pre - (t + Vector3::z() * 20.0)).norm() < 1e-6, "{p:?}");
            assert!((forward(&m, &p.q_rad).flange().r - r).norm() < 1e-9);
        }
        let entries = plan.entries();
        assert_eq!(entries.len(), 15);
        assert_eq!(entries[1].q_rad, plan.pose(5).unwrap().q_rad);
        assert_eq!(plan.approaches().len(), 15);

        // the whole 1000 mm box is beyond the arm: refused naming the pose
        let whole = IsoRequest {
            cube_center_mm: Vector3::new(550.0, 0.0, 550.0),
            cube_edge_mm: 1000.0,
            ..iso
        };
        let e = plan_iso(&m, &req, &whole, &hub, &Targeting::Nominal).unwrap_err();
        assert!(e.to_string().starts_with("ISO pose P"), "{e}");
    }
}
