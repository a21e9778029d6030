//! Automatic, deterministic selection of the identified parameter set: structural, then
//! practical.
//!
//! **Structural.** The stacked Jacobian over the actual poses is scaled as docs/method.md §2 fixes
//! (direction rows ×1000 mm, angle columns ÷1000 so every column is in mm per mm-at-one-metre),
//! reduced to its column-normalised Gram matrix (accumulated block by block, so 10 000 poses cost
//! no big matrix), and the columns are taken greedily in a fixed priority order by an
//! incremental Cholesky factorisation: a column is kept when the squared sine of its angle to
//! the span of the columns already kept exceeds `1e-10` (kept columns of the TX60 are above
//! 1e-4, dependent ones at round-off, ~1e-15). The priority order is **frame first**: the base
//! and tool parameters being identified, then the four classic DH parameters per joint, with β
//! replacing d at a joint whose next axis is nominally parallel (Hayati), then the remaining
//! β/d. Where a frame parameter and a robot parameter are indistinguishable (base_tz and d1,
//! base_rz and θ1, tool_x and a6, tool_z and d6), the frame takes the offset and the robot
//! parameter stays at nominal: the robot's geometry is known to tenths of a millimetre, the
//! tracker and tool frames are not known at all. The gap in the spectrum is clean (kept
//! ≥ 0.3, dropped ≤ 1e-14 for the TX60), so this result is structural: no effect on the
//! measurement, or an exact combination of kept parameters.
//!
//! **Practical.** A formally identifiable parameter can still be undetermined by the data (the
//! README's campaign: a stage axis measured 4 mrad off +y makes β6 formally identifiable, and
//! β6, a6, d6 then cancel inside the sampled box). With [`PracticalBounds`], the same greedy
//! pass also predicts each candidate's standard deviation with the set kept so far,
//! `σ_noise·√diag((JᵀJ)⁻¹)` of the weighted Jacobian the solver uses (direction rows × the
//! direction weight, pose weights applied; `σ_noise` = the a-priori σ of a unit-weight row). A
//! candidate over its bound (lengths in mm, angles in rad) is held at nominal with that figure:
//! *poorly determined* when the data barely moves it at all (`σ_noise/‖column‖` alone is over
//! the bound), *dependent* ("indistinguishable from a6 given these poses") when the
//! near-cancellation with kept parameters inflates it. A later column can also push an earlier
//! kept one over its bound (a well-excited parameter that shares a weak one's direction): the
//! kept parameter furthest over is then held back as dependent and the pass runs again without
//! it, until every kept σ is within its bound — holding back the weak one, not the strong one,
//! keeps the bias small. Frame first holds here too: a robot parameter that would push a kept
//! frame parameter over its bound is held back when it comes, so the frames keep their offsets. A later parameter may take a held-back one's place when the data
//! determines it (α6 for θ6 on the UR5 grid). The structural verdict comes from a pass without
//! the practical test, so a hold-back never hides a structural loss, nor looks like one. The
//! diagonal of `(JᵀJ)⁻¹` is carried along the incremental Cholesky factor (rank-one Schur
//! updates), so a pass costs O(k²) per candidate.
//!
//! Each dropped parameter carries its kind ([`DropKind`]), reason and figure.

use nalgebra::DMatrix;

use super::normal::SplitSums;
use super::observation::{Measured, ObsConfig};
use super::params::ParamId;
use super::problem::{CalibProblem, JointTrig};
use crate::model::{ParamKind, RobotModel};

/// Scale of direction rows and angle columns for the rank test (mm).
pub const RANK_SCALE_MM: f64 = 1000.0;
/// Squared sine of the angle to the kept span below which a column is dependent.
pub const DEPENDENCE_TOL: f64 = 1e-10;
/// Relative column norm below which a parameter has no effect.
pub const NO_EFFECT_TOL: f64 = 1e-9;
/// Default a-priori σ of a unit-weight residual row (mm): an AT960 coordinate at ~2.5 m range,
/// (15 µm + 6 µm/m · 2.5 m)/2.
pub const DEFAULT_NOISE_MM: f64 = 0.015;
/// Default largest predicted σ of an identified length (mm).
pub const DEFAULT_MAX_SIGMA_MM: f64 = 0.05;
/// Default largest predicted σ of an identified angle (rad): 0.5 mrad, 0.05 mm at 100 mm.
pub const DEFAULT_MAX_SIGMA_RAD: f64 = 5e-4;
/// The gravity torque (N·m) a compliance is judged at: its column is scaled as the angle it
/// turns the joint by at this torque, and its σ bound is the angle bound over it (0.5 mrad at
/// 50 N·m: 10 µrad/(N·m)). Joints 2–3 of a 5–10 kg-payload arm carry 30–150 N·m.
pub const REFERENCE_TORQUE_NM: f64 = 50.0;

