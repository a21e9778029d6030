//! Levenberg–Marquardt on the normal equations: Marquardt scaling, Nielsen's damping update,
//! geodesic acceleration and MINPACK-style termination.
//!
//! Own implementation rather than the `levenberg-marquardt` crate: the problems here have few
//! parameters (≤ 39) and many rows (up to 120 000), so accumulating `JᵀJ` block by block and
//! solving a 39×39 Cholesky system is far cheaper than MINPACK's dense QR of the whole
//! Jacobian, never stores the Jacobian, and supports the manifold update of the base rotation.
//!
//! - **Scaling** (Moré 1978, as MINPACK): the damping is `λ·D²` with `D` the running maximum of
//!   the Jacobian's column norms `√diag(JᵀJ)`, so the step does not depend on the parameters'
//!   units. The damped system is solved in scaled variables (`D⁻¹JᵀJD⁻¹ + λI`, unit diagonal),
//!   which keeps the Cholesky factorisation accurate when the scaled Jacobian's condition
//!   number is ~10⁶ (real data: the UR5 set in `tests/data/realdata/`).
//! - **Geodesic acceleration** (Transtrum & Sethna 2012): the second-order correction `a` of the
//!   step along the curved valley of a sloppy model, from a finite-difference second directional
//!   derivative of the residuals; the step is `v + a/2`, or the plain `v` when
//!   `2‖Da‖/‖Dv‖ > 0.75` (the second-order path is not to be trusted that far; raising the
//!   damping instead cost the 7-DOF WAM set of the same source 10 extra iterations).
//!   It costs a pass over the data per trial, so it starts only once a step's actual cost
//!   reduction is off the predicted one by more than 25 % (never on well-posed simulated cases,
//!   which converge in 2–6 Gauss–Newton steps).
//!   On ill-conditioned real data the optimum lies far along a curved, nearly flat valley, where
//!   plain LM crawls: 2 456 iterations on the UR5 grid set, 166 with acceleration (288 and 37
//!   on the UR5 set with all grid poses).
//! - **Termination** (MINPACK `lmder`): `ftol` on the actual and predicted relative cost
//!   reduction (on the predicted one alone once the last step confirmed the model), `xtol` on the scaled step relative to the scaled parameter norm, `gtol` on the
//!   largest cosine between the residual and a Jacobian column; each is its own [`Termination`].

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};

/// Cost `½‖r‖²`, gradient `Jᵀr` and Gauss–Newton matrix `JᵀJ` at one state.
pub type Linearization = (f64, DVector<f64>, DMatrix<f64>);

/// A nonlinear least-squares problem `min ½‖r(x)‖²` over a state with a local step.
pub trait Problem {
    /// The state (e.g. a robot model).
    type State: Clone;
    /// Number of parameters in a step.
    fn dim(&self) -> usize;
    /// Number of residual rows.
    fn rows(&self) -> usize;
    /// Cost `½‖r‖²`, gradient `Jᵀr` and Gauss–Newton matrix `JᵀJ` at a state.
    fn linearize(&self, state: &Self::State) -> Linearization;
    /// Cost `½‖r‖²` at a state.
    fn cost(&self, state: &Self::State) -> f64;
    /// Apply a step.
    fn retract(&self, state: &Self::State, step: &[f64]) -> Self::State;
    /// The parameters' current values, for the relative step test (a parameter the state holds
    /// only through a local increment, like a rotation on a manifold, counts as 0).
    fn values(&self, state: &Self::State) -> Vec<f64>;
    /// `Jᵀ·r_vv`, with `r_vv ≈ (2/h)·((r(x ⊕ h·v) − r(x))/h − J·v)` the second directional
    /// derivative of the residuals along `v` (for geodesic acceleration); `None` when the
    /// problem does not provide it.
    fn second_directional(&self, state: &Self::State, v: &[f64], h: f64) -> Option<DVector<f64>> {
        let _ = (state, v, h);
        None
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// `ftol`: the actual and the predicted relative cost reduction of a step fell below `ftol`.
    CostConverged,
    /// `xtol`: the scaled step fell below `xtol` times the scaled parameter norm.
    StepConverged,
    /// `gtol`: the largest cosine between the residual and a Jacobian column fell below `gtol`.
    GradientConverged,
    /// The model predicts no cost reduction above round-off (a minimum to machine precision).
    NoFurtherReduction,
    /// No trial step lowered the cost although the model predicts a reduction (the residuals
    /// are not finite, or not smooth where the solver is).
    Stalled,
    /// The iteration limit was reached.
    MaxIterations,
}

impl Termination {
    /// Whether this counts as converged (a stationary point within the tolerances).
    pub fn converged(self) -> bool {
        !matches!(self, Termination::MaxIterations | Termination::Stalled)
    }

