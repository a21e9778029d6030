//! Numerical inverse kinematics of the flange for small Cartesian motions.
//!
//! Damped Newton (Levenberg–Marquardt, the crate's least-squares core [`crate::lsq`] with
//! Marquardt's ten-fold damping) on the flange pose error in the robot base frame:
//! position error `p* − p(q)` (mm) and rotation error `log(R*·R(q)ᵀ)` (rad, weighted by
//! [`IkOptions::rotation_scale_mm`]). The joint Jacobian is built from the θ screws of
//! [`Frames::screws`]: in MDH the derivative with respect to joint `i` equals the derivative
//! with respect to the θ_i offset. Each iteration's joint step is capped, so the solution stays
//! on the branch of the start configuration; the result must lie inside the joint limits.
//! Base and tool transforms are not applied: targets are flange poses (or a point of the flange
//! frame, [`IkGoal::Point`]) in the robot base frame. [`solve_within_limits`] keeps every iterate
//! inside the joint limits (projected steps) and returns the best pose it reaches.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::kinematics::{forward, Frames, Pose};
use super::rotation::{from_rotation_vector, log_so3};
use super::{JointLimit, RobotModel};
use crate::lsq::{self, Damping, Diagonal, Linearization, Termination};

/// Options of the inverse-kinematics iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkOptions {
    /// Maximum number of accepted Newton steps.
    pub max_iterations: usize,
    /// Position tolerance (mm).
    pub tol_mm: f64,
    /// Rotation tolerance (rad).
    pub tol_rad: f64,
    /// Weight of the rotation error against the position error in the damped step (mm per rad).
    pub rotation_scale_mm: f64,
    /// Largest change of any joint in one step (rad); keeps the solution on the start's branch.
    pub max_step_rad: f64,
}

impl Default for IkOptions {
    /// 200 steps, 1e-10 mm, 1e-12 rad, rotation weight 100 mm/rad, steps ≤ 0.1 rad.
    fn default() -> Self {
        IkOptions {
            max_iterations: 200,
            tol_mm: 1e-10,
            tol_rad: 1e-12,
            rotation_scale_mm: 100.0,
            max_step_rad: 0.1,
        }
    }
}

/// Why the inverse kinematics failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IkError {
    /// The start configuration does not match the model.
    #[error(
        "inverse kinematics: the start has {got} joint values, the model has {expected} joints"
    )]
    DofMismatch {
        /// Joints of the model.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// The start or the target contains a NaN or an infinity.
    #[error("inverse kinematics: start or target is not finite")]
    NotFinite,
    /// The iteration stopped with the target not reached (out of reach, or singular).
    #[error(
        "inverse kinematics did not converge after {iterations} steps: {position_mm:.3e} mm and \
         {rotation_rad:.3e} rad left (target out of reach or at a singularity)"
    )]
    NoConvergence {
        /// Accepted steps.
        iterations: usize,
        /// Remaining position error (mm).
        position_mm: f64,
        /// Remaining rotation error (rad).
        rotation_rad: f64,
    },
    /// The solution leaves a joint's limits.
    #[error(
        "inverse kinematics: joint {joint} would be at {value_rad:.4} rad, outside its limits \
         [{min_rad:.4}, {max_rad:.4}] rad"
    )]
    OutsideLimits {
        /// Joint number (1-based).
        joint: usize,
        /// Solution value (rad).
        value_rad: f64,
        /// Lower limit (rad).
        min_rad: f64,
        /// Upper limit (rad).
        max_rad: f64,
    },
}

/// A converged inverse-kinematics solution.
#[derive(Debug, Clone, PartialEq)]
pub struct IkSolution {
    /// Joint values (rad).
    pub q: Vec<f64>,
    /// Accepted Newton steps.
    pub iterations: usize,
    /// Remaining position error (mm).
    pub position_error_mm: f64,
    /// Remaining rotation error (rad).
    pub rotation_error_rad: f64,
}

