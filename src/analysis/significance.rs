//! Significance indices of the MDH parameters (paper §2.2, eq. 8–10; docs/method.md §3).
//!
//! For parameter k: perturb the nominal model by `dq_k` (0.1 mm for lengths, 0.1 rad for
//! angles), evaluate the pose error it causes (`dP`, `dn`, `do`, `da`) at N random joint
//! configurations, and average the projection of `S_k·dq_k` (`S_k = ∂·/∂q_k`, analytic) on it:
//! `e_p,k = (S_p,k · dP) dq_k / ‖dP‖` (0 where `dP = 0`), likewise for n, o, a.

use rand::{Rng, SeedableRng};
use serde::Serialize;

use crate::identify::params::{all_params, retract, ParamId};
use crate::model::kinematics::forward;
use crate::model::RobotModel;

/// Perturbation applied to lengths (mm).
pub const LENGTH_STEP_MM: f64 = 0.1;
/// Perturbation applied to angles (rad).
pub const ANGLE_STEP_RAD: f64 = 0.1;

/// Average significance indices of one parameter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Significance {
    /// Parameter name (`theta1`, …).
    pub name: String,
    /// Joint number (1-based).
    pub joint: usize,
    /// Unit of the parameter.
    pub unit: &'static str,
    /// Perturbation used (mm or rad).
    pub perturbation: f64,
    /// ē_p: position (mm).
    pub e_p_mm: f64,
    /// ē_n: flange x axis (unit vector change, dimensionless).
    pub e_n: f64,
    /// ē_o: flange y axis.
    pub e_o: f64,
    /// ē_a: flange z axis.
    pub e_a: f64,
}

fn projection(s: &nalgebra::Vector3<f64>, d: &nalgebra::Vector3<f64>, dq: f64) -> f64 {
    let n = d.norm();
    if n <= 1e-12 * dq.abs().max(1.0) {
        0.0
    } else {
        s.dot(d) * dq / n
    }
}

/// Significance indices of every MDH parameter over `samples` random joint configurations.
pub fn significance(model: &RobotModel, samples: usize, seed: u64) -> Vec<Significance> {
    let bare = model.bare();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let qs: Vec<Vec<f64>> = (0..samples)
        .map(|_| {
            bare.limits
                .iter()
                .map(|l| rng.random_range(l.min..=l.max))
                .collect()
        })
        .collect();
    let params = all_params(bare.dof(), false, false);
    let nominal: Vec<_> = qs.iter().map(|q| forward(&bare, q)).collect();
    params
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let dq = if p.is_angle() {
                ANGLE_STEP_RAD
            } else {
                LENGTH_STEP_MM
            };
            let mut step = vec![0.0; params.len()];
            step[k] = dq;
            let pert = retract(&bare, &params, &step);
            let mut sums = [0.0; 4];
            for (q, f0) in qs.iter().zip(&nominal) {
                let f1 = forward(&pert, q);
                let (t0, t1) = (f0.flange(), f1.flange());
                let ParamId::Mdh { joint, kind } = *p else {
                    unreachable!("only MDH parameters are analysed")
                };
                let screw = f0.screws(&bare.joints)[5 * joint + kind as usize];
                sums[0] += projection(&screw.point_rate(&t0.p), &(t1.p - t0.p), dq);
                for c in 0..3 {
                    let col0 = t0.r.column(c).into_owned();
                    let col1 = t1.r.column(c).into_owned();
                    sums[1 + c] += projection(&screw.direction_rate(&col0), &(col1 - col0), dq);
                }
            }
            let n = samples.max(1) as f64;
            Significance {
                name: p.name(),
                joint: p.joint_number().unwrap_or(0),
                unit: p.unit(),
                perturbation: dq,
                e_p_mm: sums[0] / n,
                e_n: sums[1] / n,
                e_o: sums[2] / n,
                e_a: sums[3] / n,
            }
        })
        .collect()
}
