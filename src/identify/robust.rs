//! Robust identification: iteratively reweighted least squares with a Huber or Cauchy loss on
//! each pose's residual norm, then rejection of gross outliers and a final plain fit.
//!
//! The scale is the median pose residual norm `m`; a pose with norm `s` has `u = s/m`. Huber
//! weights `min(1, c/u)`, Cauchy `1/(1 + (u/c)²)` with `c = 3`. After the weights settle, poses
//! with `u > 6` (for Gaussian noise that is beyond 9σ: no good pose is ever lost) are rejected
//! and the rest is fitted without robust weights, so the final estimate and its standard
//! deviations are the ordinary maximum-likelihood ones on the inliers.

use super::observation::{Measured, ObsConfig};
use super::params::ParamId;
use super::problem::CalibProblem;
use super::solver::{self, Linearization, Options, Solution};
use super::IdentifyError;
use crate::model::RobotModel;

/// Robust loss function.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobustLoss {
    /// Huber: quadratic near zero, linear in the tails.
    Huber,
    /// Cauchy (Lorentzian): strongly redescending.
    Cauchy,
}

/// Tuning constant (in units of the median pose residual).
pub const TUNING: f64 = 3.0;
/// Rejection threshold (in units of the median pose residual).
pub const REJECT: f64 = 6.0;

impl RobustLoss {
    /// IRLS weight for a normalised residual `u`.
    pub fn weight(self, u: f64) -> f64 {
        match self {
            RobustLoss::Huber => {
                if u <= TUNING {
                    1.0
                } else {
                    TUNING / u
                }
            }
            RobustLoss::Cauchy => 1.0 / (1.0 + (u / TUNING).powi(2)),
        }
    }
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// IRLS fit from `initial` (`start`: the plain problem's linearisation there); returns the
/// final inlier fit and the rejected pose indices.
pub fn solve_robust(
    initial: &RobotModel,
    start: Linearization,
    poses: &[Measured],
    cfg: &ObsConfig,
    params: &[ParamId],
    loss: RobustLoss,
    opts: &Options,
) -> Result<(Solution<RobotModel>, Vec<usize>), IdentifyError> {
    let base: Vec<f64> = poses.iter().map(|p| p.weight).collect();
    let mut work: Vec<Measured> = poses.to_vec();
    let mut sol = solver::solve_from(
        &CalibProblem::new(&work, cfg, params),
        initial.clone(),
        start,
        opts,
    );
    let mut u = Vec::new();
    for _ in 0..30 {
        let plain: Vec<Measured> = poses.to_vec();
        let norms = CalibProblem::new(&plain, cfg, params).pose_norms(&sol.state);
        let m = median(&norms).max(1e-12);
        u = norms.iter().map(|s| s / m).collect::<Vec<f64>>();
        let mut change: f64 = 0.0;
        for (i, p) in work.iter_mut().enumerate() {
            let w = base[i] * loss.weight(u[i]).sqrt();
            change = change.max((w - p.weight).abs() / base[i].max(1e-300));
            p.weight = w;
        }
        sol = solver::solve(&CalibProblem::new(&work, cfg, params), sol.state, opts);
        if change < 1e-4 {
            break;
        }
    }
    let rejected: Vec<usize> = (0..poses.len()).filter(|&i| u[i] > REJECT).collect();
    let remaining = poses.len() - rejected.len();
    if remaining * cfg.model.rows() <= params.len() || remaining < poses.len() / 2 {
        return Err(IdentifyError::TooManyOutliers {
            rejected: rejected.len(),
            poses: poses.len(),
        });
    }
    let inliers: Vec<Measured> = poses
        .iter()
        .enumerate()
        .map(|(i, p)| Measured {
            weight: if rejected.contains(&i) { 0.0 } else { p.weight },
            ..p.clone()
        })
        .collect();
    let fin = solver::solve(&CalibProblem::new(&inliers, cfg, params), sol.state, opts);
    Ok((fin, rejected))
}
