//! Compensation, the fourth step of the method: joint values that put the real robot (the
//! identified model) where a target or a program says.
//!
//! Two models take part. The *nominal* model is the controller's: the nominal MDH chain,
//! placed in the measurement frame by the identified model's base and carrying its tool (the
//! nominal file's own base and tool are not used), so the two differ only in the chain. The
//! *identified* model is the corrected model file. Joint limits are the nominal file's (the
//! controller's) for both.
//!
//! - A target (tool pose in the measurement frame): the nominal model's solution first (damped
//!   Newton from the previous target's nominal solution, the first from the given start, so a
//!   sequence of targets stays on one branch), then the identified model's solution from it:
//!   the capped steps keep the nominal solution's branch, so the result is the solution nearest
//!   the nominal one. A position-only target keeps the orientation the nominal model's
//!   solution gives the tool (the nominal solution solves the position alone, its orientation
//!   free and kept near the start's).
//! - A program point (joints computed on the nominal model): the target is the tool pose the
//!   nominal model gives those joints, its nominal solution the joints themselves.
//!
//! The identified model's forward kinematics include its non-geometric terms (joint
//! compliance under the gravity torque of its masses, per-joint harmonics; docs/method.md §10),
//! and the inverse kinematics differentiates through them, so the compensated joints put the
//! robot that has them on the target; the nominal (controller's) model has none.
//!
//! Every solution stays inside the joint limits ([`solve_within_limits`]); a target the
//! identified model cannot reach there is reported unreachable with its remaining error and
//! the joints on a limit.

pub mod table;
#[cfg(test)]
mod tests;

use nalgebra::{Matrix3, Vector3};

use crate::model::ik::{solve_within_limits, IkGoal, IkOptions};
use crate::model::kinematics::{measured_point, measured_rotation, Pose};
use crate::model::rotation::log_so3;
use crate::model::{IkError, RobotModel, TermFamily};

/// Largest MDH length difference (mm) between the nominal and the identified model.
pub const MAX_LENGTH_CHANGE_MM: f64 = 20.0;
/// Largest MDH angle difference (rad, 10°) between the nominal and the identified model.
pub const MAX_ANGLE_CHANGE_RAD: f64 = 10.0 * std::f64::consts::PI / 180.0;

/// Why compensation cannot run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CompensateError {
    /// The two models have different numbers of joints.
    #[error("the nominal model has {nominal} joints, the identified model {identified}")]
    DofMismatch {
        /// Joints of the nominal model.
        nominal: usize,
        /// Joints of the identified model.
        identified: usize,
    },
    /// The identified model is too far from the nominal one to be its calibration.
    #[error(
        "the identified model's {name} differs from the nominal model's by {difference} (limit \
         {limit}): is it the calibration of this robot?"
    )]
    NotACalibration {
        /// Parameter name (`d3`, `alpha2`).
        name: String,
        /// The difference, with its unit.
        difference: String,
        /// The allowed difference, with its unit.
        limit: String,
    },
    /// The identified model has a joint compliance but no masses to compute the gravity
    /// torque it multiplies (§10): compensating would leave the compliance out.
    #[error(
        "the identified model has a compliance on joint {joints} but no [[masses]]: the \
         gravity torques it was identified with are unknown, so compensation would leave the \
         compliance out (give the masses the identification used)"
    )]
    ComplianceWithoutMasses {
        /// The joints with a compliance (1-based, comma-separated).
        joints: String,
    },
    /// A start or program joint vector has the wrong length or a value that is not finite.
    #[error("{0}")]
    Joints(IkError),
}

/// A tool pose to reach, in the identified model's measurement frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// Tool (ball) position (mm).
    pub position_mm: Vector3<f64>,
    /// Tool orientation (= the flange's); `None`: position only (see the module doc).
    pub rotation: Option<Matrix3<f64>>,
}

