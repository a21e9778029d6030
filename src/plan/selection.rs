//! Optimal selection of identification poses, and the one prediction of a calibration's
//! verification error (docs/method.md §9).
//!
//! **The prediction.** The campaign's verification figure is the mean, over the verification
//! poses, of ‖e‖ with `e = P1 − p_model` (`Metrics::position_mean_mm`, docs/method.md §6). For
//! a model identified with parameter error `δ ~ N(0, C)` the error at one verification pose is
//! `e = J_v δ + ε_v`: `J_v` the ball position's Jacobian over the identified parameters, `ε_v`
//! the verification reading's own noise (the tracker's per-axis σ at that range, plus the
//! arm's joint jitter). So `e ~ N(0, J_v C J_vᵀ + Σ_v)`, and its expected norm is computed
//! exactly (a one-dimensional integral over the three eigenvalues, [`expected_norm`]), not by
//! `√trace`. [`predicted_verification`] averages it over the verification joints; its noise
//! floor is the same with `C = 0` (a perfect model still reads noise).
//!
//! **The covariance of a design.** The campaign identifies by unweighted least squares on the
//! solver's rows (position, and the stage direction times its weight `w`); the rows' noise is
//! not independent: `P1` enters the position rows and the direction `(P2 − P1)/s`, so their
//! perpendicular parts correlate (−1/√2 at `w = s/√2`), and the jitter of the arm moves both.
//! [`Design::covariance`] is that estimator's exact (linearised) covariance, the sandwich
//! `A⁻¹ B A⁻¹` with `A = Σ JᵢᵀJᵢ`, `B = Σ Jᵢᵀ Σᵢ Jᵢ`, `Σᵢ` each pose's row noise.
//!
//! **The criterion** (I-optimality): minimise `tr(W·C)`, the mean squared error the
//! parameters add at random workspace poses, `W` = the mean of `J_vᵀJ_v` over a separate
//! random draw of workspace poses (never the campaign's verification poses). The figure
//! is a verification error, and I-optimality minimises exactly its parameter part, weighting
//! each direction of parameter space by how much it moves the ball where the robot works; a
//! D-optimal design maximises the volume of information, in mixed units (mm and rad), and
//! spends poses on parameter combinations the verification barely sees (the base rotation
//! against joint offsets at long lever arms). For the search, `C` is the covariance with each
//! row independent at its pose's tracker σ (the predicted σ of the identifiability analysis,
//! range-dependent), so one pose is a rank-`r` update of the information (`r` = rows per pose)
//! and Woodbury's identity prices every candidate in O(p²r). Greedy forward selection from a
//! weak prior (10 mm, 10 mrad per parameter: it only orders the first picks), then exchange
//! passes (Fedorov: the best swap of a selected pose for a candidate, until none improves the
//! criterion by 0.01 %, at most 10 passes);
//! then the selection is re-ranked greedily among itself, so every prefix is a good design
//! (blocks of a campaign that stops early). The figures reported are always the exact
//! sandwich covariance above.

use nalgebra::{DMatrix, Matrix3, Vector3};

use crate::identify::identifiability::{
    analyze_linearized, is_compliance, PracticalBounds, REFERENCE_TORQUE_NM,
};
use crate::identify::observation::{predict, residual_jacobian, Measured, ObsConfig, ObsModel};
use crate::identify::params::{all_params, ParamId};
use crate::identify::problem::JointTrig;
use crate::identify::TrackerNoise;
use crate::model::{ParamKind, RobotModel};

/// How the identification poses of a campaign are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Selection {
    /// The first poses drawn (joint-space sampling with rejection).
    #[default]
    Random,
    /// Chosen from a pool of measurable poses by the I-optimal criterion ([`select`]).
    Optimal,
}

impl Selection {
    /// Contract name: `random`, `optimal`.
    pub fn name(self) -> &'static str {
        match self {
            Selection::Random => "random",
            Selection::Optimal => "optimal",
        }
    }
}

/// What a campaign's identification will be, for [`Selection::Optimal`] to design for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DesignSetup {
    /// Observation model, stage axis, direction weight.
    pub obs: ObsConfig,
    /// Stage travel P1 → P2 (mm).
    pub stage_travel_mm: f64,
    /// The base is identified (a campaign's default).
    pub identify_base: bool,
    /// The tool is identified.
    pub identify_tool: bool,
    /// Tracker per-axis σ at 2.5 m (mm; [`NoiseModel::at960_scaled`]).
    pub noise_mm: f64,
    /// Joint jitter σ (rad).
    pub joint_jitter_rad: f64,
}

