//! Least-squares sphere fit: an algebraic linear fit for the start, then Levenberg–Marquardt
//! (the crate's least-squares core, [`crate::lsq`]) on the geometric residuals `‖p_i − c‖ − r`.
//!
//! The conditioning of the geometric fit is reported: points on a small cap of the sphere (the
//! tool-setup pattern: two short arcs through one point) determine the centre along the cap's
//! axis poorly, and coplanar points (one circle) do not determine it at all. [`Sphere::condition`]
//! is the condition number of the geometric Jacobian at the solution (columns: centre x, y, z,
//! radius, all dimensionless), and [`Sphere::centre_noise_gain`] the RMS centre error (mm) per
//! 1 mm of point noise, `√trace((JᵀJ)⁻¹)` over the centre block.

use nalgebra::{DMatrix, DVector, Matrix4, Vector3, Vector4};

use crate::lsq::{self, Damping, Diagonal, Linearization, Termination};

/// Condition numbers above this count as degenerate (points on one circle or one line).
pub const MAX_SPHERE_CONDITION: f64 = 1e7;

/// Why a sphere fit failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SphereFitError {
    /// Fewer than four points.
    #[error("sphere fit needs at least 4 points, got {0}")]
    TooFewPoints(usize),
    /// A point contains a NaN or an infinity.
    #[error("sphere fit: point {0} is not finite")]
    NotFinite(usize),
    /// The points are coplanar or collinear (or coincide): no unique sphere.
    #[error(
        "sphere fit: points are (nearly) coplanar or collinear, no unique sphere \
         (condition {condition:.3e})"
    )]
    Degenerate {
        /// Condition number of the fit (∞ when exactly degenerate).
        condition: f64,
    },
    /// The geometric refinement did not converge.
    #[error("sphere fit did not converge in {0} iterations")]
    NoConvergence(usize),
}

/// A fitted sphere with its quality numbers.
#[derive(Debug, Clone, PartialEq)]
pub struct Sphere {
    /// Centre (mm, frame of the points).
    pub centre: Vector3<f64>,
    /// Radius (mm).
    pub radius_mm: f64,
    /// Geometric residuals `‖p_i − c‖ − r` (mm), in input order.
    pub residuals_mm: Vec<f64>,
    /// RMS of the residuals (mm).
    pub rms_mm: f64,
    /// Largest absolute residual (mm).
    pub max_residual_mm: f64,
    /// Condition number of the geometric Jacobian at the solution.
    pub condition: f64,
    /// RMS centre error (mm) per 1 mm of point noise: `√trace(((JᵀJ)⁻¹)_centre)`.
    pub centre_noise_gain: f64,
    /// Radius error (mm) per 1 mm of point noise: `√((JᵀJ)⁻¹)_rr`.
    pub radius_noise_gain: f64,
    /// Levenberg–Marquardt iterations of the geometric refinement.
    pub iterations: usize,
}

/// Algebraic fit `‖p‖² = 2c·p + k` on centred, scaled points; returns centre and radius.
fn algebraic(points: &[Vector3<f64>]) -> Result<(Vector3<f64>, f64), SphereFitError> {
    let n = points.len();
    let mean = points.iter().sum::<Vector3<f64>>() / n as f64;
    let scale = (points
        .iter()
        .map(|p| (p - mean).norm_squared())
        .sum::<f64>()
        / n as f64)
        .sqrt()
        .max(1e-300);
    let mut a = DMatrix::zeros(n, 4);
    let mut b = DVector::zeros(n);
    for (i, p) in points.iter().enumerate() {
        let x = (p - mean) / scale;
        a[(i, 0)] = 2.0 * x.x;
        a[(i, 1)] = 2.0 * x.y;
        a[(i, 2)] = 2.0 * x.z;
        a[(i, 3)] = 1.0;
        b[i] = x.norm_squared();
    }
    let svd = a.svd(true, true);
    let s = &svd.singular_values;
    let (smax, smin) = (s.max(), s.min());
    if smin <= 1e-10 * smax {
        return Err(SphereFitError::Degenerate {
            condition: if smin > 0.0 {
                smax / smin
            } else {
                f64::INFINITY
            },
        });
    }
    let sol = svd.solve(&b, 0.0).map_err(|_| SphereFitError::Degenerate {
        condition: f64::INFINITY,
    })?;
    let c = Vector3::new(sol[0], sol[1], sol[2]);
    let r2 = sol[3] + c.norm_squared();
    if r2.is_nan() || r2 <= 0.0 {
        return Err(SphereFitError::Degenerate {
            condition: f64::INFINITY,
        });
    }
    Ok((mean + c * scale, r2.sqrt() * scale))
}