    /// Short description.
    pub fn describe(self) -> &'static str {
        match self {
            Termination::CostConverged => "relative cost reduction below ftol",
            Termination::StepConverged => "relative step below xtol",
            Termination::GradientConverged => {
                "gradient below gtol (residual orthogonal to the Jacobian)"
            }
            Termination::NoFurtherReduction => {
                "no further cost reduction possible (machine precision)"
            }
            Termination::Stalled => "no trial step lowered the cost",
            Termination::MaxIterations => "iteration limit reached",
        }
    }
}

/// Default iteration limit of [`Options`]: a safety net, not a tolerance. The UR5 grid set
/// needs ~170 accelerated iterations along its sloppy valley; MINPACK's default budget for 27
/// parameters is 100·(n + 1) = 2 800 evaluations.
pub const DEFAULT_MAX_ITERATIONS: usize = 500;

/// Solver options.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Maximum number of accepted iterations.
    pub max_iterations: usize,
    /// Relative cost-reduction tolerance (actual and predicted, per step).
    pub ftol: f64,
    /// Relative step tolerance: `‖D·δ‖ ≤ xtol·‖D·x‖` with `D` the column scaling.
    pub xtol: f64,
    /// Gradient tolerance: the largest cosine between the residual and a Jacobian column.
    pub gtol: f64,
    /// Use geodesic acceleration when the problem provides second directional derivatives,
    /// from the first step whose actual cost reduction is off the predicted one by > 25 %.
    pub geodesic_acceleration: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_iterations: DEFAULT_MAX_ITERATIONS,
            ftol: 1e-10,
            xtol: 1e-10,
            gtol: 1e-10,
            geodesic_acceleration: true,
        }
    }
}

/// Outcome of a solve.
#[derive(Debug, Clone)]
pub struct Solution<S> {
    /// Final state.
    pub state: S,
    /// Accepted iterations.
    pub iterations: usize,
    /// Cost evaluations (including rejected trial steps).
    pub evaluations: usize,
    /// Initial cost `½‖r‖²`.
    pub initial_cost: f64,
    /// Final cost `½‖r‖²`.
    pub final_cost: f64,
    /// Why it stopped.
    pub termination: Termination,
    /// `JᵀJ` at the solution (for the covariance).
    pub normal_matrix: DMatrix<f64>,
}

/// Initial damping, relative to the scaled Gauss–Newton matrix (unit diagonal): small, since
/// the identification starts close to its optimum and the update adapts within a few steps.
const INITIAL_DAMPING: f64 = 1e-6;
/// Damping beyond which no step can matter (the step is below round-off of the parameters).
const MAX_DAMPING: f64 = 1e20;
/// Relative finite-difference step of the second directional derivative (Transtrum: 0.1).
const ACCEL_FD_STEP: f64 = 0.1;
/// Largest accepted ratio `2‖Da‖/‖Dv‖` of acceleration to velocity (Transtrum: 0.75).
const ACCEL_MAX_RATIO: f64 = 0.75;
/// Trial steps per iteration before giving up.
const MAX_TRIALS: usize = 80;

/// Run Levenberg–Marquardt from `x0`.
pub fn solve<P: Problem>(problem: &P, x0: P::State, opts: &Options) -> Solution<P::State> {
    let start = problem.linearize(&x0);
    solve_from(problem, x0, start, opts)
}