impl Default for DesignSetup {
    /// OP, stage +y 10 mm, base identified, tool not, an AT960, no jitter.
    fn default() -> Self {
        DesignSetup {
            obs: ObsConfig::new(ObsModel::Op, 10.0),
            stage_travel_mm: 10.0,
            identify_base: true,
            identify_tool: false,
            noise_mm: crate::identify::identifiability::DEFAULT_NOISE_MM,
            joint_jitter_rad: 0.0,
        }
    }
}

/// Predicted mean verification error (mm) and what it is made of.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PredictedError {
    /// Expected mean ‖P1 − p_model‖ over the verification poses (mm), as
    /// `Metrics::position_mean_mm` measures it: parameter error and reading noise together.
    pub mean_mm: f64,
    /// The same with a perfect model: the verification readings' own noise (mm).
    pub noise_floor_mm: f64,
}

/// Measurement noise of the cell: the tracker's range-dependent per-axis σ and the arm's joint
/// jitter (the arm sits a little off the joints the controller reports).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseModel {
    /// Tracker model (its position in the measurement frame gives the range).
    pub tracker: TrackerNoise,
    /// σ of each joint's jitter (rad), drawn once per move: the same for P1 and P2.
    pub joint_jitter_rad: f64,
}

impl NoiseModel {
    /// An AT960 at `tracker_mm` scaled so that its per-axis σ at 2.5 m range is `noise_mm`
    /// (0.015 mm: the AT960 itself, [`crate::identify::identifiability::DEFAULT_NOISE_MM`]),
    /// no joint jitter.
    pub fn at960_scaled(tracker_mm: Vector3<f64>, noise_mm: f64) -> NoiseModel {
        let mut t = TrackerNoise::at960(tracker_mm);
        let at_ref = t.sigma_mm(&(tracker_mm + Vector3::new(REFERENCE_RANGE_MM, 0.0, 0.0)));
        t.k *= at_ref / noise_mm;
        NoiseModel {
            tracker: t,
            joint_jitter_rad: 0.0,
        }
    }
}

/// The range at which `--noise-mm` gives the tracker's per-axis σ (mm).
pub const REFERENCE_RANGE_MM: f64 = 2500.0;

/// An identification to design for: the nominal model in the measurement frame (base, and the
/// ball as its tool), the observation model, the noise and the identified parameters.
#[derive(Debug, Clone)]
pub struct Design {
    /// Nominal model; `base_*` map the robot base into the measurement frame, `tool` is the
    /// ball in the flange frame.
    pub model: RobotModel,
    /// Observation model, stage axis and direction weight, as the identification uses them.
    pub obs: ObsConfig,
    /// Stage travel P1 → P2 (mm): the direction's noise is the points' noise over it.
    pub stage_travel_mm: f64,
    /// The cell's noise.
    pub noise: NoiseModel,
    /// The identified parameters (structurally and practically identifiable, held-back ones
    /// excluded), in the identification's order.
    pub params: Vec<ParamId>,
}

/// Why a design or a selection cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SelectionError {
    /// No candidate to choose from.
    #[error("the pool of candidate poses is empty")]
    EmptyPool,
    /// Fewer poses than the identification needs.
    #[error("{count} poses cannot identify {parameters} parameters with {rows} equations per pose: at least {needed} are needed")]
    TooFew {
        /// Poses asked for.
        count: usize,
        /// Parameters identified.
        parameters: usize,
        /// Rows per pose.
        rows: usize,
        /// Least number of poses.
        needed: usize,
    },
    /// More poses asked for than the pool holds.
    #[error("{count} poses asked for, but the pool holds only {pool}")]
    PoolTooSmall {
        /// Poses asked for.
        count: usize,
        /// Candidates.
        pool: usize,
    },
    /// A value that is not usable (NaN, infinite, out of range).
    #[error("{0}")]
    Invalid(String),
}