/// The practical test: how noisy one residual row is a priori, and how large a predicted
/// parameter σ may be for the parameter still to be identified.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PracticalBounds {
    /// A-priori σ of one unit-weight residual row (mm): a tracker coordinate, or a direction row
    /// times its weight. 0 keeps every structurally identifiable parameter.
    pub noise_mm: f64,
    /// Largest predicted σ of an identified length (mm).
    pub max_sigma_mm: f64,
    /// Largest predicted σ of an identified angle (rad).
    pub max_sigma_rad: f64,
}

impl Default for PracticalBounds {
    /// [`DEFAULT_NOISE_MM`], [`DEFAULT_MAX_SIGMA_MM`], [`DEFAULT_MAX_SIGMA_RAD`].
    fn default() -> Self {
        PracticalBounds {
            noise_mm: DEFAULT_NOISE_MM,
            max_sigma_mm: DEFAULT_MAX_SIGMA_MM,
            max_sigma_rad: DEFAULT_MAX_SIGMA_RAD,
        }
    }
}

impl PracticalBounds {
    /// The bound of one parameter, in its unit (mm, rad, or rad/(N·m) for a compliance: the
    /// angle bound at [`REFERENCE_TORQUE_NM`]).
    pub fn bound(&self, p: &ParamId) -> f64 {
        if is_compliance(p) {
            self.max_sigma_rad / REFERENCE_TORQUE_NM
        } else if p.is_angle() {
            self.max_sigma_rad
        } else {
            self.max_sigma_mm
        }
    }

    /// `Err` naming the first value that is not usable: the noise must be finite and ≥ 0, the
    /// bounds finite and > 0.
    pub fn check(&self) -> Result<(), String> {
        if !(self.noise_mm.is_finite() && self.noise_mm >= 0.0) {
            return Err(format!(
                "noise {} mm: must be a finite number ≥ 0",
                self.noise_mm
            ));
        }
        for (name, v) in [
            ("max sigma (mm)", self.max_sigma_mm),
            ("max sigma (rad)", self.max_sigma_rad),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} {v}: must be a finite number > 0"));
            }
        }
        Ok(())
    }
}

/// Why a parameter is not identified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropKind {
    /// No effect on the measurement, or an exact combination of identified parameters on these
    /// poses (without the practical test, the only kind).
    Structural,
    /// Identifiable alone, but indistinguishable from parameters already identified given
    /// these poses: together their predicted σ would exceed a bound.
    Dependent,
    /// The poses barely move it: its predicted σ exceeds its bound even on its own.
    PoorlyDetermined,
    /// A non-geometric term these poses determine but whose estimate is within
    /// [`super::TERM_SIGNIFICANCE_SIGMAS`] σ of zero: held there.
    NotSignificant,
}

impl DropKind {
    /// Contract name: `structural`, `dependent`, `poorly_determined`, `not_significant`.
    pub fn name(self) -> &'static str {
        match self {
            DropKind::Structural => "structural",
            DropKind::Dependent => "dependent",
            DropKind::PoorlyDetermined => "poorly_determined",
            DropKind::NotSignificant => "not_significant",
        }
    }
}

/// A parameter that is not identified (held at nominal), and why.
#[derive(Debug, Clone, PartialEq)]
pub struct Dropped {
    /// The parameter.
    pub param: ParamId,
    /// Human reason, e.g. "no effect on this measurement", "dependent on d3" or
    /// "indistinguishable from a6 given these poses: predicted σ 52.1 mrad (bound 0.5 mrad)".
    pub reason: String,
    /// Structural, or held back by the practical test.
    pub kind: DropKind,
    /// Its predicted σ had it been identified with the parameters kept before it (mm or rad);
    /// `None` when unbounded (structural, or exactly dependent).
    pub predicted_sigma: Option<f64>,
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
    /// Predicted σ of each identified parameter (order of `identified`; mm or rad) at the a-priori
    /// noise; empty when the analysis ran without [`PracticalBounds`].
    pub predicted_sigma: Vec<f64>,
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

    /// Whether `p` was dropped structurally on these poses (not merely held back in practice).
    pub fn structurally_dropped(&self, p: &ParamId) -> bool {
        self.dropped
            .iter()
            .any(|d| d.param == *p && d.kind == DropKind::Structural)
    }
}

/// Whether `p` places a frame around the robot (base, tool, stage axis) rather than the
/// robot's own geometry: frames go first in the priority order, so a frame parameter takes an
/// offset it cannot be told apart from and the robot parameter stays at nominal.
pub fn is_frame(p: &ParamId) -> bool {
    matches!(
        p,
        ParamId::BaseTranslation(_)
            | ParamId::BaseRotation(_)
            | ParamId::Tool(_)
            | ParamId::StageAxis(_)
    )
}

/// Whether `p` is a joint compliance (rad/(N·m)).
pub fn is_compliance(p: &ParamId) -> bool {
    matches!(
        p,
        ParamId::Term {
            kind: crate::model::TermKind::Compliance,
            ..
        }
    )
}

/// The class of a parameter in the priority order: frames (0) before the robot's geometry (1)
/// before the non-geometric terms (2). A parameter that would push a kept one of an earlier
/// class over its bound is held back when it comes, so the earlier class keeps the offset.
fn priority_class(p: &ParamId) -> u8 {
    if is_frame(p) {
        0
    } else if p.is_term() {
        2
    } else {
        1
    }
}

