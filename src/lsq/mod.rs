//! The crate's one nonlinear least-squares core: Levenberg–Marquardt on the normal equations
//! over a [`Problem`], used by identification (`identify`), inverse kinematics (`model::ik`)
//! and the sphere fit (`measure::sphere`). One loop holds the step acceptance, the damping
//! update ([`Damping`]), the stopping criteria ([`Termination`]) and the iteration count
//! ([`Solution`]); a problem gives its cost, gradient `Jᵀr` and Gauss–Newton matrix `JᵀJ`, its
//! update (`retract`: a manifold step, a clamp into bounds) and optionally a step cap and an
//! absolute target.
//!
//! Own implementation rather than the `levenberg-marquardt` crate: the problems here have few
//! parameters (≤ 39) and many rows (up to 120 000), so accumulating `JᵀJ` block by block and
//! solving a 39×39 Cholesky system is far cheaper than MINPACK's dense QR of the whole
//! Jacobian (that crate's `LeastSquaresProblem` hands over the whole Jacobian: 120 000 × 39
//! floats, 37 MB, per evaluation), never stores the Jacobian, and supports the manifold update
//! of the base rotation, the projected steps of bounded inverse kinematics and the geodesic
//! acceleration below, none of which that crate offers.
//!
//! - **Scaling** (Moré 1978, as MINPACK; [`Damping::Nielsen`]): the damping is `λ·D²` with `D`
//!   the running maximum of the Jacobian's column norms `√diag(JᵀJ)`, so the step does not
//!   depend on the parameters' units. The damped system is solved in scaled variables
//!   (`D⁻¹JᵀJD⁻¹ + λI`, unit diagonal), which keeps the Cholesky factorisation accurate when the
//!   scaled Jacobian's condition number is ~10⁶ (real data: the UR5 set in
//!   `tests/data/realdata/`). The small, well-conditioned problems (inverse kinematics, the
//!   sphere fit) use Marquardt's classic ten-fold update instead ([`Damping::Tenfold`]).
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
//!   reduction (on the predicted one alone once the last step confirmed the model), `xtol` on
//!   the scaled step relative to the scaled parameter norm, `gtol` on the largest cosine between
//!   the residual and a Jacobian column, and a problem's own absolute target
//!   ([`Problem::reached`]); each is its own [`Termination`].

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
    /// Shape a proposed LM step before it is tried (e.g. cap its largest component so that
    /// inverse kinematics stays on its branch); the default leaves it as it is.
    fn shape_step(&self, state: &Self::State, step: &mut DVector<f64>) {
        let _ = (state, step);
    }
    /// Whether the state meets the problem's own absolute target (e.g. a pose error below its
    /// tolerances): the solver stops there with [`Termination::TargetReached`]. Default: never.
    fn reached(&self, state: &Self::State) -> bool {
        let _ = state;
        false
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
    /// The problem's own target is met ([`Problem::reached`]).
    TargetReached,
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
            Termination::TargetReached => "target reached within its tolerances",
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

/// The diagonal `s` that [`Damping::Tenfold`] adds `λ·s` to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Diagonal {
    /// The mean of `diag(JᵀJ)` on every element (isotropic, as for joint angles of one unit).
    MeanTrace,
    /// Each element's own `(JᵀJ)ᵢᵢ`, at least `floor` (Marquardt 1963).
    Own {
        /// Smallest element added.
        floor: f64,
    },
}

/// How the damping `λ` enters the step and changes from step to step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Damping {
    /// `λ·D²` with Moré's running column scaling `D`, solved in scaled variables; Nielsen's
    /// update (`λ·max(⅓, 1 − (2ρ − 1)³)` on a step with gain ratio `ρ`, `λ·ν`, `ν` doubling, on a
    /// rejected one); from 1e-6, given up beyond 1e20. For ill-conditioned problems in mixed
    /// units (identification).
    Nielsen,
    /// Marquardt's classic: `λ·s` added to the diagonal of `JᵀJ` ([`Diagonal`]), `λ/10` (at
    /// least 1e-15) after an accepted step, `10·λ` after a rejected one; from `initial`, given
    /// up at `max`. For small well-conditioned problems (inverse kinematics, the sphere fit).
    Tenfold {
        /// Starting damping.
        initial: f64,
        /// Damping at which no step is tried any more.
        max: f64,
        /// What `λ` multiplies.
        diagonal: Diagonal,
    },
}

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
    /// The damping strategy.
    pub damping: Damping,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_iterations: DEFAULT_MAX_ITERATIONS,
            ftol: 1e-10,
            xtol: 1e-10,
            gtol: 1e-10,
            geodesic_acceleration: true,
            damping: Damping::Nielsen,
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

/// Initial damping of [`Damping::Nielsen`], relative to the scaled Gauss–Newton matrix (unit
/// diagonal): small, since the identification starts close to its optimum and the update
/// adapts within a few steps.
const INITIAL_DAMPING: f64 = 1e-6;
/// Damping of [`Damping::Nielsen`] beyond which no step can matter (the step is below
/// round-off of the parameters).
const MAX_DAMPING: f64 = 1e20;
/// Smallest damping [`Damping::Tenfold`] lowers to.
const MIN_TENFOLD_DAMPING: f64 = 1e-15;
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