impl Design {
    /// The design of an identification of `model` with `obs`: the parameters are those the
    /// identification keeps on the poses `poses` (structural and practical test with the
    /// default bounds, as a campaign identifies; base and tool as asked).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: RobotModel,
        obs: ObsConfig,
        stage_travel_mm: f64,
        noise: NoiseModel,
        identify_base: bool,
        identify_tool: bool,
        poses: &[Vec<f64>],
    ) -> Result<Design, SelectionError> {
        if poses.is_empty() {
            return Err(SelectionError::EmptyPool);
        }
        for (what, v) in [
            ("stage travel (mm)", stage_travel_mm),
            ("joint jitter (rad)", noise.joint_jitter_rad),
            ("tracker noise", noise.tracker.k),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SelectionError::Invalid(format!(
                    "{what} {v}: must be a finite number ≥ 0"
                )));
            }
        }
        let measured: Vec<Measured> = poses.iter().cloned().map(Measured::joints_only).collect();
        let candidates = all_params(model.dof(), identify_base, identify_tool);
        let (ident, _) = analyze_linearized(
            &model,
            &measured,
            &JointTrig::of(&measured),
            &obs,
            &candidates,
            Some(&PracticalBounds::default()),
        );
        Ok(Design {
            model,
            obs,
            stage_travel_mm,
            noise,
            params: ident.identified,
        })
    }

    /// Rows per pose of the observation model.
    pub fn rows(&self) -> usize {
        self.obs.model.rows()
    }

    /// Least number of poses the identification accepts (as `identify` counts them).
    pub fn min_poses(&self) -> usize {
        (self.params.len().div_ceil(self.rows()) + 1).max(3)
    }

    /// The identification's rows at `q` (rows × params, row-major, solver weights, pose
    /// weight 1).
    fn rows_at(&self, q: &[f64], params: &[ParamId]) -> DMatrix<f64> {
        let rows = self.rows();
        let mut res = vec![0.0; rows];
        let mut jac = vec![0.0; rows * params.len()];
        residual_jacobian(
            &self.model,
            &Measured::joints_only(q.to_vec()),
            &self.obs,
            params,
            &mut res,
            &mut jac,
        );
        DMatrix::from_row_slice(rows, params.len(), &jac)
    }

    /// The identification rows at `q` over [`Design::params`].
    pub fn jacobian(&self, q: &[f64]) -> DMatrix<f64> {
        self.rows_at(q, &self.params)
    }

    /// Ball position Jacobian at `q` (3 × params): how each parameter moves the ball.
    pub fn position_jacobian(&self, q: &[f64]) -> DMatrix<f64> {
        self.jacobian(q).rows(0, 3).into_owned()
    }

    /// The tracker's per-axis σ (mm) of the ball at `q`.
    pub fn tracker_sigma_mm(&self, q: &[f64]) -> f64 {
        self.noise.tracker.sigma_mm(&predict(&self.model, q).p)
    }

    /// The joint-jitter Jacobian of the identification rows at `q` (rows × dof): a joint's
    /// jitter moves the arm as its θ offset does.
    pub(crate) fn jitter_rows(&self, q: &[f64]) -> DMatrix<f64> {
        let thetas: Vec<ParamId> = (0..self.model.dof())
            .map(|joint| ParamId::Mdh {
                joint,
                kind: ParamKind::Theta,
            })
            .collect();
        self.rows_at(q, &thetas)
    }

    /// Covariance of the noise of the identification rows at `q` (rows × rows): the reading
    /// P1 in the position rows; for np/op the direction `(P2 − P1)/s` perpendicular to the
    /// stage direction, correlated with P1; for the full model each rotation row as noisy as
    /// a unit-weight position row (no 1D stage measures it; an assumption); plus the joint
    /// jitter moving all of them.
    pub fn row_noise(&self, q: &[f64]) -> DMatrix<f64> {
        let rows = self.rows();
        let pr = predict(&self.model, q);
        let s1 = self.noise.tracker.sigma_mm(&pr.p);
        let mut c = DMatrix::zeros(rows, rows);
        for i in 0..3 {
            c[(i, i)] = s1 * s1;
        }
        match self.obs.model {
            ObsModel::Position => {}
            ObsModel::Np | ObsModel::Op => {
                let l = pr.r * self.obs.stage_axis;
                let s = self.stage_travel_mm.max(1e-9);
                let s2 = self.noise.tracker.sigma_mm(&(pr.p + s * l));
                let perp = Matrix3::identity() - l * l.transpose();
                let g = self.obs.direction_weight_mm / s;
                let dir = perp * (g * g * (s1 * s1 + s2 * s2));
                // residual rows: −ε1 and −g·P⊥(ε2 − ε1): their covariance is −g·σ1²·P⊥
                let cross = perp * (-g * s1 * s1);
                for a in 0..3 {
                    for b in 0..3 {
                        c[(3 + a, 3 + b)] = dir[(a, b)];
                        c[(a, 3 + b)] = cross[(a, b)];
                        c[(3 + a, b)] = cross[(b, a)];
                    }
                }
            }
            ObsModel::Full => {
                for i in 3..rows {
                    c[(i, i)] = s1 * s1;
                }
            }
        }
        let sq = self.noise.joint_jitter_rad;
        if sq > 0.0 {
            let g = self.jitter_rows(q);
            c += (&g * g.transpose()) * (sq * sq);
        }
        c
    }

    /// Covariance (3 × 3, mm²) of one verification reading at `q`: the tracker's σ per axis
    /// and the joint jitter.
    pub fn reading_noise(&self, q: &[f64]) -> Matrix3<f64> {
        let s = self.tracker_sigma_mm(q);
        let mut c = Matrix3::identity() * (s * s);
        let sq = self.noise.joint_jitter_rad;
        if sq > 0.0 {
            let g = self.jitter_rows(q);
            let gp = g.rows(0, 3);
            let gg = gp * gp.transpose() * (sq * sq);
            c += Matrix3::from_fn(|a, b| gg[(a, b)]);
        }
        c
    }

    /// Predicted covariance of the identified parameters (over [`Design::params`]) from the
    /// identification poses `ident_q`: the campaign's unweighted least squares under this
    /// design's noise, `A⁻¹ B A⁻¹` (module doc); `None` when the poses do not determine every
    /// parameter.
    pub fn covariance(&self, ident_q: &[Vec<f64>]) -> Option<DMatrix<f64>> {
        let p = self.params.len();
        let mut a = DMatrix::zeros(p, p);
        let mut b = DMatrix::zeros(p, p);
        for q in ident_q {
            let j = self.jacobian(q);
            let jt = j.transpose();
            a += &jt * &j;
            b += &jt * self.row_noise(q) * &j;
        }
        let ai = a.cholesky()?.inverse();
        let c = &ai * b * &ai;
        Some((&c + c.transpose()) * 0.5)
    }
}

