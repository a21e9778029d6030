//! Covariance of the estimates `σ̂²·(JᵀJ)⁻¹`: the variance of unit weight from the fit's
//! redundancy, standard deviations and correlations.
//!
//! The inverse comes from the Cholesky factor `L` of `JᵀJ`: `L⁻¹` by forward substitution,
//! then `(JᵀJ)⁻¹ = L⁻ᵀL⁻¹`, each using only the triangles (a third of the work of solving
//! against the identity).

use nalgebra::DMatrix;

use super::observation::ObsModel;

/// The a-posteriori variance of unit weight `σ̂² = rᵀr / (n − u)` of a fit with final cost
/// `½rᵀr` over `poses` poses of `model` and `params` parameters: the redundancy `n − u` counts
/// independent observations ([`ObsModel::observations`]), not residual rows (at least 1).
pub fn unit_variance(final_cost: f64, poses: usize, model: ObsModel, params: usize) -> f64 {
    let redundancy = (poses * model.observations()).saturating_sub(params).max(1);
    2.0 * final_cost / redundancy as f64
}

/// Standard deviations and correlation matrix of the estimates.
#[derive(Debug, Clone, PartialEq)]
pub struct Covariance {
    /// Standard deviation of each parameter (its unit).
    pub std: Vec<f64>,
    /// Correlation matrix.
    pub correlation: DMatrix<f64>,
}

/// The covariance `σ̂²·(JᵀJ)⁻¹` of a fit with Gauss–Newton matrix `normal` and variance of unit
/// weight `sigma0_sq`; NaN throughout when `normal` is not positive definite.
pub fn covariance(normal: DMatrix<f64>, sigma0_sq: f64) -> Covariance {
    let k = normal.nrows();
    let cov =
        spd_inverse(normal).unwrap_or_else(|| DMatrix::from_element(k, k, f64::NAN)) * sigma0_sq;
    // NaN stays NaN (an undetermined σ must not read as a perfect 0)
    let std: Vec<f64> = (0..k)
        .map(|i| match cov[(i, i)] {
            v if v.is_nan() => f64::NAN,
            v => v.max(0.0).sqrt(),
        })
        .collect();
    let correlation = DMatrix::from_fn(k, k, |i, j| cov[(i, j)] / (std[i] * std[j]));
    Covariance { std, correlation }
}

/// Inverse of a symmetric positive-definite matrix (`None` when it is not).
pub fn spd_inverse(m: DMatrix<f64>) -> Option<DMatrix<f64>> {
    let k = m.nrows();
    let l = m.cholesky()?.unpack();
    // rows of L, and the columns of X = L⁻¹ (lower triangular): x[j*k + m] = X[m][j]
    let mut lr = vec![0.0; k * k];
    for i in 0..k {
        for m in 0..=i {
            lr[i * k + m] = l[(i, m)];
        }
    }
    let mut x = vec![0.0; k * k];
    for i in 0..k {
        let d = lr[i * k + i];
        x[i * k + i] = 1.0 / d;
        for j in 0..i {
            let s = dot(&lr[i * k + j..i * k + i], &x[j * k + j..j * k + i]);
            x[j * k + i] = -s / d;
        }
    }
    // (L⁻ᵀL⁻¹)[i][j] = Σ_{m ≥ i} X[m][i]·X[m][j] for i ≥ j
    let mut inv = DMatrix::zeros(k, k);
    for i in 0..k {
        for j in 0..=i {
            let s = dot(&x[i * k + i..(i + 1) * k], &x[j * k + i..(j + 1) * k]);
            inv[(i, j)] = s;
            inv[(j, i)] = s;
        }
    }
    Some(inv)
}

/// `Σ a_i·b_i` in order.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_of_spd_matrix() {
        let a = DMatrix::from_fn(5, 5, |i, j| ((i * 7 + j * 3) % 5) as f64 - 2.0);
        let m = a.transpose() * &a + DMatrix::identity(5, 5);
        let inv = spd_inverse(m.clone()).expect("positive definite");
        assert!((&m * &inv - DMatrix::identity(5, 5)).norm() < 1e-12);
        assert!(spd_inverse(-m).is_none());
    }

    #[test]
    fn a_singular_normal_matrix_gives_undetermined_not_zero_sigmas() {
        let singular = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 1.0, 1.0]);
        let c = covariance(singular, 0.01);
        assert!(c.std.iter().all(|s| s.is_nan()), "{:?}", c.std);
        let fine = DMatrix::from_row_slice(2, 2, &[4.0, 0.0, 0.0, 1.0]);
        let c = covariance(fine, 0.01);
        assert!((c.std[0] - 0.05).abs() < 1e-12 && (c.std[1] - 0.1).abs() < 1e-12);
    }
}