/// The priority order in which candidates are tried (see the module doc): the frame
/// parameters (base, tool) first, in candidate order, then the robot's MDH parameters.
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
    let mut out: Vec<ParamId> = candidates.iter().filter(|p| is_frame(p)).copied().collect();
    out.extend(order.into_iter().filter(|p| candidates.contains(p)));
    // the non-geometric terms last: they take only what the geometry cannot explain
    out.extend(candidates.iter().filter(|p| p.is_term()).copied());
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
            if is_compliance(p) {
                1.0 / (RANK_SCALE_MM * REFERENCE_TORQUE_NM)
            } else if p.is_angle() {
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

/// A Gram matrix read through its column norms: `cos(a, b)` is the cosine between columns.
struct NormalisedGram {
    /// `JᵀJ`.
    g: DMatrix<f64>,
    /// Column norms `√(JᵀJ)ᵢᵢ`.
    norm: Vec<f64>,
}

impl NormalisedGram {
    fn new(g: DMatrix<f64>) -> NormalisedGram {
        let norm = (0..g.ncols()).map(|c| g[(c, c)].max(0.0).sqrt()).collect();
        NormalisedGram { g, norm }
    }

    fn cos(&self, a: usize, b: usize) -> f64 {
        self.g[(a, b)] / (self.norm[a] * self.norm[b])
    }
}

/// A candidate column seen from the kept span of a [`KeptFactor`].
struct Projection {
    /// `L⁻¹v`, `v` = cosines of the candidate to the kept columns.
    y: Vec<f64>,
    /// Squared sine of the angle to the span: `1 − ‖y‖²`.
    sin2: f64,
    /// Normalised coefficients `L⁻ᵀy` of the candidate on the kept columns.
    coef: Vec<f64>,
}

/// Incremental Cholesky factor `L` of the normalised Gram block of the kept columns, with the
/// diagonal of its inverse.
#[derive(Default)]
struct KeptFactor {
    /// Kept columns, in the order taken.
    cols: Vec<usize>,
    /// Rows of `L`.
    l: Vec<Vec<f64>>,
    /// `diag(C⁻¹)` of the normalised block `C`, per kept column.
    inv_diag: Vec<f64>,
}

impl KeptFactor {
    fn project(&self, gram: &NormalisedGram, c: usize) -> Projection {
        let k = self.cols.len();
        let v: Vec<f64> = self.cols.iter().map(|&j| gram.cos(j, c)).collect();
        let mut y = vec![0.0; k];
        for i in 0..k {
            let s: f64 = (0..i).map(|j| self.l[i][j] * y[j]).sum();
            y[i] = (v[i] - s) / self.l[i][i];
        }
        let mut coef = vec![0.0; k];
        for i in (0..k).rev() {
            let s: f64 = (i + 1..k).map(|j| self.l[j][i] * coef[j]).sum();
            coef[i] = (y[i] - s) / self.l[i][i];
        }
        let sin2 = 1.0 - y.iter().map(|x| x * x).sum::<f64>();
        Projection { y, sin2, coef }
    }

    /// `diag(C⁻¹)` with the projected candidate added (last entry: the candidate's).
    fn inv_diag_with(&self, p: &Projection) -> Vec<f64> {
        let s = p.sin2.max(0.0);
        let mut d: Vec<f64> = self
            .inv_diag
            .iter()
            .zip(&p.coef)
            .map(|(d, b)| d + b * b / s)
            .collect();
        d.push(1.0 / s);
        d
    }

    fn push(&mut self, c: usize, p: Projection) {
        self.inv_diag = self.inv_diag_with(&p);
        let mut row = p.y;
        row.push(p.sin2.sqrt());
        self.l.push(row);
        self.cols.push(c);
    }
}

/// The practical test's state: the weighted Gram matrix the solver uses, its kept factor, the
/// bounds, and the parameters held back after the fact (column → why).
struct Practical<'a> {
    bounds: &'a PracticalBounds,
    gram: NormalisedGram,
    kept: KeptFactor,
    excluded: Vec<(usize, HeldBack)>,
}

/// A candidate the practical test holds back.
#[derive(Clone)]
struct HeldBack {
    kind: DropKind,
    sigma: f64,
    reason: String,
}

/// `v` in the unit of `p` with about three significant digits (angles in mrad, compliances
/// in µrad/(N·m)).
fn figure(p: &ParamId, v: f64) -> String {
    let (v, unit) = if is_compliance(p) {
        (v * 1e6, "µrad/(N·m)")
    } else if p.is_angle() {
        (v * 1e3, "mrad")
    } else {
        (v, "mm")
    };
    if !v.is_finite() {
        return format!("unbounded {unit}");
    }
    let digits = if v > 0.0 {
        (2 - v.log10().floor() as i32).clamp(0, 6) as usize
    } else {
        3
    };
    format!("{v:.digits$} {unit}")
}

