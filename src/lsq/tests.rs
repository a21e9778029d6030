//! The core on textbook problems with known optima, and its stopping reasons.
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

fn tenfold(diagonal: Diagonal) -> Options {
    Options {
        geodesic_acceleration: false,
        damping: Damping::Tenfold {
            initial: 1e-3,
            max: 1e12,
            diagonal,
        },
        ..Options::default()
    }
}

#[test]
fn tenfold_damping_reaches_the_same_optima() {
    for diagonal in [Diagonal::MeanTrace, Diagonal::Own { floor: 1e-12 }] {
        let opts = tenfold(diagonal);
        let p = Small(Banana { a: 10.0, c: 0.0 }, 2);
        let sol = solve(&p, vec![-1.2, 1.0], &opts);
        assert!(sol.termination.converged(), "{:?}", sol.termination);
        assert!((sol.state[0] - 1.0).abs() < 1e-9 && (sol.state[1] - 1.0).abs() < 1e-9);
        if diagonal == Diagonal::MeanTrace {
            // isotropic damping is for parameters of one unit, not the 1e8 scales below
            continue;
        }
        let lin = Linear::new();
        let exact = lin.exact();
        let p = Small(lin, 3);
        let tight = Options {
            ftol: 1e-15,
            xtol: 1e-15,
            gtol: 0.0,
            ..opts
        };
        let sol = solve(&p, vec![0.0; 3], &tight);
        assert!(sol.termination.converged(), "{:?}", sol.termination);
        for j in 0..3 {
            let rel = (sol.state[j] - exact[j]) / exact[j];
            assert!(rel.abs() < 1e-6, "{diagonal:?} x{j}: {rel:e}");
        }
    }
}

/// `r = x − 1` from 0, every step capped at 0.1 per component, done within 1e-12.
struct Capped;

impl Problem for Capped {
    type State = Vec<f64>;
    fn dim(&self) -> usize {
        2
    }
    fn rows(&self) -> usize {
        2
    }
    fn linearize(&self, x: &Vec<f64>) -> Linearization {
        let r = DVector::from_iterator(2, x.iter().map(|v| v - 1.0));
        (0.5 * r.norm_squared(), r, DMatrix::identity(2, 2))
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
    fn shape_step(&self, _: &Vec<f64>, step: &mut DVector<f64>) {
        let big = step.amax();
        if big > 0.1 {
            *step *= 0.1 / big;
        }
    }
    fn reached(&self, x: &Vec<f64>) -> bool {
        x.iter().all(|v| (v - 1.0).abs() <= 1e-12)
    }
}

#[test]
fn a_capped_problem_stops_at_its_own_target() {
    let opts = Options {
        ftol: 0.0,
        xtol: 0.0,
        gtol: 0.0,
        ..tenfold(Diagonal::MeanTrace)
    };
    let sol = solve(&Capped, vec![0.0, 0.0], &opts);
    assert_eq!(sol.termination, Termination::TargetReached);
    assert!(sol.termination.converged());
    assert!(Capped.reached(&sol.state));
    // a distance of 1 in steps of at most 0.1
    assert!((10..=12).contains(&sol.iterations), "{}", sol.iterations);
    // without the cap: a few Gauss–Newton steps (the damping shrinks tenfold per step)
    struct Free;
    impl Problem for Free {
        type State = Vec<f64>;
        fn dim(&self) -> usize {
            2
        }
        fn rows(&self) -> usize {
            2
        }
        fn linearize(&self, x: &Vec<f64>) -> Linearization {
            Capped.linearize(x)
        }
        fn cost(&self, x: &Vec<f64>) -> f64 {
            Capped.cost(x)
        }
        fn retract(&self, x: &Vec<f64>, d: &[f64]) -> Vec<f64> {
            Capped.retract(x, d)
        }
        fn values(&self, x: &Vec<f64>) -> Vec<f64> {
            x.clone()
        }
        fn reached(&self, x: &Vec<f64>) -> bool {
            Capped.reached(x)
        }
    }
    let free = solve(&Free, vec![0.0, 0.0], &opts);
    assert_eq!(free.termination, Termination::TargetReached);
    assert!(free.iterations <= 3, "{}", free.iterations);
}

#[test]
fn without_tolerances_the_solver_stops_at_machine_precision() {
    // a non-zero-residual optimum and no tolerance: only round-off ends the iteration
    let p = Small(Banana { a: 10.0, c: 0.5 }, 2);
    let tight = solve(&p, vec![-1.2, 1.0], &only(0.0, 0.0, 0.0));
    assert_eq!(tight.termination, Termination::NoFurtherReduction);
    assert!(tight.termination.converged());
    let (_, g, h) = p.linearize(&tight.state);
    assert!(gradient_cosine(tight.final_cost, &g, &h) < 1e-7);
}

#[test]
fn tenfold_damping_gives_up_unconverged_on_non_finite_residuals() {
    let sol = solve(&Small(Cliff, 1), vec![1.0], &tenfold(Diagonal::MeanTrace));
    assert_eq!(sol.termination, Termination::Stalled);
    assert_eq!(sol.state, vec![1.0]);
}