/// Residuals, gradient-side Jacobian products and cost at (centre, radius).
fn normal_equations(
    points: &[Vector3<f64>],
    c: &Vector3<f64>,
    r: f64,
) -> (f64, Vector4<f64>, Matrix4<f64>) {
    let mut cost = 0.0;
    let mut g = Vector4::zeros();
    let mut h = Matrix4::zeros();
    for p in points {
        let d = p - c;
        let dist = d.norm();
        let res = dist - r;
        let nrm = if dist > 0.0 {
            d / dist
        } else {
            Vector3::zeros()
        };
        let row = Vector4::new(-nrm.x, -nrm.y, -nrm.z, -1.0);
        cost += res * res;
        g += row * res;
        h += row * row.transpose();
    }
    (cost, g, h)
}

/// The geometric fit as a least-squares problem for the core ([`crate::lsq`]): state
/// `(cx, cy, cz, r)`, residuals `‖p_i − c‖ − r`.
struct SphereProblem<'a>(&'a [Vector3<f64>]);

impl SphereProblem<'_> {
    /// The solver's settings: Marquardt's ten-fold damping on each parameter's own diagonal,
    /// stopped at a relative cost change of 1e-15 or a relative step of 1e-13 (round-off).
    fn lsq_options() -> lsq::Options {
        lsq::Options {
            max_iterations: MAX_ITER,
            ftol: 1e-15,
            xtol: 1e-13,
            gtol: 0.0,
            geodesic_acceleration: false,
            damping: Damping::Tenfold {
                initial: 1e-6,
                max: 1e16,
                diagonal: Diagonal::Own { floor: 1e-12 },
            },
        }
    }
}

/// Iteration limit of the geometric refinement.
const MAX_ITER: usize = 100;

impl lsq::Problem for SphereProblem<'_> {
    type State = Vector4<f64>;

    fn dim(&self) -> usize {
        4
    }

    fn rows(&self) -> usize {
        self.0.len()
    }

    fn linearize(&self, x: &Vector4<f64>) -> Linearization {
        let (cost, g, h) = normal_equations(self.0, &x.xyz(), x.w);
        (
            0.5 * cost,
            DVector::from_column_slice(g.as_slice()),
            DMatrix::from_column_slice(4, 4, h.as_slice()),
        )
    }

    fn cost(&self, x: &Vector4<f64>) -> f64 {
        0.5 * normal_equations(self.0, &x.xyz(), x.w).0
    }

    fn retract(&self, x: &Vector4<f64>, step: &[f64]) -> Vector4<f64> {
        Vector4::new(x.x + step[0], x.y + step[1], x.z + step[2], x.w + step[3])
    }

    fn values(&self, x: &Vector4<f64>) -> Vec<f64> {
        x.as_slice().to_vec()
    }
}