/// Names of the kept parameters a column is (nearly) a combination of, by normalised
/// coefficient (largest first; at most four, each over 0.05).
fn partners(coef: &[f64], kept: &[usize], order: &[ParamId]) -> Vec<String> {
    let mut parts: Vec<(f64, ParamId)> = coef
        .iter()
        .zip(kept)
        .map(|(w, &kc)| (w.abs(), order[kc]))
        .filter(|(w, _)| *w > 0.05)
        .collect();
    parts.sort_by(|x, y| y.0.total_cmp(&x.0));
    parts.truncate(4);
    parts.iter().map(|(_, p)| p.name()).collect()
}

/// "predicted σ 3.10 mm (bound 0.0500 mm)".
fn sigma_text(bounds: &PracticalBounds, p: &ParamId, sigma: f64) -> String {
    format!(
        "predicted σ {} (bound {})",
        figure(p, sigma),
        figure(p, bounds.bound(p))
    )
}

/// `p` held back as indistinguishable from the `kept` columns on which its normalised
/// coefficients are `coef`.
fn held_dependent(
    bounds: &PracticalBounds,
    p: &ParamId,
    sigma: f64,
    (coef, kept): (&[f64], &[usize]),
    order: &[ParamId],
) -> HeldBack {
    let names = partners(coef, kept, order);
    let names = if names.is_empty() {
        "the identified parameters".to_owned()
    } else {
        names.join(", ")
    };
    HeldBack {
        kind: DropKind::Dependent,
        sigma,
        reason: format!(
            "indistinguishable from {names} given these poses: {}",
            sigma_text(bounds, p, sigma)
        ),
    }
}

impl<'a> Practical<'a> {
    fn new(bounds: &'a PracticalBounds, gram: NormalisedGram) -> Practical<'a> {
        Practical {
            bounds,
            gram,
            kept: KeptFactor::default(),
            excluded: Vec::new(),
        }
    }

    /// Predicted σ (unit of the parameter) of column `c` from `diag(C⁻¹)` entry `inv_diag`.
    fn sigma(&self, c: usize, inv_diag: f64) -> f64 {
        self.bounds.noise_mm * inv_diag.sqrt() / self.gram.norm[c]
    }

    /// `None` when candidate `c` may join the kept set (its predicted σ with the kept columns
    /// is within its bound), else why it is held back.
    fn judge(&self, c: usize, order: &[ParamId]) -> Option<HeldBack> {
        if let Some((_, h)) = self.excluded.iter().find(|(x, _)| *x == c) {
            return Some(h.clone());
        }
        let param = &order[c];
        let bound = self.bounds.bound(param);
        let p = self.kept.project(&self.gram, c);
        let sigma = self.sigma(c, 1.0 / p.sin2.max(0.0));
        if self.gram.norm[c] == 0.0 || self.bounds.noise_mm / self.gram.norm[c] > bound {
            return Some(HeldBack {
                kind: DropKind::PoorlyDetermined,
                sigma,
                reason: format!(
                    "poorly determined by these poses: {}",
                    sigma_text(self.bounds, param, sigma)
                ),
            });
        }
        if sigma > bound || !sigma.is_finite() {
            return Some(held_dependent(
                self.bounds,
                param,
                sigma,
                (&p.coef, &self.kept.cols),
                order,
            ));
        }
        let class = priority_class(param);
        if class == 0 {
            return None;
        }
        // frame first, geometry before terms: a parameter that would blur a kept one of an
        // earlier class beyond its bound is the one held back, the earlier keeps the offset
        let with = self.kept.inv_diag_with(&p);
        let (frame, frame_sigma) = self
            .kept
            .cols
            .iter()
            .zip(&with)
            .filter(|(&k, _)| priority_class(&order[k]) < class)
            .map(|(&k, &d)| (k, self.sigma(k, d)))
            .map(|(k, s)| (k, s, s / self.bounds.bound(&order[k])))
            .filter(|(_, _, ratio)| *ratio > 1.0)
            .max_by(|a, b| a.2.total_cmp(&b.2))
            .map(|(k, s, _)| (k, s))?;
        let names = partners(&p.coef, &self.kept.cols, order);
        let names = if names.is_empty() {
            order[frame].name()
        } else {
            names.join(", ")
        };
        Some(HeldBack {
            kind: DropKind::Dependent,
            sigma,
            reason: format!(
                "indistinguishable from {names} given these poses: identifying it would raise \
                 {}'s predicted σ to {} (bound {}); the {} takes the offset",
                order[frame].name(),
                figure(&order[frame], frame_sigma),
                figure(&order[frame], self.bounds.bound(&order[frame])),
                if is_frame(&order[frame]) {
                    "frame"
                } else {
                    "geometry"
                }
            ),
        })
    }

    fn keep(&mut self, c: usize) {
        let p = self.kept.project(&self.gram, c);
        self.kept.push(c, p);
    }

    /// Predicted σ of every kept column, by column.
    fn sigmas(&self) -> Vec<(usize, f64)> {
        self.kept
            .cols
            .iter()
            .zip(&self.kept.inv_diag)
            .map(|(&c, &d)| (c, self.sigma(c, d)))
            .collect()
    }

    /// The kept column furthest over its bound (a later column made it so), held back now as
    /// indistinguishable from the others; `false` when every kept σ is within its bound.
    fn exclude_worst(&mut self, order: &[ParamId]) -> bool {
        let worst = self
            .sigmas()
            .into_iter()
            .map(|(c, s)| (c, s, s / self.bounds.bound(&order[c])))
            .filter(|(_, _, ratio)| *ratio > 1.0)
            .max_by(|a, b| a.2.total_cmp(&b.2));
        let Some((j, sigma, _)) = worst else {
            return false;
        };
        // the others, refactored without it, to name what it cannot be told apart from
        let mut others = KeptFactor::default();
        for &c in self.kept.cols.iter().filter(|&&c| c != j) {
            let p = others.project(&self.gram, c);
            others.push(c, p);
        }
        let coef = others.project(&self.gram, j).coef;
        let held = held_dependent(self.bounds, &order[j], sigma, (&coef, &others.cols), order);
        self.excluded.push((j, held));
        self.kept = KeptFactor::default();
        true
    }
}

/// The decision on one candidate column.
enum Decision {
    Keep,
    NoEffect,
    /// An exact combination of the kept columns.
    RankDependent,
    Held(HeldBack),
}

/// The greedy pass over `order`: the rank test on `rank`, then the practical test if any
/// (whose kept factor it fills). Returns one decision per column and the kept factor.
fn greedy(
    order: &[ParamId],
    rank: &NormalisedGram,
    mut practical: Option<&mut Practical>,
) -> (Vec<Decision>, KeptFactor) {
    let n = order.len();
    let max_diag = (0..n).map(|c| rank.g[(c, c)]).fold(0.0, f64::max);
    let mut kept = KeptFactor::default();
    let mut decisions = Vec::with_capacity(n);
    for c in 0..n {
        let gcc = rank.g[(c, c)];
        if gcc <= (NO_EFFECT_TOL * NO_EFFECT_TOL) * max_diag || gcc == 0.0 {
            decisions.push(Decision::NoEffect);
            continue;
        }
        let p = kept.project(rank, c);
        if p.sin2 <= DEPENDENCE_TOL {
            decisions.push(Decision::RankDependent);
            continue;
        }
        if let Some(held) = practical.as_deref().and_then(|pr| pr.judge(c, order)) {
            decisions.push(Decision::Held(held));
            continue;
        }
        kept.push(c, p);
        if let Some(pr) = practical.as_deref_mut() {
            pr.keep(c);
        }
        decisions.push(Decision::Keep);
    }
    (decisions, kept)
}

/// [`greedy`] with the practical test, repeated while a kept parameter ends over its bound
/// (adding a column never lowers another's σ, so a later one can push an earlier one over):
/// that parameter is held back and the pass runs again without it, so that every identified
/// parameter's predicted σ is within its bound.
fn greedy_practical<'a>(
    order: &[ParamId],
    rank: &NormalisedGram,
    mut practical: Practical<'a>,
) -> (Vec<Decision>, KeptFactor, Practical<'a>) {
    loop {
        let (decisions, kept) = greedy(order, rank, Some(&mut practical));
        if !practical.exclude_worst(order) {
            return (decisions, kept, practical);
        }
    }
}