/// The damped system `D⁻¹JᵀJD⁻¹ + λI` in scaled variables, factorised.
struct Damped {
    chol: Cholesky<f64, Dyn>,
    /// The column scaling `D`.
    diag: Vec<f64>,
}

impl Damped {
    /// Factorise `JᵀJ + λD²` (`None` when not positive definite in floating point).
    fn new(h: &DMatrix<f64>, diag: &[f64], lambda: f64) -> Option<Damped> {
        let n = diag.len();
        let scaled = DMatrix::from_fn(n, n, |i, j| {
            h[(i, j)] / (diag[i] * diag[j]) + if i == j { lambda } else { 0.0 }
        });
        Some(Damped {
            chol: scaled.cholesky()?,
            diag: diag.to_vec(),
        })
    }

    /// `−(JᵀJ + λD²)⁻¹·b`.
    fn solve_neg(&self, b: &DVector<f64>) -> DVector<f64> {
        let d = &self.diag;
        let rhs = DVector::from_fn(b.len(), |i, _| -b[i] / d[i]);
        let y = self.chol.solve(&rhs);
        DVector::from_fn(b.len(), |i, _| y[i] / d[i])
    }
}

/// `‖D·v‖`.
fn scaled_norm(diag: &[f64], v: &[f64]) -> f64 {
    diag.iter()
        .zip(v)
        .map(|(d, x)| (d * x).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The largest cosine between the residual and a Jacobian column: `|gᵢ|/(‖Jᵢ‖·‖r‖)` (columns
/// without effect are skipped; 0 when the residual is zero).
pub fn gradient_cosine(cost: f64, g: &DVector<f64>, h: &DMatrix<f64>) -> f64 {
    let rnorm = (2.0 * cost).sqrt();
    if rnorm == 0.0 {
        return 0.0;
    }
    (0..g.len())
        .filter(|&i| h[(i, i)] > 0.0)
        .map(|i| g[i].abs() / (h[(i, i)].sqrt() * rnorm))
        .fold(0.0, f64::max)
}

/// Reduction `−gᵀδ − ½δᵀHδ` of the Gauss–Newton model by a step `δ`.
fn model_reduction(g: &DVector<f64>, h: &DMatrix<f64>, step: &DVector<f64>) -> f64 {
    -g.dot(step) - 0.5 * step.dot(&(h * step))
}

/// One proposed step: the velocity `v` (the LM step) and the step taken (`v + a/2`).
struct Proposal {
    velocity: DVector<f64>,
    step: DVector<f64>,
}

/// The iteration state of [`solve_from`].
struct Lm<'p, P: Problem> {
    problem: &'p P,
    opts: &'p Options,
    state: P::State,
    cost: f64,
    g: DVector<f64>,
    h: DMatrix<f64>,
    /// Column scaling `D`: running maximum of the column norms.
    diag: Vec<f64>,
    lambda: f64,
    nu: f64,
    iterations: usize,
    evaluations: usize,
    /// Whether a trial step of this iteration gave a non-finite cost.
    non_finite: bool,
    /// Whether steps are geodesically accelerated (see [`Lm::note_model_fit`]).
    curved: bool,
    /// Whether the last accepted step reduced the cost as the quadratic model predicted.
    model_confirmed: bool,
}

/// What [`Lm::propose`] gave.
enum Proposed {
    /// A step to try.
    Step(Proposal),
    /// No step at this damping (it has been raised): try again.
    Retry,
    /// Stop here.
    Stop(Termination),
}

/// What one trial step gave.
enum Trial {
    /// Accepted; the solver stops here when `Some`.
    Accepted(Option<Termination>),
    /// Rejected; the solver stops here when `Some`.
    Rejected(Option<Termination>),
}

impl<P: Problem> Lm<'_, P> {
    /// Raise the column scaling to the current column norms (zero columns: 1).
    fn update_scaling(&mut self) {
        for (i, d) in self.diag.iter_mut().enumerate() {
            let c = self.h[(i, i)].sqrt();
            *d = if *d == 0.0 && c == 0.0 { 1.0 } else { d.max(c) };
        }
    }

    fn reject(&mut self) {
        self.lambda *= self.nu;
        self.nu *= 2.0;
        self.note_model_fit(0.0);
    }

    /// Switch geodesic acceleration on (when enabled) once a step shows that the quadratic
    /// model is off by more than a quarter (`rho` = actual / predicted reduction): a problem
    /// that converges in a few Gauss–Newton steps never pays for the extra pass over the data.
    fn note_model_fit(&mut self, rho: f64) {
        if (rho - 1.0).abs() > 0.25 {
            self.curved |= self.opts.geodesic_acceleration;
        }
    }

    /// The step at the current damping, with geodesic acceleration when enabled; a retry when
    /// the damped system is not positive definite or the acceleration is not finite (the
    /// damping has been raised); the `ftol` stop when the last step confirmed the quadratic
    /// model (`|rho − 1| ≤ 0.25`) and it predicts a relative reduction below `ftol` (this saves
    /// the pass over the data that would only confirm it).
    fn propose(&mut self) -> Proposed {
        let Some(damped) = Damped::new(&self.h, &self.diag, self.lambda) else {
            self.reject();
            return Proposed::Retry;
        };
        let velocity = damped.solve_neg(&self.g);
        if self.model_confirmed
            && model_reduction(&self.g, &self.h, &velocity) <= self.opts.ftol * self.cost
        {
            return Proposed::Stop(Termination::CostConverged);
        }
        let v_norm = scaled_norm(&self.diag, velocity.as_slice());
        let rvv = if self.curved && v_norm > 0.0 {
            let v = velocity.as_slice();
            self.problem
                .second_directional(&self.state, v, ACCEL_FD_STEP)
        } else {
            None
        };
        let Some(rvv) = rvv else {
            return Proposed::Step(Proposal {
                step: velocity.clone(),
                velocity,
            });
        };
        let accel = damped.solve_neg(&rvv);
        let ratio = 2.0 * scaled_norm(&self.diag, accel.as_slice()) / v_norm;
        if !ratio.is_finite() {
            self.non_finite = true;
            self.reject();
            return Proposed::Retry;
        }
        let step = if ratio <= ACCEL_MAX_RATIO {
            &velocity + 0.5 * accel
        } else {
            // the second-order path is not to be trusted this far: a plain LM step
            velocity.clone()
        };
        Proposed::Step(Proposal { step, velocity })
    }

    /// Evaluate a proposed step: accept it (and test `ftol` and `xtol`) or reject it.
    fn try_step(&mut self, p: Proposal) -> Trial {
        let trial = self.problem.retract(&self.state, p.step.as_slice());
        let (new_cost, new_g, new_h) = self.problem.linearize(&trial);
        self.evaluations += 1;
        // the predicted reduction of the velocity (for an LM step ½vᵀHv + λ‖Dv‖² > 0)
        let pred = model_reduction(&self.g, &self.h, &p.velocity);
        let actual = self.cost - new_cost;
        let scaled_step = scaled_norm(&self.diag, p.step.as_slice());
        let x_norm = scaled_norm(&self.diag, &self.problem.values(&self.state));
        let small_step = scaled_step <= self.opts.xtol * x_norm;
        let no_reduction = pred <= f64::EPSILON * self.cost;
        if new_cost.is_finite() && actual > 0.0 {
            let rho = if pred > 0.0 { actual / pred } else { 1.0 };
            self.note_model_fit(rho);
            self.model_confirmed = (rho - 1.0).abs() <= 0.25;
            self.lambda *= (1.0_f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
            self.nu = 2.0;
            let old = self.cost;
            self.state = trial;
            (self.cost, self.g, self.h) = (new_cost, new_g, new_h);
            self.iterations += 1;
            let stop =
                if actual <= self.opts.ftol * old && pred <= self.opts.ftol * old && rho <= 2.0 {
                    Some(Termination::CostConverged)
                } else if small_step {
                    Some(Termination::StepConverged)
                } else {
                    None
                };
            return Trial::Accepted(stop);
        }
        self.reject();
        self.non_finite |= !new_cost.is_finite();
        Trial::Rejected(if small_step && self.non_finite {
            // the steps shrank only to escape non-finite residuals: no stationary point
            Some(Termination::Stalled)
        } else if small_step {
            Some(Termination::StepConverged)
        } else if no_reduction {
            Some(Termination::NoFurtherReduction)
        } else if self.lambda > MAX_DAMPING {
            Some(Termination::Stalled)
        } else {
            None
        })
    }

    /// One iteration: trial steps at growing damping until one is accepted; `Some` to stop.
    fn iterate(&mut self) -> Option<Termination> {
        self.non_finite = false;
        for _ in 0..MAX_TRIALS {
            if self.lambda > MAX_DAMPING {
                return Some(Termination::Stalled);
            }
            let p = match self.propose() {
                Proposed::Step(p) => p,
                Proposed::Retry => continue,
                Proposed::Stop(t) => return Some(t),
            };
            match self.try_step(p) {
                Trial::Accepted(stop) => return stop,
                Trial::Rejected(Some(t)) => return Some(t),
                Trial::Rejected(None) => {}
            }
        }
        Some(Termination::Stalled)
    }
}

/// Run Levenberg–Marquardt from `x0`, given the linearisation there (e.g. from an analysis
/// that already computed it).
pub fn solve_from<P: Problem>(
    problem: &P,
    x0: P::State,
    start: Linearization,
    opts: &Options,
) -> Solution<P::State> {
    let (cost, g, h) = start;
    let mut lm = Lm {
        problem,
        opts,
        state: x0,
        cost,
        g,
        h,
        diag: vec![0.0; problem.dim()],
        lambda: INITIAL_DAMPING,
        nu: 2.0,
        iterations: 0,
        evaluations: 1,
        non_finite: false,
        curved: false,
        model_confirmed: false,
    };
    let termination = loop {
        lm.update_scaling();
        if gradient_cosine(lm.cost, &lm.g, &lm.h) <= opts.gtol {
            break Termination::GradientConverged;
        }
        if lm.iterations >= opts.max_iterations {
            break Termination::MaxIterations;
        }
        if let Some(t) = lm.iterate() {
            break t;
        }
    };
    Solution {
        state: lm.state,
        iterations: lm.iterations,
        evaluations: lm.evaluations,
        initial_cost: cost,
        final_cost: lm.cost,
        termination,
        normal_matrix: lm.h,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small problem given by its residuals and Jacobian, with exact `r_vv` by finite
    /// differences of the Jacobian.
    trait Residuals {
        fn residuals(&self, x: &[f64]) -> (DVector<f64>, DMatrix<f64>);
    }

    struct Small<R: Residuals>(R, usize);

    impl<R: Residuals> Problem for Small<R> {
        type State = Vec<f64>;
        fn dim(&self) -> usize {
            self.1
        }
        fn rows(&self) -> usize {
            self.0.residuals(&vec![0.0; self.1]).0.len()
        }
        fn linearize(&self, x: &Vec<f64>) -> Linearization {
            let (r, j) = self.0.residuals(x);
            (
                0.5 * r.norm_squared(),
                j.transpose() * &r,
                j.transpose() * j,
            )
        }
        fn cost(&self, x: &Vec<f64>) -> f64 {
            self.linearize(x).0
        }
        fn retract(&self, x: &Vec<f64>, d: &[f64]) -> Vec<f64> {
            x.iter().zip(d).map(|(a, b)| a + b).collect()
        }
        fn values(&self, x: &Vec<f64>) -> Vec<f64> {
            x.clone()
        }
        fn second_directional(&self, x: &Vec<f64>, v: &[f64], h: f64) -> Option<DVector<f64>> {
            let (r0, j) = self.0.residuals(x);
            let (r1, _) = self
                .0
                .residuals(&self.retract(x, &v.iter().map(|a| h * a).collect::<Vec<_>>()));
            let jv = &j * DVector::from_column_slice(v);
            Some(j.transpose() * ((r1 - r0) / h - jv) * (2.0 / h))
        }
    }

    /// Rosenbrock's banana as least squares, `r = [A(y − x²), 1 − x]`, with an extra residual
    /// `c` that makes the optimum a non-zero-residual one when `c ≠ 0`.
    struct Banana {
        a: f64,
        c: f64,
    }

    impl Residuals for Banana {
        fn residuals(&self, s: &[f64]) -> (DVector<f64>, DMatrix<f64>) {
            let (x, y) = (s[0], s[1]);
            (
                DVector::from_vec(vec![self.a * (y - x * x), 1.0 - x, self.c * (x + y)]),
                DMatrix::from_row_slice(
                    3,
                    2,
                    &[-2.0 * self.a * x, self.a, -1.0, 0.0, self.c, self.c],
                ),
            )
        }
    }

    /// A badly scaled, nearly collinear linear least-squares problem `min ‖A·x − b‖²` whose
    /// columns differ by 10⁸ in scale (mm next to µrad, say).
    struct Linear {
        a: DMatrix<f64>,
        b: DVector<f64>,
    }

    impl Linear {
        fn new() -> Linear {
            let rows = 40;
            let scale = [1e4, 1e-4, 1.0];
            let a = DMatrix::from_fn(rows, 3, |i, j| {
                let t = i as f64 / rows as f64;
                let col = match j {
                    0 => 1.0 + t,
                    1 => 1.0 + t + 1e-3 * (7.0 * t).sin(),
                    _ => t * t,
                };
                col * scale[j]
            });
            let b = DVector::from_fn(rows, |i, _| (0.37 * i as f64).cos() + 2.0);
            Linear { a, b }
        }

        /// The least-squares solution by QR of the scaled columns.
        fn exact(&self) -> DVector<f64> {
            let n = self.a.ncols();
            let d: Vec<f64> = (0..n).map(|j| self.a.column(j).norm()).collect();
            let scaled = DMatrix::from_fn(self.a.nrows(), n, |i, j| self.a[(i, j)] / d[j]);
            let qr = scaled.qr();
            let y = qr
                .r()
                .solve_upper_triangular(&(qr.q().transpose() * &self.b))
                .expect("full rank");
            DVector::from_fn(n, |j, _| y[j] / d[j])
        }
    }

    impl Residuals for Linear {
        fn residuals(&self, x: &[f64]) -> (DVector<f64>, DMatrix<f64>) {
            (
                &self.a * DVector::from_column_slice(x) - &self.b,
                self.a.clone(),
            )
        }
    }

    fn only(ftol: f64, xtol: f64, gtol: f64) -> Options {
        Options {
            ftol,
            xtol,
            gtol,
            ..Options::default()
        }
    }

    #[test]
    fn rosenbrock_converges() {
        let p = Small(Banana { a: 10.0, c: 0.0 }, 2);
        let sol = solve(&p, vec![-1.2, 1.0], &Options::default());
        assert!(sol.termination.converged(), "{:?}", sol.termination);
        assert!((sol.state[0] - 1.0).abs() < 1e-9 && (sol.state[1] - 1.0).abs() < 1e-9);
        assert!(sol.final_cost < 1e-20);
    }

    #[test]
    fn each_tolerance_reports_its_own_termination() {
        // a non-zero-residual banana: the cost stalls at its positive minimum
        let p = Small(Banana { a: 10.0, c: 0.5 }, 2);
        let tight = solve(&p, vec![-1.2, 1.0], &only(0.0, 1e-15, 0.0));
        let cases = [
            (only(1e-10, 0.0, 0.0), Termination::CostConverged),
            (only(0.0, 1e-8, 0.0), Termination::StepConverged),
            (only(0.0, 0.0, 1e-8), Termination::GradientConverged),
        ];
        for (opts, expected) in cases {
            let sol = solve(&p, vec![-1.2, 1.0], &opts);
            assert_eq!(sol.termination, expected, "{opts:?}");
            assert!(sol.termination.converged());
            assert!(!sol.termination.describe().is_empty());
            assert!(sol.final_cost > 0.01, "non-zero residual");
            let rel = (sol.final_cost - tight.final_cost) / tight.final_cost;
            assert!(
                rel.abs() < 1e-9,
                "{expected:?}: cost off the optimum by {rel:e}"
            );
        }
        // the stop happens where the criterion says, not before
        let (_, g, h) = p.linearize(&tight.state);
        assert!(gradient_cosine(tight.final_cost, &g, &h) < 1e-8);
    }

    #[test]
    fn iteration_limit_is_not_convergence() {
        let p = Small(Banana { a: 10.0, c: 0.5 }, 2);
        let opts = Options {
            max_iterations: 2,
            ..Options::default()
        };
        let sol = solve(&p, vec![-1.2, 1.0], &opts);
        assert_eq!(sol.termination, Termination::MaxIterations);
        assert_eq!(sol.iterations, 2);
        assert!(!sol.termination.converged());
        assert_eq!(DEFAULT_MAX_ITERATIONS, Options::default().max_iterations);
    }

    /// Residuals that are not finite away from the start.
    struct Cliff;

    impl Residuals for Cliff {
        fn residuals(&self, x: &[f64]) -> (DVector<f64>, DMatrix<f64>) {
            let r = if x[0] == 1.0 { 1.0 } else { f64::NAN };
            (DVector::from_vec(vec![r]), DMatrix::from_element(1, 1, 1.0))
        }
    }

    #[test]
    fn non_finite_residuals_stall_unconverged() {
        let sol = solve(&Small(Cliff, 1), vec![1.0], &Options::default());
        assert_eq!(sol.termination, Termination::Stalled);
        assert!(!sol.termination.converged());
        assert_eq!(sol.state, vec![1.0]);
    }

    #[test]
    fn badly_scaled_linear_least_squares_reaches_the_exact_solution() {
        let lin = Linear::new();
        let exact = lin.exact();
        let a = lin.a.clone();
        let p = Small(lin, 3);
        // the default tolerances stop within a thousandth of a standard deviation
        let sol = solve(&p, vec![0.0; 3], &Options::default());
        assert!(sol.termination.converged(), "{:?}", sol.termination);
        assert!(sol.iterations <= 10, "{} iterations", sol.iterations);
        let sigma0_sq = 2.0 * sol.final_cost / (a.nrows() - 3) as f64;
        let inv = (a.transpose() * &a).try_inverse().expect("invertible");
        for j in 0..3 {
            let std = (sigma0_sq * inv[(j, j)]).sqrt();
            let off = (sol.state[j] - exact[j]) / std;
            assert!(off.abs() < 1e-3, "x{j}: {off:e} σ off");
        }
        // tight tolerances reach the exact solution despite the 1e8 column scales, as far as
        // the cost resolves it (columns 0 and 1 are nearly collinear)
        let tight = solve(&p, vec![0.0; 3], &only(1e-15, 1e-15, 0.0));
        assert!(tight.termination.converged(), "{:?}", tight.termination);
        for j in 0..3 {
            let rel = (tight.state[j] - exact[j]) / exact[j];
            assert!(
                rel.abs() < 1e-6,
                "x{j}: {} vs {} ({rel:e})",
                tight.state[j],
                exact[j]
            );
        }
    }

    #[test]
    fn geodesic_acceleration_follows_a_narrow_curved_valley() {
        // a narrow banana (A = 1000): plain LM creeps along the valley floor
        let p = Small(Banana { a: 1000.0, c: 0.0 }, 2);
        let plain = Options {
            geodesic_acceleration: false,
            max_iterations: 10_000,
            ..Options::default()
        };
        let accel = Options {
            max_iterations: 10_000,
            ..Options::default()
        };
        let slow = solve(&p, vec![-1.2, 1.0], &plain);
        let fast = solve(&p, vec![-1.2, 1.0], &accel);
        for s in [&slow, &fast] {
            assert!(s.termination.converged(), "{:?}", s.termination);
            assert!((s.state[0] - 1.0).abs() < 1e-6, "{:?}", s.state);
        }
        assert!(
            2 * fast.iterations < slow.iterations,
            "accelerated {} vs plain {} iterations",
            fast.iterations,
            slow.iterations
        );
    }
}
