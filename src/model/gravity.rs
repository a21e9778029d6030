//! The data of a robot's static gravity model: lumped masses fixed in its MDH frames and the
//! direction of gravity (the torques they put on the joints: [`super::kinematics::gravity_torques`], §10).

use nalgebra::Vector3;

/// Standard gravity (m/s²).
pub const STANDARD_GRAVITY_M_S2: f64 = 9.80665;

/// A lumped mass fixed in one MDH frame: a link, a motor, the payload.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mass {
    /// MDH frame it is fixed in (1..=n; frame k moves with joints 1..=k).
    pub frame: usize,
    /// Its centre of mass in that frame (mm).
    pub at: Vector3<f64>,
    /// Its mass (kg).
    pub kg: f64,
}

/// The default direction of gravity: −z of the robot base frame.
pub fn default_gravity() -> Vector3<f64> {
    -Vector3::z()
}