/// The compensated joints of one target or program point.
#[derive(Debug, Clone, PartialEq)]
pub struct Compensated {
    /// Joints for the identified model (rad), inside the limits.
    pub q: Vec<f64>,
    /// The nominal model's solution it started from (rad).
    pub nominal_q: Vec<f64>,
    /// Whether the identified model reaches the target at `q`.
    pub reachable: bool,
    /// Tool position error of the identified model at `q` (mm, measurement frame).
    pub residual_mm: f64,
    /// Tool orientation error at `q` against the target's (or, position only, the nominal
    /// solution's) orientation (rad).
    pub residual_rad: f64,
    /// Joints (1-based) on a limit at `q`; when not reachable, the limits that bind.
    pub at_limit: Vec<usize>,
}

/// The nominal and identified models, ready to compensate targets and programs.
#[derive(Debug, Clone)]
pub struct Compensator {
    nominal: RobotModel,
    identified: RobotModel,
    opts: IkOptions,
}

/// Every MDH parameter of `identified` within [`MAX_LENGTH_CHANGE_MM`] /
/// [`MAX_ANGLE_CHANGE_RAD`] of `nominal`'s, else the first one that is not.
fn check_calibration(nominal: &RobotModel, identified: &RobotModel) -> Result<(), CompensateError> {
    for (i, (n, m)) in nominal.joints.iter().zip(&identified.joints).enumerate() {
        for kind in crate::model::ParamKind::ALL {
            let diff = (m.get(kind) - n.get(kind)).abs();
            let name = format!("{}{}", kind.stem(), i + 1);
            let (over, difference, limit) = if kind.is_angle() {
                (
                    diff > MAX_ANGLE_CHANGE_RAD,
                    format!("{:.3}°", diff.to_degrees()),
                    format!("{:.0}°", MAX_ANGLE_CHANGE_RAD.to_degrees()),
                )
            } else {
                (
                    diff > MAX_LENGTH_CHANGE_MM,
                    format!("{diff:.3} mm"),
                    format!("{MAX_LENGTH_CHANGE_MM} mm"),
                )
            };
            if over || !diff.is_finite() {
                return Err(CompensateError::NotACalibration {
                    name,
                    difference,
                    limit,
                });
            }
        }
    }
    // a harmonic turns the joint by up to its coefficient: the same bound as an MDH angle
    for (i, t) in identified.terms.iter().enumerate() {
        for kind in TermFamily::Harmonics.kinds() {
            let v = t.get(*kind).abs();
            if v > MAX_ANGLE_CHANGE_RAD || !v.is_finite() {
                return Err(CompensateError::NotACalibration {
                    name: format!("{}{}", kind.name(), i + 1),
                    difference: format!("{:.3}°", v.to_degrees()),
                    limit: format!("{:.0}°", MAX_ANGLE_CHANGE_RAD.to_degrees()),
                });
            }
        }
    }
    if identified.masses.is_empty() {
        let compliant: Vec<String> = identified
            .terms
            .iter()
            .enumerate()
            .filter(|(_, t)| t.compliance != 0.0)
            .map(|(i, _)| (i + 1).to_string())
            .collect();
        if !compliant.is_empty() {
            return Err(CompensateError::ComplianceWithoutMasses {
                joints: compliant.join(", "),
            });
        }
    }
    Ok(())
}

impl Compensator {
    /// The nominal chain placed by the identified model's base and tool, both with the nominal
    /// limits; refused when the chains differ in length or by more than a calibration can
    /// ([`MAX_LENGTH_CHANGE_MM`], [`MAX_ANGLE_CHANGE_RAD`], also for each harmonic), or when
    /// the identified model has a compliance but no masses. The nominal model is the
    /// controller's: its non-geometric terms, if its file has any, are dropped; the identified
    /// model keeps its terms, masses and gravity (§10), so its solutions account for them.
    pub fn new(
        nominal: &RobotModel,
        identified: &RobotModel,
    ) -> Result<Compensator, CompensateError> {
        if nominal.dof() != identified.dof() {
            return Err(CompensateError::DofMismatch {
                nominal: nominal.dof(),
                identified: identified.dof(),
            });
        }
        check_calibration(nominal, identified)?;
        let placed = RobotModel {
            base_rotation: identified.base_rotation,
            base_translation: identified.base_translation,
            tool: identified.tool,
            terms: Vec::new(),
            ..nominal.clone()
        };
        let identified = RobotModel {
            limits: nominal.limits.clone(),
            ..identified.clone()
        };
        Ok(Compensator {
            nominal: placed,
            identified,
            opts: IkOptions::default(),
        })
    }

