//! [`Pose`]: the one rigid transform, and the small functions named after its maths.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::rotation::{from_rotation_vector, to_rotation_vector};

/// The one rigid-transform type (`x ↦ r·x + p`): a link, the flange, the robot base in the
/// measurement frame, a fitted registration, a tracker frame segment into the first. Rotation
/// as a matrix (what the MDH chain, its Jacobians and the stored frames compute with, so every
/// result stays bit for bit); files and JSON keep their own spellings (rotation vector,
/// `translation_mm`) and convert at the edge ([`Pose::from_rotation_vector`],
/// [`Pose::rotation_vector`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Rotation; columns are the frame's x (n), y (o), z (a) axes.
    pub r: Matrix3<f64>,
    /// Origin (mm).
    pub p: Vector3<f64>,
}

impl Pose {
    /// The identity transform.
    pub fn identity() -> Pose {
        Pose {
            r: Matrix3::identity(),
            p: Vector3::zeros(),
        }
    }

    /// Composition `self · other`.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose {
            r: self.r * other.r,
            p: self.r * other.p + self.p,
        }
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Pose {
        let rt = self.r.transpose();
        Pose {
            r: rt,
            p: -(rt * self.p),
        }
    }

    /// Apply to a point.
    pub fn transform_point(&self, x: &Vector3<f64>) -> Vector3<f64> {
        self.r * x + self.p
    }

    /// Apply to a direction (rotation only).
    pub fn transform_vector(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.r * v
    }

    /// The transform of rotation vector `rotation_vector_rad` (exponential map) and
    /// translation `p`.
    pub fn from_rotation_vector(rotation_vector_rad: &Vector3<f64>, p: Vector3<f64>) -> Pose {
        Pose {
            r: from_rotation_vector(rotation_vector_rad),
            p,
        }
    }

    /// The rotation as a rotation vector (rad; logarithm map).
    pub fn rotation_vector(&self) -> Vector3<f64> {
        to_rotation_vector(&self.r)
    }

    /// The rotation angle (rad, in [0, π]).
    pub fn rotation_angle(&self) -> f64 {
        Rotation3::from_matrix_unchecked(self.r).angle()
    }
}