/// The damped system, factorised.
enum Damped {
    /// `D⁻¹JᵀJD⁻¹ + λI` in scaled variables, with the column scaling `D`.
    Scaled {
        chol: Cholesky<f64, Dyn>,
        diag: Vec<f64>,
    },
    /// `JᵀJ + λ·diag(s)`.
    Plain(Cholesky<f64, Dyn>),
}

impl Damped {
    /// Factorise the damped system of `damping` (`None` when not positive definite in floating
    /// point).
    fn new(damping: &Damping, h: &DMatrix<f64>, diag: &[f64], lambda: f64) -> Option<Damped> {
        let n = diag.len();
        match damping {
            Damping::Nielsen => {
                let scaled = DMatrix::from_fn(n, n, |i, j| {
                    h[(i, j)] / (diag[i] * diag[j]) + if i == j { lambda } else { 0.0 }
                });
                Some(Damped::Scaled {
                    chol: scaled.cholesky()?,
                    diag: diag.to_vec(),
                })
            }
            Damping::Tenfold { diagonal, .. } => {
                let mut a = h.clone();
                match diagonal {
                    Diagonal::MeanTrace => {
                        let s = (h.trace() / n as f64).max(1e-300);
                        for i in 0..n {
                            a[(i, i)] += lambda * s;
                        }
                    }
                    Diagonal::Own { floor } => {
                        for i in 0..n {
                            a[(i, i)] += lambda * h[(i, i)].max(*floor);
                        }
                    }
                }
                Some(Damped::Plain(a.cholesky()?))
            }
        }
    }

    /// `−(damped system)⁻¹·b`.
    fn solve_neg(&self, b: &DVector<f64>) -> DVector<f64> {
        match self {
            Damped::Scaled { chol, diag: d } => {
                let rhs = DVector::from_fn(b.len(), |i, _| -b[i] / d[i]);
                let y = chol.solve(&rhs);
                DVector::from_fn(b.len(), |i, _| y[i] / d[i])
            }
            Damped::Plain(chol) => chol.solve(&(-b)),
        }
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

    /// Whether the damping is past the point where a step is still tried.
    fn exhausted(&self) -> bool {
        match self.opts.damping {
            Damping::Nielsen => self.lambda > MAX_DAMPING,
            Damping::Tenfold { max, .. } => self.lambda >= max,
        }
    }

    fn reject(&mut self) {
        match self.opts.damping {
            Damping::Nielsen => {
                self.lambda *= self.nu;
                self.nu *= 2.0;
            }
            Damping::Tenfold { .. } => self.lambda *= 10.0,
        }
        self.note_model_fit(0.0);
    }

    /// Lower the damping after a step with gain ratio `rho`.
    fn accept(&mut self, rho: f64) {
        match self.opts.damping {
            Damping::Nielsen => {
                self.lambda *= (1.0_f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
                self.nu = 2.0;
            }
            Damping::Tenfold { .. } => {
                self.lambda = (self.lambda / 10.0).max(MIN_TENFOLD_DAMPING);
            }
        }
    }

    /// Switch geodesic acceleration on (when enabled) once a step shows that the quadratic
    /// model is off by more than a quarter (`rho` = actual / predicted reduction): a problem
    /// that converges in a few Gauss–Newton steps never pays for the extra pass over the data.
    fn note_model_fit(&mut self, rho: f64) {
        if (rho - 1.0).abs() > 0.25 {
            self.curved |= self.opts.geodesic_acceleration;
        }
    }

    /// The step at the current damping (shaped by the problem), with geodesic acceleration
    /// when enabled; a retry when the damped system is not positive definite or the
    /// acceleration is not finite (the damping has been raised); the `ftol` stop when the last
    /// step confirmed the quadratic model (`|rho − 1| ≤ 0.25`) and it predicts a relative
    /// reduction below `ftol` (this saves the pass over the data that would only confirm it).
    fn propose(&mut self) -> Proposed {
        let Some(damped) = Damped::new(&self.opts.damping, &self.h, &self.diag, self.lambda) else {
            self.reject();
            return Proposed::Retry;
        };
        let mut velocity = damped.solve_neg(&self.g);
        self.problem.shape_step(&self.state, &mut velocity);
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
            self.accept(rho);
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
        } else if self.exhausted() {
            Some(Termination::Stalled)
        } else {
            None
        })
    }

    /// One iteration: trial steps at growing damping until one is accepted; `Some` to stop.
    fn iterate(&mut self) -> Option<Termination> {
        self.non_finite = false;
        for _ in 0..MAX_TRIALS {
            if self.exhausted() {
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
    let lambda = match opts.damping {
        Damping::Nielsen => INITIAL_DAMPING,
        Damping::Tenfold { initial, .. } => initial,
    };
    let mut lm = Lm {
        problem,
        opts,
        state: x0,
        cost,
        g,
        h,
        diag: vec![0.0; problem.dim()],
        lambda,
        nu: 2.0,
        iterations: 0,
        evaluations: 1,
        non_finite: false,
        curved: false,
        model_confirmed: false,
    };
    let termination = loop {
        lm.update_scaling();
        if problem.reached(&lm.state) {
            break Termination::TargetReached;
        }
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
mod tests;