/// A motion of the flange expressed in the flange frame at the start configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FlangeMotion {
    /// Translate by `distance_mm` along the unit `axis` (flange frame); orientation kept.
    Translate {
        /// Direction in the flange frame (normalised here).
        axis: Vector3<f64>,
        /// Distance (mm).
        distance_mm: f64,
    },
    /// Rotate by `angle_rad` about `axis` (flange frame) through the flange origin.
    Rotate {
        /// Axis in the flange frame (normalised here).
        axis: Vector3<f64>,
        /// Angle (rad, right-handed).
        angle_rad: f64,
    },
    /// A general relative transform `T_start⁻¹ · T_target` in the flange frame.
    Relative(Pose),
}

impl FlangeMotion {
    /// The motion as a transform in the start flange frame.
    pub fn as_pose(&self) -> Pose {
        match *self {
            FlangeMotion::Translate { axis, distance_mm } => Pose {
                r: Matrix3::identity(),
                p: axis.normalize() * distance_mm,
            },
            FlangeMotion::Rotate { axis, angle_rad } => Pose {
                r: from_rotation_vector(&(axis.normalize() * angle_rad)),
                p: Vector3::zeros(),
            },
            FlangeMotion::Relative(p) => p,
        }
    }
}

/// The flange pose `A_1 ⋯ A_n` in the robot base frame (base and tool not applied).
pub fn flange_pose(model: &RobotModel, q: &[f64]) -> Pose {
    *forward(model, q).flange()
}

/// Position (mm) and rotation (rad) error `target ⊖ current`, both in the base frame.
fn pose_error(target: &Pose, current: &Pose) -> (Vector3<f64>, Vector3<f64>) {
    (
        target.p - current.p,
        log_so3(&(target.r * current.r.transpose())),
    )
}

/// What the iteration drives to: a whole flange pose, or one point of the flange frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum IkGoal {
    /// The flange pose (robot base frame).
    Flange(Pose),
    /// The point `tool` (mm, flange frame) at `target` (mm, robot base frame); orientation free
    /// (the damped steps keep it near the start's).
    Point {
        /// The point in the flange frame (mm).
        tool: Vector3<f64>,
        /// Where it should be (mm, robot base frame).
        target: Vector3<f64>,
    },
}

impl IkGoal {
    /// Whether every number of the goal is finite.
    fn is_finite(&self) -> bool {
        match self {
            IkGoal::Flange(t) => t.r.iter().chain(t.p.iter()).all(|v| v.is_finite()),
            IkGoal::Point { tool, target } => {
                tool.iter().chain(target.iter()).all(|v| v.is_finite())
            }
        }
    }

    /// Position error (mm) and rotation error (rad; zero for a point) at the frames `f`.
    fn error(&self, f: &Frames) -> (Vector3<f64>, Vector3<f64>) {
        match self {
            IkGoal::Flange(t) => pose_error(t, f.flange()),
            IkGoal::Point { tool, target } => {
                (target - f.flange().transform_point(tool), Vector3::zeros())
            }
        }
    }

    /// The residual vector the step minimises: position, then rotation × `w` for a pose.
    fn weighted(&self, ep: &Vector3<f64>, er: &Vector3<f64>, w: f64) -> DVector<f64> {
        match self {
            IkGoal::Flange(_) => {
                DVector::from_iterator(6, ep.iter().copied().chain(er.iter().map(|v| v * w)))
            }
            IkGoal::Point { .. } => DVector::from_iterator(3, ep.iter().copied()),
        }
    }