    /// Number of joints.
    pub fn dof(&self) -> usize {
        self.nominal.dof()
    }

    /// The nominal model in the measurement frame (nominal chain, identified base and tool).
    pub fn nominal(&self) -> &RobotModel {
        &self.nominal
    }

    /// The identified model (with the nominal limits).
    pub fn identified(&self) -> &RobotModel {
        &self.identified
    }

    /// The robot-base frame of both models in the measurement frame.
    fn base(&self) -> Pose {
        Pose {
            r: self.nominal.base_rotation,
            p: self.nominal.base_translation,
        }
    }

    /// The flange pose (robot base frame) that puts the tool at `tool_pose` (measurement frame).
    fn flange_goal(&self, r: &Matrix3<f64>, p: &Vector3<f64>) -> IkGoal {
        let flange = Pose {
            r: *r,
            p: p - r * self.nominal.tool,
        };
        IkGoal::Flange(self.base().inverse().compose(&flange))
    }

    /// Compensate a sequence of targets: each row's nominal solution starts from the previous
    /// reached nominal solution, the first from `start` (rad).
    pub fn targets(
        &self,
        targets: &[Target],
        start: &[f64],
    ) -> Result<Vec<Compensated>, CompensateError> {
        let mut from = start.to_vec();
        let mut out = Vec::with_capacity(targets.len());
        for t in targets {
            let (c, nominal_reached) = self.target(t, &from)?;
            if nominal_reached {
                from.clone_from(&c.nominal_q);
            }
            out.push(c);
        }
        Ok(out)
    }

    /// One target from `start`; also whether the nominal model reached it.
    fn target(&self, t: &Target, start: &[f64]) -> Result<(Compensated, bool), CompensateError> {
        let goal = match &t.rotation {
            Some(r) => self.flange_goal(r, &t.position_mm),
            None => IkGoal::Point {
                tool: self.nominal.tool,
                target: self.base().inverse().transform_point(&t.position_mm),
            },
        };
        let nominal = solve_within_limits(&self.nominal, start, &goal, &self.opts)
            .map_err(CompensateError::Joints)?;
        let r = t
            .rotation
            .unwrap_or_else(|| measured_rotation(&self.nominal, &nominal.q));
        let c = self.solve(&nominal.q, &r, &t.position_mm)?;
        Ok((c, nominal.reached))
    }

    /// A program point: the joints that put the identified model's tool where the nominal
    /// model puts it at `q_nominal` (rad).
    pub fn program_point(&self, q_nominal: &[f64]) -> Result<Compensated, CompensateError> {
        if q_nominal.len() != self.dof() {
            return Err(CompensateError::Joints(IkError::DofMismatch {
                expected: self.dof(),
                got: q_nominal.len(),
            }));
        }
        if q_nominal.iter().any(|v| !v.is_finite()) {
            return Err(CompensateError::Joints(IkError::NotFinite));
        }
        let r = measured_rotation(&self.nominal, q_nominal);
        let p = measured_point(&self.nominal, q_nominal);
        self.solve(q_nominal, &r, &p)
    }

    /// The identified model's solution for the tool pose (`r`, `p`) from the nominal solution.
    fn solve(
        &self,
        nominal_q: &[f64],
        r: &Matrix3<f64>,
        p: &Vector3<f64>,
    ) -> Result<Compensated, CompensateError> {
        let goal = self.flange_goal(r, p);
        let s = solve_within_limits(&self.identified, nominal_q, &goal, &self.opts)
            .map_err(CompensateError::Joints)?;
        let residual_mm = (measured_point(&self.identified, &s.q) - p).norm();
        let residual_rad =
            log_so3(&(r * measured_rotation(&self.identified, &s.q).transpose())).norm();
        Ok(Compensated {
            reachable: s.reached,
            q: s.q,
            nominal_q: nominal_q.to_vec(),
            residual_mm,
            residual_rad,
            at_limit: s.at_limit,
        })
    }
}