/// Reason for a column that is an exact combination of the `kept` columns of `rank`.
fn dependence_reason(rank: &NormalisedGram, kept: &[usize], c: usize, order: &[ParamId]) -> String {
    let sub = |rows: &[usize], cols: &[usize]| {
        DMatrix::from_fn(rows.len(), cols.len(), |i, j| rank.cos(rows[i], cols[j]))
    };
    let Some(chol) = sub(kept, kept).cholesky() else {
        return "dependent on the identified parameters".to_owned();
    };
    // normalised coefficients: the dropped column as a combination of kept columns
    let coef = chol.solve(&sub(kept, &[c]));
    let names = partners(coef.as_slice(), kept, order);
    match names.len() {
        0 => "dependent on the identified parameters".to_owned(),
        1 => format!("dependent on {}", names[0]),
        _ => format!("combination of {}", names.join(", ")),
    }
}

/// The identified set of `candidates` (tried in `order`) from the rank-scaled Gram matrix
/// over `order` and, for the practical test, the bounds with the weighted Gram matrix the
/// solver uses (same columns).
fn select(
    order: &[ParamId],
    candidates: &[ParamId],
    rank_gram: DMatrix<f64>,
    weighted: Option<(&PracticalBounds, DMatrix<f64>)>,
) -> Identifiability {
    let rank = NormalisedGram::new(rank_gram);
    // the structural verdict on these poses, apart: a practical hold-back may let a later
    // parameter in (α6 for a held-back θ6 on the UR5 grid), which must not hide a structural loss
    let (structural, structural_kept) = greedy(order, &rank, None);
    let practical = weighted.map(|(bounds, g)| {
        greedy_practical(order, &rank, Practical::new(bounds, NormalisedGram::new(g)))
    });
    let (decisions, kept, practical) = match practical {
        None => (
            (0..order.len()).map(|_| None).collect(),
            structural_kept.cols.clone(),
            None,
        ),
        Some((d, k, p)) => (d.into_iter().map(Some).collect::<Vec<_>>(), k.cols, Some(p)),
    };
    let mut dropped: Vec<Dropped> = Vec::new();
    for (c, (first, second)) in structural.into_iter().zip(decisions).enumerate() {
        if kept.contains(&c) {
            continue;
        }
        let (kind, reason, predicted_sigma) = match (first, second) {
            (Decision::NoEffect, _) => (
                DropKind::Structural,
                "no effect on this measurement".to_owned(),
                None,
            ),
            (Decision::RankDependent, _) => (
                DropKind::Structural,
                dependence_reason(&rank, &structural_kept.cols, c, order),
                None,
            ),
            (_, Some(Decision::Held(h))) => {
                (h.kind, h.reason, Some(h.sigma).filter(|s| s.is_finite()))
            }
            // an exact combination of what the practical pass kept in its place
            _ => (
                DropKind::Dependent,
                dependence_reason(&rank, &kept, c, order),
                None,
            ),
        };
        dropped.push(Dropped {
            param: order[c],
            reason,
            kind,
            predicted_sigma,
        });
    }
    dropped.sort_by_key(|d| candidates.iter().position(|p| *p == d.param));
    let identified: Vec<ParamId> = candidates
        .iter()
        .filter(|p| kept.iter().any(|&c| order[c] == **p))
        .copied()
        .collect();
    let predicted_sigma = practical.map_or_else(Vec::new, |pr| {
        let s = pr.sigmas();
        identified
            .iter()
            .filter_map(|p| s.iter().find(|(c, _)| order[*c] == *p).map(|(_, v)| *v))
            .collect()
    });
    // the scaled (not normalised) identified Gram matrix, in candidate order
    let cols: Vec<usize> = identified
        .iter()
        .filter_map(|p| order.iter().position(|q| q == p))
        .collect();
    let gram = DMatrix::from_fn(cols.len(), cols.len(), |i, j| rank.g[(cols[i], cols[j])]);
    Identifiability {
        identified,
        dropped,
        gram,
        predicted_sigma,
    }
}