/// Expected norm `E‖x‖` of a zero-mean Gaussian 3-vector with covariance `cov` (mm), from its
/// eigenvalues λ: `E‖x‖ = (1/2√π) ∫₀^∞ (1 − Π(1 + 2tλᵢ)^(−1/2)) t^(−3/2) dt`, integrated in
/// `ln t` by the trapezoid rule (exponentially convergent here; relative error < 1e-9).
pub fn expected_norm(cov: &Matrix3<f64>) -> f64 {
    let sym = (cov + cov.transpose()) * 0.5;
    let ev = sym.symmetric_eigenvalues();
    let lam: Vec<f64> = ev.iter().map(|l| l.max(0.0)).collect();
    let total: f64 = lam.iter().sum();
    if total.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || !total.is_finite() {
        return if total.is_finite() { 0.0 } else { f64::NAN };
    }
    let rel: Vec<f64> = lam.iter().map(|l| l / total).collect();
    // the integrand in u = ln t, of the normalised eigenvalues (Σ = 1): e^(u/2) as u → −∞,
    // ≤ e^(−u/2)/√(min λ) as u → ∞; the floor keeps a degenerate direction from a long tail
    let min = rel.iter().copied().fold(f64::INFINITY, f64::min).max(1e-12);
    let (lo, hi) = (-44.0, 44.0 - min.ln());
    let h = 0.05;
    let n = ((hi - lo) / h).ceil() as usize;
    let f = |u: f64| {
        let t = u.exp();
        let log_prod: f64 = rel.iter().map(|l| (2.0 * t * l).ln_1p()).sum();
        -(-0.5 * log_prod).exp_m1() * (-0.5 * u).exp()
    };
    let mut sum = 0.5 * (f(lo) + f(lo + n as f64 * h));
    for i in 1..n {
        sum += f(lo + i as f64 * h);
    }
    total.sqrt() * sum * h / (2.0 * std::f64::consts::PI.sqrt())
}

/// Predicted verification error of a model identified with parameter covariance `cov` (over
/// `design.params`) at the verification joints `verify_q`, under the design's noise model.
pub fn predicted_verification(
    design: &Design,
    cov: &DMatrix<f64>,
    verify_q: &[Vec<f64>],
) -> PredictedError {
    predicted_verification_biased(design, cov, verify_q, None)
}

