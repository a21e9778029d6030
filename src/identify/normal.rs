//! Normal-equation sums `rᵀr`, `Jᵀr`, `JᵀJ`, accumulated block by block.
//!
//! Rows `[J r]` are gathered in blocks of up to [`BLOCK_POSES`] poses and folded into the sums
//! by matrix products, `[J r]ᵀ[J r]`, which holds `JᵀJ`, `Jᵀr` and `rᵀr` at once
//! (cache-friendly GEMM instead of a scalar loop per row; only its upper triangle, band by band,
//! mirrored at the end). The
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

/// Tile edge of the matrix product's kernels (8×8 with AVX-512, 8×4 with AVX2): rows padded
/// with zeros to a multiple of it keep every tile whole, which is cheaper than the partial
/// tiles of an odd width.
const GEMM_TILE: usize = 8;

/// Rows of the Gram matrix per product in a fold: only the upper triangle is formed, band by
/// band (a multiple of [`GEMM_TILE`]; narrower bands skip more of the lower triangle but pack
/// the right factor more often).
const GRAM_BAND: usize = 24;

/// Rows of `[J r]` over some of the problem's columns, gathered in blocks and folded into
/// normal-equation sums one block at a time: one matrix product per block gives
/// `[J r]ᵀ[J r]`, which holds `JᵀJ`, `Jᵀr` (last column) and `rᵀr` (corner) at once.
pub(crate) struct Folder {
    /// The problem's columns held here, in order.
    cols: Vec<usize>,
    /// Columns of the problem.
    k: usize,
    /// Rows per block.
    cap: usize,
    /// Rows in the block.
    rows: usize,
    /// Room for a block of rows `[J r 0]` (held columns, the residual, zeros), row after row;
    /// the first `rows` read as a column-major matrix are `[J r]ᵀ`. The zeros past the residual
    /// are never written, so the room is zeroed once, not per block.
    block: Vec<f64>,
    /// `[J r]ᵀ[J r]` summed over the folded blocks.
    gram: DMatrix<f64>,
}

impl Folder {
    /// A folder of the columns `cols` of a `k`-column problem, in blocks of `cap` rows.
    pub fn new(cols: Vec<usize>, k: usize, cap: usize) -> Folder {
        let stride = (cols.len() + 1).next_multiple_of(GEMM_TILE);
        Folder {
            cols,
            k,
            cap,
            rows: 0,
            block: vec![0.0; cap * stride],
            gram: DMatrix::zeros(stride, stride),
        }
    }

    /// Entries per row: the held columns, the residual, then zeros up to a multiple of
    /// [`GEMM_TILE`].
    pub fn stride(&self) -> usize {
        self.gram.nrows()
    }

    /// Room for `rows` (≤ the block size) more rows `[J r 0]`, each
    /// [`stride`](Self::stride) entries: the caller writes every row's Jacobian over the held
    /// columns and its residual at index `cols.len()` (they hold an earlier block's values);
    /// the entries after the residual are zero.
    pub fn rows(&mut self, rows: usize) -> &mut [f64] {
        if self.rows + rows > self.cap {
            self.flush();
        }
        let stride = self.stride();
        let start = self.rows * stride;
        self.rows += rows;
        &mut self.block[start..self.rows * stride]
    }

    /// Fold the block's rows into the upper triangle of the Gram matrix (`[J r]ᵀ[J r]` is
    /// symmetric: [`finish`](Self::finish) mirrors it), one product per band of
    /// [`GRAM_BAND`] rows, both factors read in place.
    fn flush(&mut self) {
        let s = self.stride();
        if self.rows > 0 {
            let filled = &self.block[..self.rows * s];
            // M = [J r]ᵀ (the block's rows are its columns) and Mᵀ, views of the same entries
            let m = DMatrixView::from_slice(filled, s, self.rows);
            let mt = DMatrixView::from_slice_with_strides(filled, self.rows, s, s, 1);
            for top in (0..s).step_by(GRAM_BAND) {
                let band = GRAM_BAND.min(s - top);
                self.gram.view_mut((top, top), (band, s - top)).gemm(
                    1.0,
                    &m.rows(top, band),
                    &mt.columns(top, s - top),
                    1.0,
                );
            }
        }
        self.rows = 0;
    }

    /// The sums over all the problem's columns (zero in columns not held).
    pub fn finish(mut self) -> NormalSums {
        self.flush();
        self.gram.fill_lower_triangle_with_upper_triangle();
        let w = self.cols.len();
        let g = &self.gram;
        let sums = NormalSums {
            sum_sq: g[(w, w)],
            g: g.view((0, w), (w, 1)).column(0).into_owned(),
            h: g.view((0, 0), (w, w)).into_owned(),
        };
        if w == self.k {
            sums
        } else {
            sums.embed(&self.cols, self.k)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folded_blocks_give_the_sums_of_the_rows() {
        let k = 5;
        let held = vec![0, 2, 3];
        // 23 rows in blocks of 8: two full blocks folded, the rest at the end
        let rows: Vec<([f64; 3], f64)> = (0..23)
            .map(|i| {
                let x = i as f64;
                ([x.sin(), 0.5 * x.cos(), 1.0 - 0.01 * x], 0.1 * x - 1.0)
            })
            .collect();
        let mut folder = Folder::new(held.clone(), k, 8);
        assert_eq!(folder.stride() % GEMM_TILE, 0);
        for (j, r) in &rows {
            let row = folder.rows(1);
            row[..3].copy_from_slice(j);
            row[3] = *r;
        }
        let sums = folder.finish();
        let mut want = NormalSums::zeros(k);
        for (j, r) in &rows {
            want.sum_sq += r * r;
            for (a, &ca) in held.iter().enumerate() {
                want.g[ca] += j[a] * r;
                for (b, &cb) in held.iter().enumerate() {
                    want.h[(ca, cb)] += j[a] * j[b];
                }
            }
        }
        assert!((sums.sum_sq - want.sum_sq).abs() <= 1e-12 * want.sum_sq);
        assert!((&sums.g - &want.g).norm() <= 1e-12 * want.g.norm());
        assert!((&sums.h - &want.h).norm() <= 1e-12 * want.h.norm());
        // columns not held stay zero
        assert_eq!(sums.g[1], 0.0);
        assert_eq!(sums.h.row(4).norm(), 0.0);
    }
}