    /// The joint Jacobian of [`IkGoal::weighted`] at commanded joints `q` (frames `f`): 6×n for
    /// a pose (velocity of the flange origin, then angular velocity × `w` mm/rad), 3×n for a
    /// point, from the θ screws at the link angles, times `I + ∂Δθ/∂q` when the model has
    /// non-geometric terms (§10: the link turns by `q + Δθ(q)`).
    fn jacobian(&self, model: &RobotModel, q: &[f64], f: &Frames, w: f64) -> DMatrix<f64> {
        let n = model.dof();
        let screws = f.screws(&model.joints);
        let (p, rows) = match self {
            IkGoal::Flange(_) => (f.flange().p, 6),
            IkGoal::Point { tool, .. } => (f.flange().transform_point(tool), 3),
        };
        let mut j = DMatrix::zeros(rows, n);
        for i in 0..n {
            let s = &screws[5 * i];
            let v = s.point_rate(&p);
            for k in 0..3 {
                j[(k, i)] = v[k];
                if rows == 6 {
                    j[(3 + k, i)] = w * s.axis[k];
                }
            }
        }
        if model.has_terms() {
            let chain = DMatrix::identity(n, n) + model.correction_rates(q);
            j *= chain;
        }
        j
    }
}

/// Where the damped Newton iteration stopped.
struct Reached {
    q: Vec<f64>,
    iterations: usize,
    position_mm: f64,
    rotation_rad: f64,
    converged: bool,
}

/// Joint `i` sits on a bound and the descent `g` points out of it (such a joint takes no step).
fn pushed_out(q: f64, g: f64, l: &JointLimit) -> bool {
    (q <= l.min && g < 0.0) || (q >= l.max && g > 0.0)
}

/// An iterate: joints (inside the bounds, when there are bounds), their frames and the
/// position (mm) and rotation (rad) error there.
#[derive(Clone)]
struct IkState {
    q: Vec<f64>,
    frames: Frames,
    ep: Vector3<f64>,
    er: Vector3<f64>,
}

/// The inverse kinematics as a least-squares problem for the core ([`crate::lsq`]): residual
/// `−`[`IkGoal::weighted`] error, the step capped at [`IkOptions::max_step_rad`], each trial
/// clamped into the bounds and a joint the descent pushes against its bound held (projected
/// Newton), the target the tolerances of [`IkOptions`].
struct IkProblem<'a> {
    model: &'a RobotModel,
    goal: &'a IkGoal,
    opts: &'a IkOptions,
    bounds: Option<&'a [JointLimit]>,
}

impl IkProblem<'_> {
    /// The iterate at joints `q` (clamped into the bounds first).
    fn at(&self, mut q: Vec<f64>) -> IkState {
        if let Some(b) = self.bounds {
            for (v, l) in q.iter_mut().zip(b) {
                *v = v.clamp(l.min, l.max);
            }
        }
        let frames = forward(self.model, &q);
        let (ep, er) = self.goal.error(&frames);
        IkState { q, frames, ep, er }
    }

    /// The solver's settings: Marquardt's ten-fold damping on the mean diagonal (joint angles
    /// share one unit), no relative tolerances (the target tolerances decide).
    fn lsq_options(&self) -> lsq::Options {
        lsq::Options {
            max_iterations: self.opts.max_iterations,
            ftol: 0.0,
            xtol: 0.0,
            gtol: 0.0,
            geodesic_acceleration: false,
            damping: Damping::Tenfold {
                initial: 1e-3,
                max: 1e12,
                diagonal: Diagonal::MeanTrace,
            },
        }
    }
}