/// [`predicted_verification`] with, at each verification pose, the covariance (mm²) of what
/// the parameters held at nominal leave in the model ([`held_back_bias`]; `None`: nothing).
pub fn predicted_verification_biased(
    design: &Design,
    cov: &DMatrix<f64>,
    verify_q: &[Vec<f64>],
    bias: Option<&[Matrix3<f64>]>,
) -> PredictedError {
    let n = verify_q.len().max(1) as f64;
    let (mut mean, mut floor) = (0.0, 0.0);
    for (i, q) in verify_q.iter().enumerate() {
        let jv = design.position_jacobian(q);
        let noise = design.reading_noise(q);
        let par = &jv * cov * jv.transpose();
        let held = bias
            .and_then(|b| b.get(i))
            .copied()
            .unwrap_or_else(Matrix3::zeros);
        let total = noise + held + Matrix3::from_fn(|a, b| par[(a, b)]);
        mean += expected_norm(&total);
        floor += expected_norm(&noise);
    }
    PredictedError {
        mean_mm: mean / n,
        noise_floor_mm: floor / n,
    }
}

/// The spread of a parameter's error before calibration (its unit), what a parameter held at
/// nominal is expected to be off by: the RMS of the TX60's errors in the paper's Table 3
/// (docs/method.md §7), rounded up: 1 mrad for a joint offset θ (Table 3: 1.0 mrad), 0.5 mrad
/// for another angle (α: 0.54 mrad), 0.2 mm for a length (d, a: 0.16 mm), and for a
/// compliance the angle at [`REFERENCE_TORQUE_NM`].
pub fn prior_error(p: &ParamId) -> f64 {
    if is_compliance(p) {
        PRIOR_ERROR_RAD / REFERENCE_TORQUE_NM
    } else if matches!(
        p,
        ParamId::Mdh {
            kind: ParamKind::Theta,
            ..
        }
    ) {
        PRIOR_OFFSET_ERROR_RAD
    } else if p.is_angle() {
        PRIOR_ERROR_RAD
    } else {
        PRIOR_ERROR_MM
    }
}

/// σ of a length's error before calibration (mm), [`prior_error`].
pub const PRIOR_ERROR_MM: f64 = 0.2;
/// σ of an angle's error before calibration (rad), [`prior_error`].
pub const PRIOR_ERROR_RAD: f64 = 5e-4;
/// σ of a joint offset's error before calibration (rad), [`prior_error`].
pub const PRIOR_OFFSET_ERROR_RAD: f64 = 1e-3;

/// What parameters held at nominal (`held`, each off by its [`prior_error`]) leave in a model
/// whose `design.params` are identified on `ident_q`: the identification absorbs the part of
/// their effect its parameters can mimic on those poses (least squares, `A = (J_kᵀJ_k)⁻¹J_kᵀJ_h`
/// over the solver's rows), the rest stays; at each verification pose the covariance (mm²) of
/// the ball's error that rest makes, `B·diag(σ²)·Bᵀ` with `B = J_v,h − J_v,k·A`. `None` when the
/// poses do not determine `design.params`.
pub fn held_back_bias(
    design: &Design,
    held: &[ParamId],
    ident_q: &[Vec<f64>],
    verify_q: &[Vec<f64>],
) -> Option<Vec<Matrix3<f64>>> {
    let k = design.params.len();
    let mut both = design.clone();
    both.params.extend(held.iter().copied());
    let h = held.len();
    let (mut jkk, mut jkh) = (DMatrix::zeros(k, k), DMatrix::zeros(k, h));
    for q in ident_q {
        let j = both.jacobian(q);
        let (jk, jh) = (j.columns(0, k), j.columns(k, h));
        jkk += jk.transpose() * jk;
        jkh += jk.transpose() * jh;
    }
    let a = jkk.cholesky()?.solve(&jkh);
    let prior = DMatrix::from_fn(h, h, |i, j| {
        if i == j {
            prior_error(&held[i]).powi(2)
        } else {
            0.0
        }
    });
    Some(
        verify_q
            .iter()
            .map(|q| {
                let j = both.position_jacobian(q);
                let b = j.columns(k, h) - j.columns(0, k) * &a;
                let c = &b * &prior * b.transpose();
                Matrix3::from_fn(|r, s| c[(r, s)])
            })
            .collect(),
    )
}

