//! The calibration least-squares problem over a set of poses.

use nalgebra::{DMatrix, DVector};

use super::observation::{residual_jacobian, Measured, ObsConfig};
use super::params::{retract, ParamId};
use super::solver::{Linearization, Problem};
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

/// Normal-equation sums of residual rows `r` with Jacobian `J`: `rᵀr`, `Jᵀr` and `JᵀJ`.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalSums {
    /// `rᵀr`.
    sum_sq: f64,
    /// `Jᵀr`.
    g: DVector<f64>,
    /// `JᵀJ`.
    h: DMatrix<f64>,
}

impl NormalSums {
    fn zeros(k: usize) -> NormalSums {
        NormalSums {
            sum_sq: 0.0,
            g: DVector::zeros(k),
            h: DMatrix::zeros(k, k),
        }
    }

    /// The sums of two fixed halves added in order (or the one part, or zeros).
    fn merge(parts: Vec<NormalSums>, k: usize) -> NormalSums {
        let mut it = parts.into_iter();
        let mut sums = it.next().unwrap_or_else(|| NormalSums::zeros(k));
        for p in it {
            sums.sum_sq += p.sum_sq;
            sums.g += p.g;
            sums.h += p.h;
        }
        sums
    }

    /// Cost `½rᵀr`, gradient `Jᵀr` and `JᵀJ`.
    pub fn linearization(self) -> Linearization {
        (0.5 * self.sum_sq, self.g, self.h)
    }
}

/// The normal-equation sums of the position rows and of the direction rows apart (direction
/// rows at unit direction weight), so that any direction weight can be applied afterwards.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitSums {
    /// The parameters (columns).
    params: Vec<ParamId>,
    /// Position rows.
    position: NormalSums,
    /// Direction rows, unweighted by the direction weight.
    direction: NormalSums,
}

impl SplitSums {
    /// `JᵀJ` over all parameters with direction rows weighted by `w` (mm).
    pub fn normal_matrix(&self, w: f64) -> DMatrix<f64> {
        &self.position.h + (w * w) * &self.direction.h
    }

    /// The linearisation over `params` (each one of these sums' parameters) with direction rows
    /// weighted by `w` (mm); `None` when a parameter is missing.
    pub fn linearization(&self, params: &[ParamId], w: f64) -> Option<Linearization> {
        let cols = params
            .iter()
            .map(|p| self.params.iter().position(|q| q == p))
            .collect::<Option<Vec<usize>>>()?;
        let (p, d, w2) = (&self.position, &self.direction, w * w);
        let n = cols.len();
        Some((
            0.5 * (p.sum_sq + w2 * d.sum_sq),
            DVector::from_fn(n, |i, _| p.g[cols[i]] + w2 * d.g[cols[i]]),
            DMatrix::from_fn(n, n, |i, j| {
                p.h[(cols[i], cols[j])] + w2 * d.h[(cols[i], cols[j])]
            }),
        ))
    }
}

/// Jacobian rows gathered in blocks and folded into `JᵀJ` by one matrix product per block
/// (cache-friendly GEMM instead of a scalar loop per row); `Jᵀr` and `rᵀr` row by row.
struct Folder {
    /// Parameters (columns).
    k: usize,
    /// Entries per block (rows × k).
    cap: usize,
    /// The block, row after row; read as a column-major matrix it is `Jᵀ`.
    buf: Vec<f64>,
    sums: NormalSums,
}

impl Folder {
    fn new(k: usize, rows: usize) -> Folder {
        Folder {
            k,
            cap: rows * k,
            buf: Vec::with_capacity(rows * k),
            sums: NormalSums::zeros(k),
        }
    }

    /// Add rows: residuals `res` and their row-major Jacobian `jac` (`res.len() × k`).
    fn push(&mut self, jac: &[f64], res: &[f64]) {
        let k = self.k;
        for (i, r) in res.iter().enumerate() {
            let row = &jac[i * k..(i + 1) * k];
            self.sums.sum_sq += r * r;
            for (g, j) in self.sums.g.as_mut_slice().iter_mut().zip(row) {
                *g += j * r;
            }
            self.buf.extend_from_slice(row);
            if self.buf.len() == self.cap && k > 0 {
                self.flush();
            }
        }
    }

    fn flush(&mut self) {
        let jt = nalgebra::DMatrixView::from_slice(&self.buf, self.k, self.buf.len() / self.k);
        self.sums.h.gemm(1.0, &jt, &jt.transpose(), 1.0);
        self.buf.clear();
    }

    fn finish(mut self) -> NormalSums {
        if !self.buf.is_empty() {
            self.flush();
        }
        self.sums
    }
}

impl CalibProblem<'_> {
    /// Normal-equation sums over a chunk of poses under `cfg`: of all rows, or (`split`) of the
    /// position rows and of the direction rows apart.
    fn accumulate(
        &self,
        state: &RobotModel,
        chunk: &[Measured],
        cfg: &ObsConfig,
        split: bool,
    ) -> Vec<NormalSums> {
        let k = self.params.len();
        let rows = cfg.model.rows();
        let cut = if split { 3 } else { rows };
        let block = BLOCK_POSES.min(chunk.len()).max(1);
        let mut folders = vec![Folder::new(k, block * cut)];
        if cut < rows {
            folders.push(Folder::new(k, block * (rows - cut)));
        }
        let mut res = vec![0.0; rows];
        let mut jac = vec![0.0; rows * k];
        for p in chunk.iter().filter(|p| p.weight != 0.0) {
            residual_jacobian(state, p, cfg, self.params, &mut res, &mut jac);
            folders[0].push(&jac[..cut * k], &res[..cut]);
            if let Some(f) = folders.get_mut(1) {
                f.push(&jac[cut * k..], &res[cut..]);
            }
        }
        folders.into_iter().map(Folder::finish).collect()
    }

    /// The sums of the position rows and of the direction rows at `state`, apart (the direction
    /// weight of the configuration is not applied).
    pub fn linearize_split(&self, state: &RobotModel) -> SplitSums {
        let k = self.params.len();
        let unit = ObsConfig {
            direction_weight_mm: 1.0,
            ..*self.cfg
        };
        let parts = split_map(self.poses, |chunk| {
            self.accumulate(state, chunk, &unit, true)
        });
        let (mut pos, mut dir) = (Vec::new(), Vec::new());
        for mut part in parts {
            if part.len() > 1 {
                dir.push(part.remove(1));
            }
            pos.push(part.remove(0));
        }
        SplitSums {
            params: self.params.to_vec(),
            position: NormalSums::merge(pos, k),
            direction: NormalSums::merge(dir, k),
        }
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

    fn linearize(&self, state: &RobotModel) -> Linearization {
        let parts = split_map(self.poses, |chunk| {
            let mut sums = self.accumulate(state, chunk, self.cfg, false);
            sums.remove(0)
        });
        NormalSums::merge(parts, self.params.len()).linearization()
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