impl lsq::Problem for IkProblem<'_> {
    type State = IkState;

    fn dim(&self) -> usize {
        self.model.dof()
    }

    fn rows(&self) -> usize {
        match self.goal {
            IkGoal::Flange(_) => 6,
            IkGoal::Point { .. } => 3,
        }
    }

    fn linearize(&self, s: &IkState) -> Linearization {
        let w = self.opts.rotation_scale_mm;
        let e = self.goal.weighted(&s.ep, &s.er, w);
        let j = self.goal.jacobian(self.model, &s.q, &s.frames, w);
        let jt = j.transpose();
        let mut h = &jt * &j;
        // the descent direction Jᵀe (e = target − current = −r)
        let mut g = &jt * &e;
        if let Some(b) = self.bounds {
            for (i, l) in b.iter().enumerate() {
                if pushed_out(s.q[i], g[i], l) {
                    h.row_mut(i).fill(0.0);
                    h.column_mut(i).fill(0.0);
                    g[i] = 0.0;
                }
            }
        }
        (0.5 * e.norm_squared(), -g, h)
    }

    fn cost(&self, s: &IkState) -> f64 {
        let e = self
            .goal
            .weighted(&s.ep, &s.er, self.opts.rotation_scale_mm);
        0.5 * e.norm_squared()
    }

    fn retract(&self, s: &IkState, step: &[f64]) -> IkState {
        self.at(s.q.iter().zip(step).map(|(a, b)| a + b).collect())
    }

    fn values(&self, s: &IkState) -> Vec<f64> {
        s.q.clone()
    }

    fn shape_step(&self, _: &IkState, step: &mut DVector<f64>) {
        let big = step.amax();
        if big > self.opts.max_step_rad {
            *step *= self.opts.max_step_rad / big;
        }
    }

    fn reached(&self, s: &IkState) -> bool {
        s.ep.norm() <= self.opts.tol_mm && s.er.norm() <= self.opts.tol_rad
    }
}

/// Damped Newton from `q0` towards `goal` (see the module doc) on the least-squares core.
/// With `bounds`, each trial is clamped into the joint limits and a joint the descent pushes
/// against its bound takes no step (projected Newton), so the iterate never leaves the limits.
/// Stops converged within the tolerances, or not converged after `max_iterations` or when no
/// damping gives a better pose.
fn iterate(
    model: &RobotModel,
    q0: &[f64],
    goal: &IkGoal,
    opts: &IkOptions,
    bounds: Option<&[JointLimit]>,
) -> Result<Reached, IkError> {
    let n = model.dof();
    if q0.len() != n {
        return Err(IkError::DofMismatch {
            expected: n,
            got: q0.len(),
        });
    }
    if q0.iter().any(|v| !v.is_finite()) || !goal.is_finite() {
        return Err(IkError::NotFinite);
    }
    let problem = IkProblem {
        model,
        goal,
        opts,
        bounds,
    };
    let start = problem.at(q0.to_vec());
    let sol = lsq::solve(&problem, start, &problem.lsq_options());
    let s = sol.state;
    Ok(Reached {
        position_mm: s.ep.norm(),
        rotation_rad: s.er.norm(),
        q: s.q,
        iterations: sol.iterations,
        converged: sol.termination == Termination::TargetReached,
    })
}

/// Solve for joints that put the flange at `target` (robot base frame), starting from `q0`.
pub fn solve_flange(
    model: &RobotModel,
    q0: &[f64],
    target: &Pose,
    opts: &IkOptions,
) -> Result<IkSolution, IkError> {
    let r = iterate(model, q0, &IkGoal::Flange(*target), opts, None)?;
    if !r.converged {
        return Err(IkError::NoConvergence {
            iterations: r.iterations,
            position_mm: r.position_mm,
            rotation_rad: r.rotation_rad,
        });
    }
    for (i, (v, l)) in r.q.iter().zip(&model.limits).enumerate() {
        if !l.contains(*v) {
            return Err(IkError::OutsideLimits {
                joint: i + 1,
                value_rad: *v,
                min_rad: l.min,
                max_rad: l.max,
            });
        }
    }
    Ok(IkSolution {
        q: r.q,
        iterations: r.iterations,
        position_error_mm: r.position_mm,
        rotation_error_rad: r.rotation_rad,
    })
}

/// The best joints inside the limits for a goal, reached or not ([`solve_within_limits`]).
#[derive(Debug, Clone, PartialEq)]
pub struct BoundedSolution {
    /// Joint values (rad), each inside its limits.
    pub q: Vec<f64>,
    /// Whether the goal was reached within the tolerances.
    pub reached: bool,
    /// Accepted Newton steps.
    pub iterations: usize,
    /// Remaining position error (mm).
    pub position_error_mm: f64,
    /// Remaining rotation error (rad; 0 for a point goal).
    pub rotation_error_rad: f64,
    /// Joints (1-based) sitting on a limit in `q`: the limits that bind when not `reached`.
    pub at_limit: Vec<usize>,
}