/// Analyse which of `candidates` the poses can identify structurally (no practical test).
pub fn analyze(
    model: &RobotModel,
    poses: &[Measured],
    cfg: &ObsConfig,
    candidates: &[ParamId],
) -> Identifiability {
    analyze_linearized(model, poses, &JointTrig::of(poses), cfg, candidates, None).0
}

/// [`analyze`], with the practical test when `practical` is given, also returning the sums it
/// computed at `model` over all candidates: the solver's first linearisation is a restriction
/// of them. `trig` is [`JointTrig::of`] the poses.
pub fn analyze_linearized(
    model: &RobotModel,
    poses: &[Measured],
    trig: &JointTrig,
    cfg: &ObsConfig,
    candidates: &[ParamId],
    practical: Option<&PracticalBounds>,
) -> (Identifiability, SplitSums) {
    let order = priority_order(model, candidates);
    let sums = CalibProblem::with_trig(poses, trig, cfg, &order).linearize_split(model);
    let weighted = practical.map(|b| (b, sums.normal_matrix(cfg.direction_weight_mm)));
    let result = select(&order, candidates, scale_gram(&sums, &order), weighted);
    (result, sums)
}

/// The identified robot parameters that are relative to the setup: those the setup's held
/// quantities `fixed` (the measured tool, the stage axis, a registered base) would take over if
/// they were free. The analysis runs again on `[fixed, identified]` with the fixed quantities
/// first (frame first); an identified MDH parameter it drops — an exact combination
/// (`structural`) or, with `practical`, indistinguishable within its σ bound (`dependent`,
/// `poorly_determined`) — is returned with that kind, figure (its predicted σ were the setup
/// free; `None` when unbounded) and reason. Its identified value and σ hold given the setup:
/// an error in the setup moves it.
pub fn setup_relative(
    model: &RobotModel,
    poses: &[Measured],
    trig: &JointTrig,
    cfg: &ObsConfig,
    identified: &[ParamId],
    fixed: &[ParamId],
    practical: Option<&PracticalBounds>,
) -> Vec<Dropped> {
    if fixed.is_empty() {
        return Vec::new();
    }
    let candidates: Vec<ParamId> = fixed.iter().chain(identified).copied().collect();
    let (free, _) = analyze_linearized(model, poses, trig, cfg, &candidates, practical);
    free.dropped
        .into_iter()
        .filter(|d| !is_frame(&d.param) && identified.contains(&d.param))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two fixed orthonormal directions in R^100 (deterministic "poses").
    fn basis() -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let n = 100;
        let raw = |f: &dyn Fn(f64) -> f64| -> Vec<f64> { (0..n).map(|i| f(i as f64)).collect() };
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let unit = |a: Vec<f64>| {
            let l = dot(&a, &a).sqrt();
            a.into_iter().map(|x| x / l).collect::<Vec<f64>>()
        };
        let reject = |a: Vec<f64>, b: &[f64]| {
            let d = dot(&a, b);
            a.iter()
                .zip(b)
                .map(|(x, y)| x - d * y)
                .collect::<Vec<f64>>()
        };
        let u = unit(raw(&|i| (0.37 * i + 0.1).sin()));
        let w = unit(reject(raw(&|i| (1.3 * i).cos()), &u));
        let z = unit(reject(reject(raw(&|i| (0.11 * i * i).sin()), &u), &w));
        (u, w, z)
    }

    /// A column `norm · (cos ε · a + sin ε · b)`.
    fn col(norm: f64, eps: f64, a: &[f64], b: &[f64]) -> Vec<f64> {
        a.iter()
            .zip(b)
            .map(|(x, y)| norm * (eps.cos() * x + eps.sin() * y))
            .collect()
    }

    fn lengths(k: usize) -> Vec<ParamId> {
        (0..k)
            .map(|joint| ParamId::Mdh {
                joint,
                kind: ParamKind::D,
            })
            .collect()
    }

    /// Select over `cols` (a Jacobian's columns, mm per mm) with the default bounds.
    fn decide(params: &[ParamId], cols: &[Vec<f64>], practical: bool) -> Identifiability {
        let j = DMatrix::from_fn(cols[0].len(), cols.len(), |r, c| cols[c][r]);
        let g = j.transpose() * &j;
        let bounds = PracticalBounds::default();
        select(params, params, g.clone(), practical.then_some((&bounds, g)))
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-6 * b.abs()
    }

    #[test]
    fn a_near_dependent_pair_keeps_the_first_and_holds_the_second_with_its_sigma() {
        let (u, w, _) = basis();
        let p = lengths(2);
        // 1 mrad apart: formally identifiable (sin² = 1e-6 ≫ 1e-10), σ = 0.015/(10·1e-3) = 1.5 mm
        let cols = [col(10.0, 0.0, &u, &w), col(10.0, 1e-3, &u, &w)];
        assert_eq!(decide(&p, &cols, false).identified, p, "structurally both");
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, [p[0]]);
        let d = &r.dropped[0];
        assert_eq!(d.param, p[1]);
        assert_eq!(d.kind, DropKind::Dependent);
        let sigma = d.predicted_sigma.expect("finite σ");
        assert!(close(sigma, 0.015 / (10.0 * 1e-3_f64.sin())), "σ {sigma}");
        assert_eq!(
            d.reason,
            "indistinguishable from d1 given these poses: predicted σ 1.50 mm (bound 0.0500 mm)"
        );
        assert!(
            close(r.predicted_sigma[0], 0.0015),
            "{:?}",
            r.predicted_sigma
        );
    }

    #[test]
    fn a_pair_the_noise_separates_is_kept_with_both_sigmas() {
        let (u, w, _) = basis();
        let p = lengths(2);
        // 0.1 rad apart: each σ = 0.015/(10·sin 0.1) ≈ 0.0150 mm, within 0.05 mm
        let cols = [col(10.0, 0.0, &u, &w), col(10.0, 0.1, &u, &w)];
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, p);
        assert!(r.dropped.is_empty());
        let expected = 0.015 / (10.0 * 0.1_f64.sin());
        assert!(
            r.predicted_sigma.iter().all(|s| close(*s, expected)),
            "{:?}",
            r.predicted_sigma
        );
    }

    #[test]
    fn a_barely_excited_parameter_is_poorly_determined() {
        let (u, w, _) = basis();
        let p = lengths(2);
        // orthogonal to the first, but the poses move it 0.1 mm per mm: σ 0.15 mm alone
        let cols = [col(10.0, 0.0, &u, &w), col(0.1, 0.0, &w, &u)];
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, [p[0]]);
        assert_eq!(r.dropped[0].kind, DropKind::PoorlyDetermined);
        assert!(close(r.dropped[0].predicted_sigma.expect("σ"), 0.15));
        assert!(r.dropped[0]
            .reason
            .starts_with("poorly determined by these poses: predicted σ 0.150 mm"));
    }

    #[test]
    fn an_exact_combination_stays_structural_without_a_figure() {
        let (u, w, _) = basis();
        let p = lengths(3);
        let cols = [
            col(10.0, 0.0, &u, &w),
            col(10.0, 0.5, &u, &w),
            col(3.0, 0.0, &u, &w),
        ];
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, [p[0], p[1]]);
        assert_eq!(
            r.dropped,
            [Dropped {
                param: p[2],
                reason: "dependent on d1".to_owned(),
                kind: DropKind::Structural,
                predicted_sigma: None,
            }]
        );
    }

    #[test]
    fn a_kept_parameter_a_later_one_pushes_over_its_bound_is_held_back() {
        let (u, w, _) = basis();
        let p = lengths(2);
        // d1 alone: σ 0.044 mm; d2 well excited (own σ 0.015/(100·0.4) = 0.000375 mm) but at
        // cos √0.84 to d1: with both, σ(d1) = 0.044/0.4 = 0.11 mm. d2 alone carries the shared
        // direction best (keeping d1 instead would blow d2's effect up into it)
        let cols = [
            col(0.015 / 0.044, 0.0, &u, &w),
            col(100.0, 0.4_f64.asin(), &u, &w),
        ];
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, [p[1]]);
        let d = &r.dropped[0];
        assert_eq!(d.param, p[0]);
        assert_eq!(d.kind, DropKind::Dependent);
        assert!(close(d.predicted_sigma.expect("σ"), 0.11));
        assert_eq!(
            d.reason,
            "indistinguishable from d2 given these poses: predicted σ 0.110 mm (bound 0.0500 mm)"
        );
        assert!(
            close(r.predicted_sigma[0], 0.00015),
            "{:?}",
            r.predicted_sigma
        );
    }

    #[test]
    fn a_rise_of_a_kept_sigma_within_its_bound_keeps_both() {
        let (u, w, _) = basis();
        let p = lengths(2);
        // σ(d1) 0.03 → 0.03/0.8 = 0.0375 mm with d2 at cos 0.6
        let cols = [
            col(0.015 / 0.03, 0.0, &u, &w),
            col(100.0, 0.6_f64.acos(), &u, &w),
        ];
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, p);
        assert!(
            close(r.predicted_sigma[0], 0.0375),
            "{:?}",
            r.predicted_sigma
        );
    }

    #[test]
    fn a_held_back_parameter_leaves_room_for_a_later_one_the_data_determines() {
        let (u, w, z) = basis();
        // θ1 barely moves the point; the later tool_y, structurally a copy of it, does the
        // same job well
        let p = [
            ParamId::Mdh {
                joint: 0,
                kind: ParamKind::Theta,
            },
            ParamId::Mdh {
                joint: 1,
                kind: ParamKind::D,
            },
            ParamId::Tool(1),
        ];
        // θ1: 0.09 mm per rad along z (σ 0.17 rad); d2 along u; tool_y along z (θ1's column × 11)
        let cols = [
            col(0.09, 0.0, &z, &u),
            col(10.0, 0.0, &u, &w),
            col(1.0, 0.0, &z, &u),
        ];
        let structural = decide(&p, &cols, false);
        assert_eq!(structural.identified, [p[0], p[1]]);
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, [p[1], p[2]]);
        assert_eq!(r.dropped.len(), 1);
        assert_eq!(r.dropped[0].kind, DropKind::PoorlyDetermined);
        assert!(
            r.dropped[0].reason.contains("mrad (bound 0.500 mrad)"),
            "{}",
            r.dropped[0].reason
        );
    }

    #[test]
    fn a_robot_parameter_that_would_blur_a_kept_frame_is_held_back_not_the_frame() {
        let (u, w, _) = basis();
        // tool_x alone: σ 0.015 mm; d1 well excited (σ 0.00075 mm with it) but at sin 0.2 to
        // tool_x: with both, σ(tool_x) = 0.015/0.2 = 0.075 mm, over its bound. Frame first:
        // the tool keeps the shared direction, d1 stays at nominal
        let tool = ParamId::Tool(0);
        let d1 = lengths(1)[0];
        let p = [tool, d1];
        let cols = [col(1.0, 0.0, &u, &w), col(100.0, 0.2_f64.asin(), &u, &w)];
        let r = decide(&p, &cols, true);
        assert_eq!(r.identified, [tool]);
        let d = &r.dropped[0];
        assert_eq!((d.param, d.kind), (d1, DropKind::Dependent));
        assert!(
            d.reason.starts_with(
                "indistinguishable from tool_x given these poses: identifying it would raise \
                 tool_x's predicted σ to 0.0750 mm (bound 0.0500 mm)"
            ),
            "{}",
            d.reason
        );
    }

    #[test]
    fn frames_come_first_in_the_priority_order() {
        let m = crate::model::tx60();
        let order = priority_order(&m, &super::super::params::all_params(6, true, true));
        assert_eq!(order.len(), 39);
        assert!(order[..9].iter().all(is_frame), "{order:?}");
        assert!(!order[9..].iter().any(is_frame), "{order:?}");
    }

    #[test]
    fn same_input_same_selection() {
        let (u, w, z) = basis();
        let p = lengths(3);
        let cols = [
            col(10.0, 0.0, &u, &w),
            col(10.0, 2e-3, &u, &w),
            col(5.0, 0.3, &z, &w),
        ];
        assert_eq!(decide(&p, &cols, true), decide(&p, &cols, true));
    }

    #[test]
    fn bounds_must_be_finite_and_positive() {
        assert!(PracticalBounds::default().check().is_ok());
        for b in [
            PracticalBounds {
                noise_mm: f64::NAN,
                ..Default::default()
            },
            PracticalBounds {
                noise_mm: -1.0,
                ..Default::default()
            },
            PracticalBounds {
                max_sigma_mm: 0.0,
                ..Default::default()
            },
            PracticalBounds {
                max_sigma_rad: f64::INFINITY,
                ..Default::default()
            },
        ] {
            assert!(b.check().is_err(), "{b:?}");
        }
    }
}
