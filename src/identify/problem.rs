//! The calibration least-squares problem over a set of poses.

use nalgebra::{DMatrix, DVector};

use super::observation::{residual_jacobian, Measured, ObsConfig};
use super::params::{retract, ParamId};
use super::solver::Problem;
use crate::model::RobotModel;

/// Stacked residuals of all poses with respect to the chosen parameters.
pub struct CalibProblem<'a> {
    poses: &'a [Measured],
    cfg: &'a ObsConfig,
    params: &'a [ParamId],
}

impl<'a> CalibProblem<'a> {
    /// A problem over `poses` (weights in each pose) for `params`.
    pub fn new(poses: &'a [Measured], cfg: &'a ObsConfig, params: &'a [ParamId]) -> Self {
        CalibProblem { poses, cfg, params }
    }

    /// Weighted residual norm of each pose at a state.
    pub fn pose_norms(&self, state: &RobotModel) -> Vec<f64> {
        let mut res = vec![0.0; self.cfg.model.rows()];
        self.poses
            .iter()
            .map(|p| {
                residual_jacobian(state, p, self.cfg, self.params, &mut res, &mut []);
                res.iter().map(|r| r * r).sum::<f64>().sqrt()
            })
            .collect()
    }
}

impl Problem for CalibProblem<'_> {
    type State = RobotModel;

    fn dim(&self) -> usize {
        self.params.len()
    }

    fn rows(&self) -> usize {
        self.poses.len() * self.cfg.model.rows()
    }

    fn linearize(&self, state: &RobotModel) -> (f64, DVector<f64>, DMatrix<f64>) {
        let k = self.params.len();
        let rows = self.cfg.model.rows();
        let mut res = vec![0.0; rows];
        let mut jac = vec![0.0; rows * k];
        let mut h = vec![0.0; k * k];
        let mut g = vec![0.0; k];
        let mut cost = 0.0;
        for p in self.poses {
            if p.weight == 0.0 {
                continue;
            }
            residual_jacobian(state, p, self.cfg, self.params, &mut res, &mut jac);
            for r in 0..rows {
                let row = &jac[r * k..(r + 1) * k];
                let rv = res[r];
                cost += rv * rv;
                for a in 0..k {
                    let ja = row[a];
                    if ja == 0.0 {
                        continue;
                    }
                    g[a] += ja * rv;
                    let ha = &mut h[a * k..(a + 1) * k];
                    for b in a..k {
                        ha[b] += ja * row[b];
                    }
                }
            }
        }
        for a in 0..k {
            for b in 0..a {
                h[a * k + b] = h[b * k + a];
            }
        }
        (
            0.5 * cost,
            DVector::from_vec(g),
            DMatrix::from_row_slice(k, k, &h),
        )
    }

    fn cost(&self, state: &RobotModel) -> f64 {
        let mut res = vec![0.0; self.cfg.model.rows()];
        let mut cost = 0.0;
        for p in self.poses {
            if p.weight == 0.0 {
                continue;
            }
            residual_jacobian(state, p, self.cfg, self.params, &mut res, &mut []);
            cost += res.iter().map(|r| r * r).sum::<f64>();
        }
        0.5 * cost
    }

    fn retract(&self, state: &RobotModel, step: &[f64]) -> RobotModel {
        retract(state, self.params, step)
    }
}
