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

/// Poses per block of Jacobian rows folded into `JᵀJ` at once.
pub const BLOCK_POSES: usize = 64;

/// Poses above which the work is split over two threads.
pub const PARALLEL_MIN_POSES: usize = 256;

/// Apply `f` to two fixed halves of `items` on two threads (or to all of them on this thread
/// when there are few). The split does not depend on the machine, so sums are bit-for-bit
/// reproducible.
pub fn split_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&[T]) -> R + Sync) -> Vec<R> {
    if items.len() < PARALLEL_MIN_POSES {
        return vec![f(items)];
    }
    let (a, b) = items.split_at(items.len() / 2);
    std::thread::scope(|s| {
        let hb = s.spawn(|| f(b));
        let ra = f(a);
        match hb.join() {
            Ok(rb) => vec![ra, rb],
            Err(_) => vec![ra, f(b)],
        }
    })
}

impl CalibProblem<'_> {
    /// Cost, gradient and `JᵀJ` (row-major) over a chunk of poses.
    ///
    /// Jacobian rows are gathered in blocks of [`BLOCK_POSES`] poses and folded into `JᵀJ` by
    /// one matrix product per block (cache-friendly GEMM instead of a scalar loop per row).
    fn accumulate(&self, state: &RobotModel, chunk: &[Measured]) -> (f64, Vec<f64>, Vec<f64>) {
        let k = self.params.len();
        let rows = self.cfg.model.rows();
        // Each pose writes its row-major Jacobian block (rows × k) straight into `buf`; read as
        // a column-major matrix, `buf` is Jᵀ (k × block rows), so no reshuffling is needed.
        let cap = BLOCK_POSES * rows;
        let mut buf = vec![0.0; cap * k];
        let mut rb = vec![0.0; cap];
        let mut h = DMatrix::<f64>::zeros(k, k);
        let mut g = DVector::<f64>::zeros(k);
        let mut cost = 0.0;
        let mut filled = 0;
        let flush =
            |buf: &[f64], rb: &[f64], n: usize, h: &mut DMatrix<f64>, g: &mut DVector<f64>| {
                let jt = nalgebra::DMatrixView::from_slice(&buf[..n * k], k, n);
                let r = nalgebra::DVectorView::from_slice(&rb[..n], n);
                h.gemm(1.0, &jt, &jt.transpose(), 1.0);
                g.gemv(1.0, &jt, &r, 1.0);
            };
        for p in chunk.iter().filter(|p| p.weight != 0.0) {
            let (res, jac) = (
                &mut rb[filled..filled + rows],
                &mut buf[filled * k..(filled + rows) * k],
            );
            residual_jacobian(state, p, self.cfg, self.params, res, jac);
            cost += res.iter().map(|r| r * r).sum::<f64>();
            filled += rows;
            if filled == cap {
                flush(&buf, &rb, filled, &mut h, &mut g);
                filled = 0;
            }
        }
        if filled > 0 {
            flush(&buf, &rb, filled, &mut h, &mut g);
        }
        let h_rows: Vec<f64> = (0..k * k).map(|i| h[(i / k, i % k)]).collect();
        (cost, g.as_slice().to_vec(), h_rows)
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
        let parts = split_map(self.poses, |chunk| self.accumulate(state, chunk));
        let mut cost = 0.0;
        let mut g = vec![0.0; k];
        let mut h = vec![0.0; k * k];
        for (c, gp, hp) in parts {
            cost += c;
            g.iter_mut().zip(&gp).for_each(|(a, b)| *a += b);
            h.iter_mut().zip(&hp).for_each(|(a, b)| *a += b);
        }
        (
            0.5 * cost,
            DVector::from_vec(g),
            DMatrix::from_row_slice(k, k, &h),
        )
    }

    fn cost(&self, state: &RobotModel) -> f64 {
        let parts = split_map(self.poses, |chunk| {
            let mut res = vec![0.0; self.cfg.model.rows()];
            let mut cost = 0.0;
            for p in chunk.iter().filter(|p| p.weight != 0.0) {
                residual_jacobian(state, p, self.cfg, self.params, &mut res, &mut []);
                cost += res.iter().map(|r| r * r).sum::<f64>();
            }
            cost
        });
        0.5 * parts.iter().sum::<f64>()
    }

    fn retract(&self, state: &RobotModel, step: &[f64]) -> RobotModel {
        retract(state, self.params, step)
    }
}