/// Prior σ of a length parameter in the search (mm): weak, it only orders the first picks.
const PRIOR_SIGMA_MM: f64 = 10.0;
/// Prior σ of an angle parameter in the search (rad).
const PRIOR_SIGMA_RAD: f64 = 0.01;
/// Exchange passes at most (each visits every selected pose once).
const MAX_EXCHANGE_PASSES: usize = 10;
/// Relative improvement of the criterion below which a swap is not made (0.01 %: smaller ones
/// change no figure and cost whole passes).
const EXCHANGE_TOL: f64 = 1e-4;

/// The result of [`select`].
#[derive(Debug, Clone, PartialEq)]
pub struct Selected {
    /// Indices into the pool, in rank order: each prefix is the best of its size the greedy
    /// ranking found among the selected (measure them first when a campaign may stop early).
    pub indices: Vec<usize>,
    /// The criterion `tr(W·C)` (mm²) of the selection, `C` with independent rows and the
    /// search's weak prior.
    pub criterion_mm2: f64,
    /// The same after the greedy pass alone, before the exchanges.
    pub greedy_criterion_mm2: f64,
    /// Swaps the exchange passes made.
    pub exchanges: usize,
}

/// The search state: whitened rows of every candidate, stacked, and the weight `W`.
struct Search {
    /// Rows per pose.
    r: usize,
    /// Parameters.
    p: usize,
    /// Candidate `k`'s rows `J_k/σ_k` are rows `k·r .. (k+1)·r`.
    z: DMatrix<f64>,
    /// `W` (p × p).
    w: DMatrix<f64>,
}

impl Search {
    fn rows(&self, k: usize) -> nalgebra::DMatrixView<'_, f64> {
        self.z.rows(k * self.r, self.r)
    }

    fn prior(&self, params: &[ParamId]) -> DMatrix<f64> {
        DMatrix::from_fn(self.p, self.p, |a, b| {
            if a != b {
                0.0
            } else if params[a].is_angle() {
                PRIOR_SIGMA_RAD * PRIOR_SIGMA_RAD
            } else {
                PRIOR_SIGMA_MM * PRIOR_SIGMA_MM
            }
        })
    }

    /// The decrease of `tr(W·C)` adding each candidate to `c` would bring (`NaN`-free; −∞ for
    /// the `taken` ones): `tr(S⁻¹ Z C W C Zᵀ)` with `S = I + Z C Zᵀ`.
    fn gains(&self, c: &DMatrix<f64>, taken: &[bool]) -> Vec<f64> {
        let cwc = c * &self.w * c;
        let y = &self.z * c;
        let v = &self.z * cwc;
        let r = self.r;
        (0..taken.len())
            .map(|k| {
                if taken[k] {
                    return f64::NEG_INFINITY;
                }
                let zk = self.rows(k);
                let s = DMatrix::identity(r, r) + y.rows(k * r, r) * zk.transpose();
                let t = v.rows(k * r, r) * zk.transpose();
                match s.cholesky() {
                    Some(ch) => ch.solve(&t).trace(),
                    None => f64::NEG_INFINITY,
                }
            })
            .collect()
    }

    /// `c` with candidate `k` added (`sign` = 1) or removed (`sign` = −1), by Woodbury.
    fn update(&self, c: &DMatrix<f64>, k: usize, sign: f64) -> Option<DMatrix<f64>> {
        let zk = self.rows(k);
        let u = zk * c;
        let s = DMatrix::identity(self.r, self.r) * sign + &u * zk.transpose();
        let inv = s.try_inverse()?;
        let out = c - u.transpose() * inv * &u;
        Some((&out + out.transpose()) * 0.5)
    }

    fn criterion(&self, c: &DMatrix<f64>) -> f64 {
        (&self.w * c).trace()
    }

    /// `C` of a set of candidates from scratch (with the prior).
    fn covariance(&self, prior: &DMatrix<f64>, set: &[usize]) -> Option<DMatrix<f64>> {
        let mut m = prior.clone().try_inverse()?;
        for &k in set {
            let zk = self.rows(k);
            m += zk.transpose() * zk;
        }
        m.cholesky().map(|ch| ch.inverse())
    }

    /// Greedy forward selection of `count` among `allowed` from `c`.
    fn greedy(
        &self,
        mut c: DMatrix<f64>,
        allowed: &[bool],
        count: usize,
    ) -> (Vec<usize>, DMatrix<f64>) {
        let mut taken: Vec<bool> = allowed.iter().map(|a| !a).collect();
        let mut out = Vec::with_capacity(count);
        while out.len() < count {
            let gains = self.gains(&c, &taken);
            let Some((best, _)) = gains
                .iter()
                .enumerate()
                .filter(|(_, g)| g.is_finite())
                .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            else {
                break;
            };
            match self.update(&c, best, 1.0) {
                Some(next) => c = next,
                None => break,
            }
            taken[best] = true;
            out.push(best);
        }
        (out, c)
    }
}