/// Joints for `goal` from `q0` (clamped into the limits first) that never leave the model's
/// joint limits: the goal reached, or the nearest pose the limits and the reach allow
/// (`reached` false, the remaining error and the joints on a limit reported).
pub fn solve_within_limits(
    model: &RobotModel,
    q0: &[f64],
    goal: &IkGoal,
    opts: &IkOptions,
) -> Result<BoundedSolution, IkError> {
    let r = iterate(model, q0, goal, opts, Some(&model.limits))?;
    let at_limit =
        r.q.iter()
            .zip(&model.limits)
            .enumerate()
            .filter(|(_, (v, l))| **v <= l.min || **v >= l.max)
            .map(|(i, _)| i + 1)
            .collect();
    Ok(BoundedSolution {
        q: r.q,
        reached: r.converged,
        iterations: r.iterations,
        position_error_mm: r.position_mm,
        rotation_error_rad: r.rotation_rad,
        at_limit,
    })
}

/// The flange target of a motion expressed in the flange frame at `q0` (robot base frame).
pub fn motion_target(model: &RobotModel, q0: &[f64], motion: &FlangeMotion) -> Pose {
    flange_pose(model, q0).compose(&motion.as_pose())
}

/// Solve for joints that perform `motion` (flange frame at `q0`), starting from `q0`.
pub fn solve_motion(
    model: &RobotModel,
    q0: &[f64],
    motion: &FlangeMotion,
    opts: &IkOptions,
) -> Result<IkSolution, IkError> {
    if q0.len() != model.dof() {
        return Err(IkError::DofMismatch {
            expected: model.dof(),
            got: q0.len(),
        });
    }
    solve_flange(model, q0, &motion_target(model, q0, motion), opts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tx60;

    const HOME: [f64; 6] = [0.1, 0.4, 1.7, 0.3, -0.6, 0.2];

    fn assert_reaches(m: &RobotModel, sol: &IkSolution, target: &Pose) {
        let got = flange_pose(m, &sol.q);
        let dp = (got.p - target.p).norm();
        let dr = log_so3(&(got.r * target.r.transpose())).norm();
        assert!(dp <= 1e-9 && dr <= 1e-9, "{dp:e} mm {dr:e} rad");
    }

    #[test]
    fn round_trip_translations_and_rotations() {
        let m = tx60();
        let opts = IkOptions::default();
        let axes = [
            Vector3::x(),
            Vector3::y(),
            Vector3::z(),
            Vector3::new(1.0, -2.0, 0.5),
        ];
        for axis in axes {
            for amount in [-50.0, -5.0, 0.001, 20.0, 80.0] {
                let motion = FlangeMotion::Translate {
                    axis,
                    distance_mm: amount,
                };
                let sol = solve_motion(&m, &HOME, &motion, &opts).expect("translation solves");
                assert_reaches(&m, &sol, &motion_target(&m, &HOME, &motion));
                // orientation kept, displacement along the flange axis
                let p0 = flange_pose(&m, &HOME);
                let p1 = flange_pose(&m, &sol.q);
                let want = p0.r * axis.normalize() * amount;
                assert!((p1.p - p0.p - want).norm() < 1e-9);
            }
            for angle in [-0.6, -0.2, 1e-6, 0.3, 0.6] {
                let motion = FlangeMotion::Rotate {
                    axis,
                    angle_rad: angle,
                };
                let sol = solve_motion(&m, &HOME, &motion, &opts).expect("rotation solves");
                assert_reaches(&m, &sol, &motion_target(&m, &HOME, &motion));
                assert!((flange_pose(&m, &sol.q).p - flange_pose(&m, &HOME).p).norm() < 1e-9);
            }
        }
    }

    #[test]
    fn general_target_from_forward_kinematics() {
        let m = tx60();
        let q_true = [0.25, 0.55, 1.5, 0.1, -0.4, 0.5];
        let target = flange_pose(&m, &q_true);
        let sol = solve_flange(&m, &HOME, &target, &IkOptions::default()).expect("solves");
        assert_reaches(&m, &sol, &target);
        // same branch: the joints themselves come back
        for (a, b) in sol.q.iter().zip(q_true) {
            assert!((a - b).abs() < 1e-8, "{a} vs {b}");
        }
    }

    #[test]
    fn out_of_reach_is_an_error() {
        let m = tx60();
        let far = FlangeMotion::Translate {
            axis: Vector3::z(),
            distance_mm: 1500.0,
        };
        match solve_motion(&m, &HOME, &far, &IkOptions::default()) {
            Err(IkError::NoConvergence { position_mm, .. }) => assert!(position_mm > 100.0),
            other => panic!("expected no convergence, got {other:?}"),
        }
    }

    #[test]
    fn joint_limits_are_enforced() {
        let m = tx60();
        let q0 = [0.1, 0.4, 1.7, 0.3, -0.6, 2.9];
        let spin = FlangeMotion::Rotate {
            axis: Vector3::z(),
            angle_rad: 0.5,
        };
        match solve_motion(&m, &q0, &spin, &IkOptions::default()) {
            Err(IkError::OutsideLimits { joint: 6, .. }) => {}
            other => panic!("expected joint 6 outside its limits, got {other:?}"),
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let m = tx60();
        let t = flange_pose(&m, &HOME);
        assert!(matches!(
            solve_flange(&m, &HOME[..5], &t, &IkOptions::default()),
            Err(IkError::DofMismatch {
                expected: 6,
                got: 5
            })
        ));
        let mut bad = t;
        bad.p.x = f64::NAN;
        assert_eq!(
            solve_flange(&m, &HOME, &bad, &IkOptions::default()),
            Err(IkError::NotFinite)
        );
    }

    /// The TX60 with masses on the arm and every kind of non-geometric term.
    fn with_terms() -> RobotModel {
        use crate::model::{Mass, TermKind};
        let mut m = tx60();
        m.masses = vec![
            Mass {
                frame: 2,
                at: Vector3::new(-150.0, 0.0, 120.0),
                kg: 8.4,
            },
            Mass {
                frame: 3,
                at: Vector3::new(20.0, 80.0, 50.0),
                kg: 5.0,
            },
            Mass {
                frame: 6,
                at: Vector3::new(0.0, 0.0, 60.0),
                kg: 2.0,
            },
        ];
        *m.term_mut(1, TermKind::Compliance) = 4e-6;
        *m.term_mut(2, TermKind::Compliance) = 6e-6;
        *m.term_mut(0, TermKind::SinQ) = 3e-4;
        *m.term_mut(2, TermKind::Cos2Q) = -4e-4;
        *m.term_mut(4, TermKind::CosQ) = 2e-4;
        m
    }

    #[test]
    fn the_jacobian_of_a_model_with_terms_is_the_derivative_of_its_forward_kinematics() {
        let m = with_terms();
        let q = [0.3, -0.4, 1.4, 0.2, -0.6, 1.1];
        let tool = Vector3::new(10.0, -20.0, 60.0);
        let w = 100.0;
        let goal = IkGoal::Flange(flange_pose(&m, &q));
        let jac = goal.jacobian(&m, &q, &forward(&m, &q), w);
        let point = IkGoal::Point {
            tool,
            target: Vector3::zeros(),
        };
        let jp = point.jacobian(&m, &q, &forward(&m, &q), w);
        let h = 1e-6;
        let mut worst: f64 = 0.0;
        for i in 0..6 {
            let (mut qp, mut qm) = (q, q);
            qp[i] += h;
            qm[i] -= h;
            let (a, b) = (flange_pose(&m, &qp), flange_pose(&m, &qm));
            let dp = (a.p - b.p) / (2.0 * h);
            let dr = log_so3(&(a.r * b.r.transpose())) / (2.0 * h);
            let dt = (a.transform_point(&tool) - b.transform_point(&tool)) / (2.0 * h);
            for k in 0..3 {
                worst = worst
                    .max((jac[(k, i)] - dp[k]).abs())
                    .max((jac[(3 + k, i)] - w * dr[k]).abs())
                    .max((jp[(k, i)] - dt[k]).abs());
            }
        }
        // the θ screws alone are off by the terms' rates (~1e-3 of ~600 mm/rad)
        assert!(
            worst < 1e-5,
            "Jacobian vs finite differences: {worst:e} mm/rad"
        );
    }

    #[test]
    fn targets_of_a_model_with_terms_are_reached_exactly() {
        let m = with_terms();
        let q_true = [0.25, 0.55, 1.5, 0.1, -0.4, 0.5];
        let target = flange_pose(&m, &q_true);
        let sol = solve_flange(&m, &HOME, &target, &IkOptions::default()).expect("solves");
        assert_reaches(&m, &sol, &target);
        for (a, b) in sol.q.iter().zip(q_true) {
            assert!((a - b).abs() < 1e-8, "{a} vs {b}");
        }
        // without the terms the same joints put the flange elsewhere
        let bare = RobotModel {
            terms: Vec::new(),
            ..m.clone()
        };
        assert!((flange_pose(&bare, &q_true).p - target.p).norm() > 0.1);
    }

    #[test]
    fn a_point_goal_places_the_point_and_leaves_the_orientation_free() {
        let m = tx60();
        let tool = Vector3::new(10.0, -20.0, 60.0);
        let q_true = [0.3, 0.5, 1.6, 0.2, 0.5, -0.3];
        let target = flange_pose(&m, &q_true).transform_point(&tool);
        let goal = IkGoal::Point { tool, target };
        let s = solve_within_limits(&m, &HOME, &goal, &IkOptions::default()).expect("solves");
        assert!(s.reached && s.at_limit.is_empty(), "{s:?}");
        let got = flange_pose(&m, &s.q).transform_point(&tool);
        assert!((got - target).norm() < 1e-9);
        assert_eq!(s.rotation_error_rad, 0.0);
    }

    #[test]
    fn bounded_solutions_stay_inside_the_limits_and_name_the_binding_joint() {
        let m = tx60();
        // reachable: the same answer as the unbounded solver
        let q_true = [0.25, 0.55, 1.5, 0.1, -0.4, 0.5];
        let target = flange_pose(&m, &q_true);
        let opts = IkOptions::default();
        let s = solve_within_limits(&m, &HOME, &IkGoal::Flange(target), &opts).unwrap();
        let u = solve_flange(&m, &HOME, &target, &opts).unwrap();
        assert!(s.reached);
        for (a, b) in s.q.iter().zip(&u.q) {
            assert!((a - b).abs() < 1e-9);
        }
        // joint 6 would have to pass its limit: it stops there, the rest as close as it gets
        let q0 = [0.1, 0.4, 1.7, 0.3, -0.6, 2.9];
        let spin = motion_target(
            &m,
            &q0,
            &FlangeMotion::Rotate {
                axis: Vector3::z(),
                angle_rad: 0.5,
            },
        );
        let s = solve_within_limits(&m, &q0, &IkGoal::Flange(spin), &opts).unwrap();
        assert!(!s.reached, "{s:?}");
        assert_eq!(s.at_limit, vec![6]);
        assert!(m.within_limits(&s.q), "{:?}", s.q);
        assert_eq!(s.q[5], m.limits[5].max);
        assert!(s.rotation_error_rad > 1e-3, "{s:?}");
    }
}
