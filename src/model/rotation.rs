//! Small rotation helpers: rotation vectors (axis·angle, rad) and SO(3) projection.

use nalgebra::{Matrix3, Rotation3, Vector3};

/// Rotation matrix of a rotation vector (axis · angle, rad).
pub fn from_rotation_vector(v: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::from_scaled_axis(*v).into_inner()
}

/// Rotation vector (axis · angle, rad) of a rotation matrix; robust near 0 and π.
pub fn to_rotation_vector(r: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix_unchecked(*r).scaled_axis()
}

/// Rotation vector of a rotation matrix, accurate to machine precision for small angles.
///
/// [`to_rotation_vector`] takes the angle from `acos((tr − 1)/2)`, which rounds angles below
/// ~1e-8 rad to zero; this one uses `atan2(‖vee(R − Rᵀ)‖/2, (tr − 1)/2)` below π/2 (and the
/// former above, where `acos` is well conditioned). Use it for tight convergence tests.
pub fn log_so3(r: &Matrix3<f64>) -> Vector3<f64> {
    let v = 0.5
        * Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        );
    let c = 0.5 * (r.trace() - 1.0);
    let s = v.norm();
    if c <= 0.0 {
        return to_rotation_vector(r);
    }
    if s == 0.0 {
        return Vector3::zeros();
    }
    v * (s.atan2(c) / s)
}

/// Nearest rotation matrix (SVD projection onto SO(3)).
pub fn project_so3(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    u * d * vt
}

/// Skew-symmetric cross-product matrix `[v]×`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_vector_round_trip() {
        for v in [
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(3.0, 0.1, 0.0),
        ] {
            let r = from_rotation_vector(&v);
            let w = to_rotation_vector(&r);
            assert!((v - w).norm() < 1e-12, "{v} vs {w}");
        }
    }

    #[test]
    fn log_is_exact_for_tiny_angles() {
        for v in [
            Vector3::new(1e-11, -2e-12, 3e-12),
            Vector3::new(1e-7, 0.0, -1e-7),
            Vector3::new(0.3, -1.2, 0.4),
            Vector3::new(2.9, 0.1, 0.0),
        ] {
            let w = log_so3(&from_rotation_vector(&v));
            assert!((v - w).norm() <= 1e-15 + 1e-12 * v.norm(), "{v} vs {w}");
        }
    }

    #[test]
    fn projection_keeps_rotations() {
        let r = from_rotation_vector(&Vector3::new(0.3, 0.2, -0.1));
        let noisy = r + Matrix3::from_element(1e-4);
        let p = project_so3(&noisy);
        assert!((p.transpose() * p - Matrix3::identity()).norm() < 1e-12);
        assert!((p.determinant() - 1.0).abs() < 1e-12);
        assert!((p - r).norm() < 1e-3);
    }
}