/// Choose `count` identification poses from `pool` (joints, rad) for `design`: the I-optimal
/// criterion `tr(W·C)` with `W` the mean of `J_vᵀJ_v` over `reference` (random workspace
/// poses, a draw of their own), by greedy forward selection and exchange passes (module doc).
/// Deterministic.
pub fn select(
    design: &Design,
    pool: &[Vec<f64>],
    count: usize,
    reference: &[Vec<f64>],
) -> Result<Selected, SelectionError> {
    if pool.is_empty() {
        return Err(SelectionError::EmptyPool);
    }
    let needed = design.min_poses();
    if count < needed {
        return Err(SelectionError::TooFew {
            count,
            parameters: design.params.len(),
            rows: design.rows(),
            needed,
        });
    }
    if count > pool.len() {
        return Err(SelectionError::PoolTooSmall {
            count,
            pool: pool.len(),
        });
    }
    if reference.is_empty() {
        return Err(SelectionError::Invalid(
            "no reference poses to weigh the verification error by".into(),
        ));
    }
    let (r, p) = (design.rows(), design.params.len());
    let mut z = DMatrix::zeros(pool.len() * r, p);
    for (k, q) in pool.iter().enumerate() {
        let sigma = design.tracker_sigma_mm(q);
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(SelectionError::Invalid(format!(
                "tracker σ {sigma} mm at a candidate: the noise must be finite and > 0"
            )));
        }
        z.rows_mut(k * r, r)
            .copy_from(&(design.jacobian(q) / sigma));
    }
    let mut w = DMatrix::zeros(p, p);
    for q in reference {
        let jv = design.position_jacobian(q);
        w += jv.transpose() * jv;
    }
    w /= reference.len() as f64;
    let search = Search { r, p, z, w };
    let prior = search.prior(&design.params);
    let all = vec![true; pool.len()];
    let (mut chosen, mut c) = search.greedy(prior.clone(), &all, count);
    if chosen.len() < count {
        return Err(SelectionError::Invalid(
            "the pool's poses do not determine the parameters".into(),
        ));
    }
    let greedy_criterion = search.criterion(&c);
    // exchange passes: for each selected pose, the best swap for a candidate
    let mut taken = vec![false; pool.len()];
    for &k in &chosen {
        taken[k] = true;
    }
    let mut exchanges = 0;
    let mut current = greedy_criterion;
    for _ in 0..MAX_EXCHANGE_PASSES {
        let mut improved = false;
        #[allow(clippy::needless_range_loop)] // `chosen[slot]` is replaced inside
        for slot in 0..chosen.len() {
            let out = chosen[slot];
            let Some(without) = search.update(&c, out, -1.0) else {
                continue;
            };
            let base = search.criterion(&without);
            let gains = search.gains(&without, &taken);
            let Some((best, gain)) = gains
                .iter()
                .enumerate()
                .filter(|(_, g)| g.is_finite())
                .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            else {
                continue;
            };
            if base - gain < current * (1.0 - EXCHANGE_TOL) {
                let Some(next) = search.update(&without, best, 1.0) else {
                    continue;
                };
                c = next;
                taken[out] = false;
                taken[best] = true;
                chosen[slot] = best;
                current = search.criterion(&c);
                exchanges += 1;
                improved = true;
            }
        }
        // from scratch once per pass: the Woodbury updates do not drift
        if let Some(fresh) = search.covariance(&prior, &chosen) {
            c = fresh;
            current = search.criterion(&c);
        }
        if !improved {
            break;
        }
    }
    // rank the selection greedily among itself: every prefix a good design
    let (ranked, c) = search.greedy(prior, &taken, count);
    let criterion = search.criterion(&c);
    let indices = if ranked.len() == count {
        ranked
    } else {
        chosen
    };
    Ok(Selected {
        indices,
        criterion_mm2: criterion,
        greedy_criterion_mm2: greedy_criterion,
        exchanges,
    })
}