/// Fit a sphere to at least four points (least squares on the geometric distances).
pub fn fit_sphere(points: &[Vector3<f64>]) -> Result<Sphere, SphereFitError> {
    if points.len() < 4 {
        return Err(SphereFitError::TooFewPoints(points.len()));
    }
    if let Some(i) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        return Err(SphereFitError::NotFinite(i));
    }
    let (c0, r0) = algebraic(points)?;
    let sol = lsq::solve(
        &SphereProblem(points),
        Vector4::new(c0.x, c0.y, c0.z, r0),
        &SphereProblem::lsq_options(),
    );
    if sol.termination == Termination::MaxIterations {
        return Err(SphereFitError::NoConvergence(sol.iterations));
    }
    // any other stop is the minimum to the precision the residuals allow
    let (c, r, iterations) = (sol.state.xyz(), sol.state.w, sol.iterations);
    let h: Matrix4<f64> = sol.normal_matrix.fixed_view::<4, 4>(0, 0).into_owned();
    let eig = h.symmetric_eigen();
    let (emax, emin) = (eig.eigenvalues.max(), eig.eigenvalues.min());
    let condition = if emin > 0.0 {
        (emax / emin).sqrt()
    } else {
        f64::INFINITY
    };
    if condition.is_nan() || condition > MAX_SPHERE_CONDITION {
        return Err(SphereFitError::Degenerate { condition });
    }
    let cov = h.try_inverse().ok_or(SphereFitError::Degenerate {
        condition: f64::INFINITY,
    })?;
    let residuals_mm: Vec<f64> = points.iter().map(|p| (p - c).norm() - r).collect();
    let n = residuals_mm.len() as f64;
    let rms_mm = (residuals_mm.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let max_residual_mm = residuals_mm.iter().fold(0.0, |m: f64, v| m.max(v.abs()));
    Ok(Sphere {
        centre: c,
        radius_mm: r,
        residuals_mm,
        rms_mm,
        max_residual_mm,
        condition,
        centre_noise_gain: (cov[(0, 0)] + cov[(1, 1)] + cov[(2, 2)]).max(0.0).sqrt(),
        radius_noise_gain: cov[(3, 3)].max(0.0).sqrt(),
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn on_sphere(c: Vector3<f64>, r: f64, dirs: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        dirs.iter().map(|d| c + d.normalize() * r).collect()
    }

    fn cap_pattern(angles: &[f64]) -> Vec<Vector3<f64>> {
        // home direction +z; rotations about x and y (the tool-setup pattern)
        let mut v = vec![Vector3::z()];
        for &a in angles {
            v.push(Vector3::new(0.0, -a.sin(), a.cos()));
            v.push(Vector3::new(a.sin(), 0.0, a.cos()));
        }
        v
    }

    #[test]
    fn exact_points_give_exact_sphere() {
        let c = Vector3::new(2400.0, -310.5, 820.25);
        let r = 61.7;
        let dirs = [
            Vector3::new(1.0, 0.2, 0.1),
            Vector3::new(-0.3, 1.0, 0.4),
            Vector3::new(0.2, -0.5, 1.0),
            Vector3::new(-1.0, -1.0, -0.2),
            Vector3::new(0.7, -0.1, -1.0),
        ];
        let s = fit_sphere(&on_sphere(c, r, &dirs)).expect("fits");
        assert!((s.centre - c).norm() < 1e-9, "{}", s.centre - c);
        assert!((s.radius_mm - r).abs() < 1e-9);
        assert!(s.rms_mm < 1e-9);
        assert!(s.condition < 10.0, "condition {}", s.condition);
    }

    #[test]
    fn tool_setup_cap_is_exact_and_reports_its_conditioning() {
        let c = Vector3::new(1800.0, 250.0, -400.0);
        let r = 64.0;
        let pts = on_sphere(c, r, &cap_pattern(&[-0.4, -0.2, 0.2, 0.4]));
        let s = fit_sphere(&pts).expect("fits");
        assert!((s.centre - c).norm() < 1e-8, "{}", s.centre - c);
        assert!((s.radius_mm - r).abs() < 1e-8);
        // a ±0.4 rad cap: the centre along the axis is ~20× less certain than a point
        assert!(s.condition > 10.0 && s.condition < 200.0, "{}", s.condition);
        assert!(s.centre_noise_gain > 3.0 && s.centre_noise_gain < 50.0);
        // a wider cap is better conditioned
        let wide = fit_sphere(&on_sphere(c, r, &cap_pattern(&[-0.8, -0.4, 0.4, 0.8]))).unwrap();
        assert!(wide.condition < s.condition && wide.centre_noise_gain < s.centre_noise_gain);
    }

    #[test]
    fn noisy_points_agree_with_the_noise_gain() {
        let c = Vector3::new(100.0, 200.0, 300.0);
        let r = 50.0;
        let clean = on_sphere(c, r, &cap_pattern(&[-0.5, -0.25, 0.25, 0.5]));
        let sigma = 0.01;
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let trials = 400;
        let mut sq = 0.0;
        let mut gain = 0.0;
        for _ in 0..trials {
            let pts: Vec<_> = clean
                .iter()
                .map(|p| {
                    p + Vector3::new(
                        StandardNormal.sample(&mut rng),
                        StandardNormal.sample(&mut rng),
                        StandardNormal.sample(&mut rng),
                    ) * sigma
                })
                .collect();
            let s = fit_sphere(&pts).unwrap();
            sq += (s.centre - c).norm_squared();
            gain = s.centre_noise_gain;
        }
        let rms = (sq / trials as f64).sqrt();
        let predicted = gain * sigma;
        assert!(
            (rms / predicted - 1.0).abs() < 0.15,
            "centre rms {rms} vs predicted {predicted}"
        );
    }

    #[test]
    fn too_few_and_degenerate_points_are_errors() {
        let p = Vector3::new(1.0, 2.0, 3.0);
        assert_eq!(fit_sphere(&[p, p, p]), Err(SphereFitError::TooFewPoints(3)));
        // coplanar: one circle
        let circle: Vec<_> = (0..8)
            .map(|i| {
                let a = i as f64 * 0.7;
                Vector3::new(10.0 * a.cos(), 10.0 * a.sin(), 5.0)
            })
            .collect();
        assert!(matches!(
            fit_sphere(&circle),
            Err(SphereFitError::Degenerate { .. })
        ));
        // collinear
        let line: Vec<_> = (0..6)
            .map(|i| Vector3::new(i as f64, 2.0 * i as f64, 1.0))
            .collect();
        assert!(matches!(
            fit_sphere(&line),
            Err(SphereFitError::Degenerate { .. })
        ));
        // coincident
        assert!(matches!(
            fit_sphere(&[p, p, p, p, p]),
            Err(SphereFitError::Degenerate { .. })
        ));
        let mut bad = circle.clone();
        bad[2].y = f64::NAN;
        assert_eq!(fit_sphere(&bad), Err(SphereFitError::NotFinite(2)));
    }
}
