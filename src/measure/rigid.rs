//! Least-squares rigid registration (Kabsch/Horn): find `R, t` minimising `Σ‖R·a_i + t − b_i‖²`.

use nalgebra::{Matrix3, Vector3};

use crate::model::Pose;

/// Why a rigid fit failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RigidFitError {
    /// Fewer than three points, or the two lists differ in length.
    #[error("rigid fit needs at least 3 matching points, got {0}")]
    TooFewPoints(usize),
    /// The points are (nearly) collinear: the rotation is undetermined.
    #[error("rigid fit: points are collinear, rotation undetermined")]
    Degenerate,
}

/// Best rigid transform mapping points `a` onto points `b` (`b ≈ T·a`).
pub fn fit_rigid(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> Result<Pose, RigidFitError> {
    if a.len() != b.len() || a.len() < 3 {
        return Err(RigidFitError::TooFewPoints(a.len().min(b.len())));
    }
    let n = a.len() as f64;
    let ca = a.iter().sum::<Vector3<f64>>() / n;
    let cb = b.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (x, y) in a.iter().zip(b) {
        h += (x - ca) * (y - cb).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(RigidFitError::Degenerate);
    };
    let mut s = svd.singular_values.as_slice().to_vec();
    s.sort_by(|x, y| y.total_cmp(x));
    if s[1] <= 1e-9 * s[0].max(1e-300) {
        return Err(RigidFitError::Degenerate);
    }
    let v = vt.transpose();
    let mut d = Matrix3::identity();
    if (v * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = v * d * u.transpose();
    Ok(Pose { r, p: cb - r * ca })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::rotation::from_rotation_vector;

    #[test]
    fn recovers_transform() {
        let r = from_rotation_vector(&Vector3::new(0.4, -1.0, 2.5));
        let t = Vector3::new(2500.0, -30.0, 700.0);
        let a: Vec<_> = (0..10)
            .map(|i| {
                Vector3::new(
                    i as f64 * 37.0 % 101.0,
                    (i * i) as f64,
                    (i as f64).sin() * 50.0,
                )
            })
            .collect();
        let b: Vec<_> = a.iter().map(|x| r * x + t).collect();
        let fit = fit_rigid(&a, &b).unwrap();
        assert!((fit.r - r).norm() < 1e-10 && (fit.p - t).norm() < 1e-7);
    }

    #[test]
    fn collinear_is_error() {
        let a: Vec<_> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert_eq!(fit_rigid(&a, &a), Err(RigidFitError::Degenerate));
    }
}
