//! Automatic, deterministic selection of the identifiable parameter set.
//!
//! The stacked Jacobian over the actual poses is scaled as METHOD.md §2 fixes (direction rows
//! ×1000 mm, angle columns ÷1000 so every column is in mm per mm-at-one-metre), reduced to its
//! column-normalised Gram matrix (accumulated block by block, so 10 000 poses cost no big
//! matrix), and the columns are taken greedily in a fixed priority order by an incremental
//! Cholesky factorisation: a column is kept when the squared sine of its angle to the span of
//! the columns already kept exceeds `1e-10` (kept columns of the TX60 are above 1e-4, dependent
//! ones at round-off, ~1e-15). The priority order
//! is the four classic DH parameters per joint, with β replacing d at a joint whose next axis is
//! nominally parallel (Hayati), then the remaining β/d, then base and tool. The gap in the
//! spectrum is clean (kept ≥ 0.3, dropped ≤ 1e-14 for the TX60), so the result is structural.
//! Each dropped parameter carries its reason: no effect on the measurement, or the kept
//! parameters it is a combination of.

use nalgebra::DMatrix;

use super::normal::SplitSums;
use super::observation::{Measured, ObsConfig};
use super::params::ParamId;
use super::problem::CalibProblem;
use crate::model::{ParamKind, RobotModel};

/// Scale of direction rows and angle columns for the rank test (mm).
pub const RANK_SCALE_MM: f64 = 1000.0;
/// Squared sine of the angle to the kept span below which a column is dependent.
pub const DEPENDENCE_TOL: f64 = 1e-10;
/// Relative column norm below which a parameter has no effect.
pub const NO_EFFECT_TOL: f64 = 1e-9;

/// A parameter that cannot be identified, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Dropped {
    /// The parameter.
    pub param: ParamId,
    /// Human reason, e.g. "no effect on this measurement" or "dependent on d3".
    pub reason: String,
}

/// Result of the identifiability analysis.
#[derive(Debug, Clone, PartialEq)]
pub struct Identifiability {
    /// Identifiable parameters, in candidate order.
    pub identified: Vec<ParamId>,
    /// Dropped parameters with reasons, in candidate order.
    pub dropped: Vec<Dropped>,
    /// Gram matrix `JᵀJ` of the scaled Jacobian restricted to the identified set.
    pub gram: DMatrix<f64>,
}

impl Identifiability {
    /// Singular values of the scaled identified Jacobian (descending; computed on demand).
    pub fn singular_values(&self) -> Vec<f64> {
        if self.gram.is_empty() {
            return Vec::new();
        }
        let mut s: Vec<f64> = self
            .gram
            .clone()
            .symmetric_eigenvalues()
            .iter()
            .map(|e| e.max(0.0).sqrt())
            .collect();
        s.sort_by(|x, y| y.total_cmp(x));
        s
    }

    /// Condition number of the scaled identified Jacobian.
    pub fn condition_number(&self) -> f64 {
        let s = self.singular_values();
        match (s.first(), s.last()) {
            (Some(a), Some(b)) if *b > 0.0 => a / b,
            _ => f64::INFINITY,
        }
    }
}

/// The priority order in which candidates are tried (see the module doc).
pub fn priority_order(model: &RobotModel, candidates: &[ParamId]) -> Vec<ParamId> {
    let n = model.dof();
    let parallel_next = |i: usize| {
        i + 1 < n
            && model.joints[i].alpha.sin().abs() < 1e-9
            && model.joints[i].beta.sin().abs() < 1e-9
    };
    let mut order = Vec::new();
    let mdh = |joint, kind| ParamId::Mdh { joint, kind };
    for i in 0..n {
        let fourth = if parallel_next(i) {
            [
                ParamKind::Theta,
                ParamKind::A,
                ParamKind::Alpha,
                ParamKind::Beta,
            ]
        } else {
            [
                ParamKind::Theta,
                ParamKind::D,
                ParamKind::A,
                ParamKind::Alpha,
            ]
        };
        order.extend(fourth.map(|k| mdh(i, k)));
    }
    for i in 0..n {
        order.push(mdh(
            i,
            if parallel_next(i) {
                ParamKind::D
            } else {
                ParamKind::Beta
            },
        ));
    }
    let mut out: Vec<ParamId> = order
        .into_iter()
        .filter(|p| candidates.contains(p))
        .collect();
    out.extend(
        candidates
            .iter()
            .filter(|p| !matches!(p, ParamId::Mdh { .. }))
            .copied(),
    );
    out
}

/// Gram matrix `JᵀJ` (k×k) of the scaled stacked Jacobian (columns = `params`).
pub fn scaled_gram(
    model: &RobotModel,
    poses: &[Measured],
    cfg: &ObsConfig,
    params: &[ParamId],
) -> DMatrix<f64> {
    scale_gram(
        &CalibProblem::new(poses, cfg, params).linearize_split(model),
        params,
    )
}

