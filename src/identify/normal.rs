//! Normal-equation sums `rᵀr`, `Jᵀr`, `JᵀJ`, accumulated block by block.
//!
//! Jacobian rows are gathered in blocks of up to [`BLOCK_POSES`] poses and folded into `JᵀJ` by
//! one matrix product per block (cache-friendly GEMM instead of a scalar loop per row). The
//! position rows and the direction rows of a pose go to separate blocks: the direction block
//! holds only the columns of parameters that turn directions (translations give zero direction
//! rows), and the split lets one set of sums serve any direction weight ([`SplitSums`]).

use nalgebra::{DMatrix, DMatrixView, DVector};

use super::params::ParamId;
use super::solver::Linearization;

/// Poses per block of Jacobian rows folded into `JᵀJ` at once.
pub const BLOCK_POSES: usize = 64;

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
    /// Empty sums over `k` columns.
    pub fn zeros(k: usize) -> NormalSums {
        NormalSums {
            sum_sq: 0.0,
            g: DVector::zeros(k),
            h: DMatrix::zeros(k, k),
        }
    }

    /// Sums of parts, added in order (zeros over `k` columns when there are none).
    pub fn merge(parts: impl IntoIterator<Item = NormalSums>, k: usize) -> NormalSums {
        let mut it = parts.into_iter();
        let mut sums = it.next().unwrap_or_else(|| NormalSums::zeros(k));
        for p in it {
            sums.sum_sq += p.sum_sq;
            sums.g += p.g;
            sums.h += p.h;
        }
        sums
    }

    /// These sums as columns `cols[i]` of sums over `k` columns (zero elsewhere).
    fn embed(self, cols: &[usize], k: usize) -> NormalSums {
        let mut out = NormalSums::zeros(k);
        out.sum_sq = self.sum_sq;
        for (i, &a) in cols.iter().enumerate() {
            out.g[a] = self.g[i];
            for (j, &b) in cols.iter().enumerate() {
                out.h[(a, b)] = self.h[(i, j)];
            }
        }
        out
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
    pub params: Vec<ParamId>,
    /// Position rows.
    pub position: NormalSums,
    /// Direction rows, unweighted by the direction weight.
    pub direction: NormalSums,
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

/// Rows of `[J r]` over some of the problem's columns, gathered in blocks and folded into
/// normal-equation sums one block at a time.
pub(crate) struct Folder {
    /// The problem's columns held here, in order.
    cols: Vec<usize>,
    /// Columns of the problem.
    k: usize,
    /// Rows per block.
    cap: usize,
    /// The block's Jacobian, row after row; read as a column-major matrix it is `Jᵀ`.
    jac: Vec<f64>,
    /// The block's residuals.
    res: Vec<f64>,
    /// Sums over the held columns.
    sums: NormalSums,
}

impl Folder {
    /// A folder of the columns `cols` of a `k`-column problem, in blocks of `cap` rows.
    pub fn new(cols: Vec<usize>, k: usize, cap: usize) -> Folder {
        let width = cols.len();
        Folder {
            cols,
            k,
            cap,
            jac: Vec::with_capacity(cap * width),
            res: Vec::with_capacity(cap),
            sums: NormalSums::zeros(width),
        }
    }

    /// Room for `rows` (≤ the block size) more rows, zeroed: their Jacobian (row-major over the
    /// held columns) and their residuals.
    pub fn rows(&mut self, rows: usize) -> (&mut [f64], &mut [f64]) {
        if self.res.len() + rows > self.cap {
            self.flush();
        }
        let (j0, r0) = (self.jac.len(), self.res.len());
        self.jac.resize(j0 + rows * self.cols.len(), 0.0);
        self.res.resize(r0 + rows, 0.0);
        (&mut self.jac[j0..], &mut self.res[r0..])
    }

    fn flush(&mut self) {
        let width = self.cols.len();
        let n = self.res.len();
        let s = &mut self.sums;
        s.sum_sq += self.res.iter().map(|r| r * r).sum::<f64>();
        if width > 0 && n > 0 {
            let g = s.g.as_mut_slice();
            for (row, r) in self.jac.chunks_exact(width).zip(&self.res) {
                g.iter_mut().zip(row).for_each(|(g, j)| *g += j * r);
            }
            let jt = DMatrixView::from_slice(&self.jac, width, n);
            s.h.gemm(1.0, &jt, &jt.transpose(), 1.0);
        }
        self.jac.clear();
        self.res.clear();
    }

    /// The sums over all the problem's columns (zero in columns not held).
    pub fn finish(mut self) -> NormalSums {
        self.flush();
        if self.cols.len() == self.k {
            self.sums
        } else {
            self.sums.embed(&self.cols, self.k)
        }
    }
}