/// [`scaled_gram`] from split sums over `params`: direction rows ×1000 mm, angle columns ÷1000.
fn scale_gram(sums: &SplitSums, params: &[ParamId]) -> DMatrix<f64> {
    let colscale: Vec<f64> = params
        .iter()
        .map(|p| {
            if p.is_angle() {
                1.0 / RANK_SCALE_MM
            } else {
                1.0
            }
        })
        .collect();
    // pose weights only scale rows: they change no rank (zero-weight poses are left out)
    let g = sums.normal_matrix(RANK_SCALE_MM);
    let k = params.len();
    DMatrix::from_fn(k, k, |a, b| g[(a, b)] * colscale[a] * colscale[b])
}

/// Analyse which of `candidates` the poses can identify.
pub fn analyze(
    model: &RobotModel,
    poses: &[Measured],
    cfg: &ObsConfig,
    candidates: &[ParamId],
) -> Identifiability {
    analyze_linearized(model, poses, cfg, candidates).0
}

/// [`analyze`], also returning the sums it computed at `model` over all candidates: the
/// solver's first linearisation is a restriction of them.
pub fn analyze_linearized(
    model: &RobotModel,
    poses: &[Measured],
    cfg: &ObsConfig,
    candidates: &[ParamId],
) -> (Identifiability, SplitSums) {
    let order = priority_order(model, candidates);
    let sums = CalibProblem::new(poses, cfg, &order).linearize_split(model);
    let g = scale_gram(&sums, &order);
    let n = order.len();
    let max_diag = (0..n).map(|c| g[(c, c)]).fold(0.0, f64::max);
    // column-normalised Gram matrix: entries are cosines between columns
    let norm: Vec<f64> = (0..n).map(|c| g[(c, c)].sqrt()).collect();
    let mut kept: Vec<usize> = Vec::new();
    let mut no_effect: Vec<usize> = Vec::new();
    let mut dependent: Vec<usize> = Vec::new();
    // incremental Cholesky factor of the kept block (rows of L)
    let mut l: Vec<Vec<f64>> = Vec::new();
    for c in 0..n {
        if g[(c, c)] <= (NO_EFFECT_TOL * NO_EFFECT_TOL) * max_diag || g[(c, c)] == 0.0 {
            no_effect.push(c);
            continue;
        }
        let v: Vec<f64> = kept
            .iter()
            .map(|&j| g[(j, c)] / (norm[j] * norm[c]))
            .collect();
        let mut y = vec![0.0; kept.len()];
        for i in 0..kept.len() {
            let s: f64 = (0..i).map(|j| l[i][j] * y[j]).sum();
            y[i] = (v[i] - s) / l[i][i];
        }
        let r2 = 1.0 - y.iter().map(|x| x * x).sum::<f64>();
        if r2 > DEPENDENCE_TOL {
            let mut row = y;
            row.push(r2.sqrt());
            l.push(row);
            kept.push(c);
        } else {
            dependent.push(c);
        }
    }
    let sub = |rows: &[usize], cols: &[usize]| {
        DMatrix::from_fn(rows.len(), cols.len(), |i, j| {
            g[(rows[i], cols[j])] / (norm[rows[i]] * norm[cols[j]])
        })
    };
    let gk = sub(&kept, &kept);
    let mut dropped: Vec<Dropped> = no_effect
        .iter()
        .map(|&c| Dropped {
            param: order[c],
            reason: "no effect on this measurement".to_owned(),
        })
        .collect();
    if let Some(chol) = gk.clone().cholesky() {
        for &c in &dependent {
            // normalised coefficients: the dropped column as a combination of kept columns
            let coef = chol.solve(&sub(&kept, &[c]));
            let mut parts: Vec<(f64, ParamId)> = kept
                .iter()
                .enumerate()
                .map(|(j, &kc)| (coef[j].abs(), order[kc]))
                .filter(|(w, _)| *w > 0.05)
                .collect();
            parts.sort_by(|x, y| y.0.total_cmp(&x.0));
            parts.truncate(4);
            let names: Vec<String> = parts.iter().map(|(_, p)| p.name()).collect();
            let reason = match names.len() {
                0 => "dependent on the identified parameters".to_owned(),
                1 => format!("dependent on {}", names[0]),
                _ => format!("combination of {}", names.join(", ")),
            };
            dropped.push(Dropped {
                param: order[c],
                reason,
            });
        }
    }
    let identified: Vec<ParamId> = candidates
        .iter()
        .filter(|p| kept.iter().any(|&c| order[c] == **p))
        .copied()
        .collect();
    dropped.sort_by_key(|d| candidates.iter().position(|p| *p == d.param));
    // singular values of the scaled (not normalised) identified Jacobian
    let gs = DMatrix::from_fn(kept.len(), kept.len(), |i, j| g[(kept[i], kept[j])]);
    let result = Identifiability {
        identified,
        dropped,
        gram: gs,
    };
    (result, sums)
}
