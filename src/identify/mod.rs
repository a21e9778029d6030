//! Identification of MDH (and optionally base and tool) parameter errors.
//!
//! Pure code. Flow: [`identify`] → initial state (given base/tool, or a rigid registration of
//! the nominal model to the data when the base is identified) → [`identifiability::analyze`]
//! on the actual poses, checked against generic poses so that too few or too similar poses are
//! an error rather than a silently smaller model (a parameter the practical test holds back as
//! undetermined by the data is a result, listed with its predicted σ, not an error) → Levenberg–Marquardt ([`solver`]), started
//! from the linearisation the analysis computed at the initial state ([`normal::SplitSums`]) →
//! optional iteratively reweighted robust refit ([`robust`]) → standard deviations and
//! correlations from `σ̂²·(JᵀJ)⁻¹`.

pub mod covariance;
pub mod identifiability;
pub mod normal;
pub mod observation;
pub mod params;
pub mod problem;
pub mod robust;
pub mod solver;
pub mod tracker_noise;

use nalgebra::{DMatrix, DVector, Vector3};
use rand::{Rng, SeedableRng};

pub use identifiability::{DropKind, Dropped, Identifiability, PracticalBounds};
pub use observation::{predict, Measured, ObsConfig, ObsModel};
pub use params::{all_params, retract, ParamId};
pub use problem::JointTrig;
pub use robust::RobustLoss;
pub use tracker_noise::TrackerNoise;

use crate::measure::fit_rigid;
use crate::model::kinematics::forward;
use crate::model::rotation::to_rotation_vector;
use crate::model::{gravity_levers, RobotModel, TermFamily, TermKind};
use covariance::{covariance, unit_variance, Covariance};
use problem::CalibProblem;
use solver::Problem;

/// Options of one identification.
#[derive(Debug, Clone, Copy)]
pub struct IdentifyOptions {
    /// Observation model and weighting.
    pub obs: ObsConfig,
    /// Identify the base transform (measurement frame ≠ robot base frame).
    pub identify_base: bool,
    /// Identify the ball position in the flange frame.
    pub identify_tool: bool,
    /// The given model's base is the cell's base registration (a campaign's setup, a data
    /// file's setup header), not the robot file's own frame: the "before" is measured with it
    /// even when the base is identified ([`BeforeBase::SetupRegistration`]), and robot
    /// parameters a held registered base absorbs are setup-relative.
    pub registered_base: bool,
    /// Robust loss for an iteratively reweighted refit, if any.
    pub robust: Option<RobustLoss>,
    /// Per-point weights from the tracker's uncertainty model: each pose is weighted by
    /// σ(1 m)/σ(range), range measured from this tracker (measurement frame). `None` = equal weights.
    pub point_weights: Option<TrackerNoise>,
    /// Solver options.
    pub solver: solver::Options,
    /// Practical identifiability: a-priori noise and the σ bounds over which a parameter is held
    /// at nominal (with `point_weights`, the noise is the tracker model's σ at 1 m instead).
    pub practical: PracticalBounds,
    /// The families of non-geometric terms identified with the geometry (§10); none by default.
    pub nongeometric: Nongeometric,
}

impl IdentifyOptions {
    /// The defaults for observation `obs`: robot parameters only (no base, no tool, the robot
    /// file's own base), equal weights, no robust refit, the default solver and bounds, no
    /// non-geometric terms.
    pub fn new(obs: ObsConfig) -> IdentifyOptions {
        IdentifyOptions {
            obs,
            identify_base: false,
            identify_tool: false,
            registered_base: false,
            robust: None,
            point_weights: None,
            solver: solver::Options::default(),
            practical: PracticalBounds::default(),
            nongeometric: Nongeometric::default(),
        }
    }
}

/// Which families of non-geometric joint terms an identification adds to the geometric
/// parameters (§10): a copyable set of [`TermFamily`]s, empty by default.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Nongeometric {
    /// One compliance per joint that carries a gravity lever.
    pub compliance: bool,
    /// Four harmonic coefficients per joint.
    pub harmonics: bool,
    /// Which model a calibration hands over (the identification itself ignores it).
    pub keep: NongeometricKeep,
}

/// `[campaign] nongeometric_keep`: which model a calibration with terms hands over.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NongeometricKeep {
    /// The model with the terms (default).
    #[default]
    Extended,
    /// The better of the extended and the geometric model on the verification set.
    Better,
}

impl Nongeometric {
    /// The set holding `families`.
    pub fn of(families: &[TermFamily]) -> Nongeometric {
        Nongeometric {
            compliance: families.contains(&TermFamily::Compliance),
            harmonics: families.contains(&TermFamily::Harmonics),
            keep: NongeometricKeep::Extended,
        }
    }

    /// The families in the set, in [`TermFamily::ALL`] order.
    pub fn families(&self) -> Vec<TermFamily> {
        TermFamily::ALL
            .into_iter()
            .filter(|f| match f {
                TermFamily::Compliance => self.compliance,
                TermFamily::Harmonics => self.harmonics,
            })
            .collect()
    }

    /// Whether no family is asked for (a geometric identification).
    pub fn is_empty(&self) -> bool {
        !self.compliance && !self.harmonics
    }
}

/// Why a compliance of a joint without a gravity lever is held at zero.
pub const NO_LEVER_REASON: &str = "no gravity torque about this joint";

/// Why an identification could not be run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// Not enough poses for the parameters to identify.
    #[error("too few poses: {poses} identification poses give {rows} equations, but {parameters} parameters need at least {needed} poses")]
    TooFewPoses {
        /// Poses given.
        poses: usize,
        /// Residual rows they give.
        rows: usize,
        /// Parameters to identify.
        parameters: usize,
        /// Minimum number of poses.
        needed: usize,
    },
    /// The poses do not excite parameters that are identifiable in general.
    #[error("rank-deficient data: the poses cannot separate {}; use more varied poses", .missing.join(", "))]
    RankDeficient {
        /// Parameter names identifiable in general but not from these poses.
        missing: Vec<String>,
    },
    /// The practical identifiability bounds are unusable (not finite, or not positive).
    #[error("identifiability bounds: {0}")]
    BadBounds(String),
    /// The base registration failed.
    #[error("base registration failed: {0}")]
    Registration(String),
    /// Robust refit rejected so many poses that too few remain.
    #[error("robust fit rejected {rejected} of {poses} poses; too few remain")]
    TooManyOutliers {
        /// Rejected poses.
        rejected: usize,
        /// All poses.
        poses: usize,
    },
}

/// Which base the "before" accuracy (the nominal model) is measured with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BeforeBase {
    /// The cell's base registration (the setup's, or the data's setup header): the base the
    /// cell uses with the nominal model, and the one the campaign's live deviation uses.
    SetupRegistration,
    /// A rigid fit of the nominal model to the identification poses (the base is identified
    /// and no registration was given).
    FittedToPoses,
    /// The robot model's own base (data in the robot's frame).
    RobotModel,
}

impl BeforeBase {
    /// The base of the "before" of an identification with these options.
    pub fn of(opts: &IdentifyOptions) -> BeforeBase {
        match (opts.registered_base, opts.identify_base) {
            (true, _) => BeforeBase::SetupRegistration,
            (false, true) => BeforeBase::FittedToPoses,
            (false, false) => BeforeBase::RobotModel,
        }
    }

    /// Contract name: `setup_registration`, `fitted_to_poses`, `robot_model`.
    pub fn name(self) -> &'static str {
        match self {
            BeforeBase::SetupRegistration => "setup_registration",
            BeforeBase::FittedToPoses => "fitted_to_poses",
            BeforeBase::RobotModel => "robot_model",
        }
    }

    /// For people: "the setup's base registration", ….
    pub fn describe(self) -> &'static str {
        match self {
            BeforeBase::SetupRegistration => "the setup's base registration",
            BeforeBase::FittedToPoses => "a base fitted to the identification poses",
            BeforeBase::RobotModel => "the robot model's own base",
        }
    }
}

/// One parameter's estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// The parameter.
    pub param: ParamId,
    /// Value before identification (mm or rad).
    pub nominal: f64,
    /// Identified − nominal (mm or rad).
    pub error: f64,
    /// Standard deviation of the error (mm or rad); `None` when not identified.
    pub std: Option<f64>,
    /// Whether it was identified.
    pub identified: bool,
}

/// Result of an identification.
#[derive(Debug, Clone)]
pub struct Identification {
    /// Options used.
    pub options: IdentifyOptions,
    /// Starting model (nominal, with the registered base when the base is identified).
    pub initial: RobotModel,
    /// The model of the "before" accuracy: the nominal model with the given tool and the base
    /// [`before_base`](Self::before_base) names.
    pub before: RobotModel,
    /// Which base `before` has.
    pub before_base: BeforeBase,
    /// Identified model.
    pub corrected: RobotModel,
    /// Identifiability analysis.
    pub identifiability: Identifiability,
    /// Identified robot parameters relative to the setup: the held setup quantities
    /// ([`setup_quantities`]) would take them over if they were free, so their values and σ
    /// hold given the setup ([`identifiability::setup_relative`]); candidate order.
    pub setup_relative: Vec<Dropped>,
    /// Every candidate parameter, identified or not.
    pub estimates: Vec<Estimate>,
    /// Correlation matrix of the identified parameters (order of `identifiability.identified`).
    pub correlation: DMatrix<f64>,
    /// A-posteriori standard deviation of unit weight (mm).
    pub sigma0_mm: f64,
    /// Solver iterations (of the final fit).
    pub iterations: usize,
    /// Solver termination.
    pub termination: solver::Termination,
    /// Final cost `½Σr²` (mm²).
    pub final_cost: f64,
    /// Indices (into the given poses) rejected by the robust fit.
    pub rejected: Vec<usize>,
}

/// Joint configurations spread over the joint limits (wrist away from singular), fixed seed.
pub fn generic_poses(model: &RobotModel, n: usize) -> Vec<Vec<f64>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x05EE_DCA1);
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let q: Vec<f64> = model
            .limits
            .iter()
            .map(|l| rng.random_range(l.min..=l.max))
            .collect();
        if model.dof() >= 5 && q[4].abs() < 10f64.to_radians() {
            continue;
        }
        out.push(q);
    }
    out
}

/// Key of the structural analysis: every input bit that can change its result.
fn structural_key(nominal: &RobotModel, obs: &ObsConfig, candidates: &[ParamId]) -> Vec<u64> {
    let mut k: Vec<u64> = Vec::with_capacity(8 * nominal.dof() + 32);
    for (j, l) in nominal.joints.iter().zip(&nominal.limits) {
        k.extend([j.theta, j.d, j.a, j.alpha, j.beta, l.min, l.max].map(f64::to_bits));
    }
    k.extend(nominal.base_rotation.iter().map(|v| v.to_bits()));
    k.extend(nominal.base_translation.iter().map(|v| v.to_bits()));
    k.extend(nominal.tool.iter().map(|v| v.to_bits()));
    k.extend(obs.stage_axis.iter().map(|v| v.to_bits()));
    k.push(obs.model.rows() as u64 * 10 + u64::from(obs.model == ObsModel::Op));
    k.push(candidates.len() as u64);
    k
}

/// The parameters identifiable in general (on 32 generic poses) for this model and
/// observation. Memoised per process: the result depends only on the key's inputs, so the
/// cache changes no output, it only spares a repeated service call ~0.2 ms.
pub fn structural_set(
    nominal: &RobotModel,
    obs: &ObsConfig,
    candidates: &[ParamId],
) -> Identifiability {
    use std::sync::{Mutex, OnceLock};
    type Memo = Mutex<Vec<(Vec<u64>, Identifiability)>>;
    static CACHE: OnceLock<Memo> = OnceLock::new();
    let key = structural_key(nominal, obs, candidates);
    let cache = CACHE.get_or_init(|| Mutex::new(Vec::new()));
    if let Ok(c) = cache.lock() {
        if let Some((_, v)) = c.iter().find(|(k, _)| *k == key) {
            return v.clone();
        }
    }
    let generic: Vec<Measured> = generic_poses(nominal, 32)
        .into_iter()
        .map(Measured::joints_only)
        .collect();
    let result = identifiability::analyze(nominal, &generic, obs, candidates);
    if let Ok(mut c) = cache.lock() {
        if c.len() >= 32 {
            c.remove(0);
        }
        c.push((key, result.clone()));
    }
    result
}

/// Starting model: the given one, with the base from a rigid registration when identified,
/// and, when a compliance is to be identified, its torque chain kept (the gravity torques stay
/// those of the given chain while its geometry is identified, §10).
pub fn initial_model(
    nominal: &RobotModel,
    poses: &[Measured],
    opts: &IdentifyOptions,
) -> Result<RobotModel, IdentifyError> {
    let mut m = nominal.clone();
    if opts.nongeometric.compliance {
        m.torque_chain = Some(nominal.torque_joints().to_vec());
    }
    if opts.identify_base {
        let a: Vec<Vector3<f64>> = poses
            .iter()
            .map(|p| {
                forward(nominal, &p.q)
                    .flange()
                    .transform_point(&nominal.tool)
            })
            .collect();
        let b: Vec<Vector3<f64>> = poses.iter().map(|p| p.p1).collect();
        let base = fit_rigid(&a, &b).map_err(|e| IdentifyError::Registration(e.to_string()))?;
        m.set_base(base);
    }
    Ok(m)
}

/// The practical bounds of `opts`, with the noise of a unit-weight row: with tracker weights,
/// the model's σ at 1 m (the weights scale every row to it), else `opts.practical.noise_mm`.
fn practical_bounds(opts: &IdentifyOptions) -> PracticalBounds {
    match &opts.point_weights {
        None => opts.practical,
        Some(t) => PracticalBounds {
            noise_mm: unit_weight_sigma_mm(t),
            ..opts.practical
        },
    }
}

/// σ (mm) of a unit-weight row under tracker weights: the model's σ at 1 m range.
fn unit_weight_sigma_mm(t: &TrackerNoise) -> f64 {
    (t.a_um + t.b_um_per_m) / 1000.0 / t.k
}

/// The setup quantities an identification with `opts` holds, as the columns the setup-relative
/// analysis frees: the tool unless identified, the stage axis' two turns when the model reads
/// the stage direction (NP, OP), the base when it is a held registration.
pub fn setup_quantities(opts: &IdentifyOptions) -> Vec<ParamId> {
    let mut v = Vec::new();
    if opts.registered_base && !opts.identify_base {
        v.extend((0..3).map(ParamId::BaseTranslation));
        v.extend((0..3).map(ParamId::BaseRotation));
    }
    if !opts.identify_tool {
        v.extend((0..3).map(ParamId::Tool));
    }
    if matches!(opts.obs.model, ObsModel::Np | ObsModel::Op) {
        // the two flange axes least along the stage axis: rotations about them span every
        // turn of it (a rotation about the third would barely move it)
        let u = opts.obs.stage_axis;
        let along = (0..3).max_by(|a, b| u[*a].abs().total_cmp(&u[*b].abs()));
        v.extend((0..3).filter(|i| Some(*i) != along).map(ParamId::StageAxis));
    }
    v
}

/// Why a parameter is setup-relative, from the setup analysis' `reason` for dropping it with
/// the `held` quantities free.
fn setup_relative_reason(held: &[ParamId], reason: &str) -> String {
    let mut what: Vec<&str> = Vec::new();
    for (p, name) in [
        (ParamId::BaseTranslation(0), "registered base"),
        (ParamId::Tool(0), "tool"),
        (ParamId::StageAxis(0), "stage axis"),
    ] {
        if held.contains(&p) {
            what.push(name);
        }
    }
    let reason = match reason.strip_prefix("combination of") {
        Some(rest) => format!("a combination of{rest}"),
        None => reason.to_owned(),
    };
    let what = match what.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
        _ => what.join(""),
    };
    format!(
        "relative to the setup's {what}: were they free, it would be {reason}; its value and σ \
         hold given the setup"
    )
}

/// The non-geometric candidates of `families` for `nominal` (joint by joint), and apart the
/// compliances of joints without a gravity lever ([`gravity_levers`]): no torque, no column.
pub fn term_candidates(
    nominal: &RobotModel,
    families: &Nongeometric,
) -> (Vec<ParamId>, Vec<ParamId>) {
    let all = params::term_params(nominal.dof(), &families.families());
    if !families.compliance {
        return (all, Vec::new());
    }
    let levers = gravity_levers(nominal);
    all.into_iter().partition(|p| match p {
        ParamId::Term {
            joint,
            kind: TermKind::Compliance,
        } => levers.get(*joint).copied().unwrap_or(false),
        _ => true,
    })
}

/// A non-geometric term is held at zero when its estimate lies within this many standard
/// deviations of zero: on data without the effect every term would otherwise fit noise.
pub const TERM_SIGNIFICANCE_SIGMAS: f64 = 3.0;

/// How far (in their own σ) holding terms at zero may move the other estimates: a term that is
/// small only because a correlated one took its part stays (its part would bias the other).
pub const TERM_HOLD_MAX_SHIFT_SIGMAS: f64 = 1.0;

/// The identified terms of `fit` to hold at zero: within [`TERM_SIGNIFICANCE_SIGMAS`] σ of their
/// initial value (σ from the fit's own σ0), taken from the least significant on while holding
/// them all moves no other estimate by more than [`TERM_HOLD_MAX_SHIFT_SIGMAS`] of its σ (the
/// conditional mean given the held ones at zero) — as held-back parameters with their reason.
fn insignificant_terms(
    initial: &RobotModel,
    fit: &solver::Solution<RobotModel>,
    params: &[ParamId],
    used: usize,
    opts: &IdentifyOptions,
) -> Vec<Dropped> {
    if !params.iter().any(ParamId::is_term) {
        return Vec::new();
    }
    let sigma0_sq = unit_variance(fit.final_cost, used, opts.obs.model, params.len());
    let Covariance { std, correlation } = covariance(fit.normal_matrix.clone(), sigma0_sq);
    // estimates in their own σ: the correlation matrix is their covariance
    let z: Vec<f64> = params
        .iter()
        .zip(&std)
        .map(|(p, s)| (p.value(&fit.state) - p.value(initial)) / s)
        .collect();
    if z.iter().any(|v| !v.is_finite()) {
        return Vec::new();
    }
    let mut candidates: Vec<usize> = (0..params.len())
        .filter(|&i| params[i].is_term() && z[i].abs() < TERM_SIGNIFICANCE_SIGMAS)
        .collect();
    candidates.sort_by(|&a, &b| z[a].abs().total_cmp(&z[b].abs()));
    let shift_ok = |held: &[usize]| {
        let h = held.len();
        let r_hh = DMatrix::from_fn(h, h, |a, b| correlation[(held[a], held[b])]);
        let z_h = DVector::from_fn(h, |a, _| z[held[a]]);
        let Some(w) = r_hh.cholesky().map(|c| c.solve(&z_h)) else {
            return false;
        };
        // together: the cost they would add (in σ0²) is a χ² of h degrees of freedom
        let joint = z_h.dot(&w);
        joint <= chi_square_bound(h, TERM_SIGNIFICANCE_SIGMAS)
            && (0..params.len()).filter(|k| !held.contains(k)).all(|k| {
                let shift: f64 = (0..h).map(|a| correlation[(k, held[a])] * w[a]).sum();
                shift.abs() <= TERM_HOLD_MAX_SHIFT_SIGMAS
            })
    };
    let mut held: Vec<usize> = Vec::new();
    for i in candidates {
        held.push(i);
        if !shift_ok(&held) {
            held.pop();
        }
    }
    held.sort_unstable();
    held.into_iter()
        .map(|i| Dropped {
            param: params[i],
            reason: format!(
                "not significant: its estimate is {:.1} σ from zero (below \
                 {TERM_SIGNIFICANCE_SIGMAS} σ); held at zero",
                z[i].abs()
            ),
            kind: DropKind::NotSignificant,
            predicted_sigma: Some(std[i]),
        })
        .collect()
}

/// `fit` with parameters `held` set back to their initial values and the others moved to the
/// optimum given that, by one Gauss–Newton step on `fit`'s normal equations (the fit converged,
/// so the step is the constrained optimum to second order in the small terms); its normal
/// matrix is the kept parameters' block and its cost the fit's plus what the same quadratic
/// model adds (no pass over the data). `None` when that block is not positive definite.
fn hold_at_initial(
    fit: &solver::Solution<RobotModel>,
    params: &[ParamId],
    held: &[ParamId],
    initial: &RobotModel,
) -> Option<solver::Solution<RobotModel>> {
    let (h, k): (Vec<usize>, Vec<usize>) =
        (0..params.len()).partition(|&i| held.contains(&params[i]));
    let n = &fit.normal_matrix;
    let d_h = DVector::from_fn(h.len(), |a, _| {
        params[h[a]].value(initial) - params[h[a]].value(&fit.state)
    });
    let n_kk = DMatrix::from_fn(k.len(), k.len(), |a, b| n[(k[a], k[b])]);
    let n_kh = DMatrix::from_fn(k.len(), h.len(), |a, b| n[(k[a], h[b])]);
    let d_k = -n_kk.clone().cholesky()?.solve(&(n_kh * &d_h));
    let mut step = vec![0.0; params.len()];
    h.iter().zip(d_h.iter()).for_each(|(&i, d)| step[i] = *d);
    k.iter().zip(d_k.iter()).for_each(|(&i, d)| step[i] = *d);
    let state = params::retract(&fit.state, params, &step);
    Some(solver::Solution {
        state,
        final_cost: fit.final_cost + held_cost(n, &h, &d_h, &n_kk, &d_k),
        normal_matrix: n_kk,
        ..fit.clone()
    })
}

/// The cost that moving the parameters `h` by `d_h` and the kept ones by the constrained
/// optimum `d_k` adds at a converged fit with normal matrix `n` (kept block `n_kk`), by the same
/// quadratic model: `½(d_hᵀN_hh d_h − d_kᵀN_kk d_k)` (the Schur complement's form in `d_h`, ≥ 0).
fn held_cost(
    n: &DMatrix<f64>,
    h: &[usize],
    d_h: &DVector<f64>,
    n_kk: &DMatrix<f64>,
    d_k: &DVector<f64>,
) -> f64 {
    let n_hh = DMatrix::from_fn(h.len(), h.len(), |a, b| n[(h[a], h[b])]);
    (0.5 * (d_h.dot(&(n_hh * d_h)) - d_k.dot(&(n_kk * d_k)))).max(0.0)
}

/// The χ² value of `dof` degrees of freedom exceeded with the probability of a normal deviate
/// beyond `sigmas` (one-sided), by the Wilson–Hilferty cube-root approximation (within 1 % of
/// the exact quantile from 1 degree of freedom at 3 σ).
fn chi_square_bound(dof: usize, sigmas: f64) -> f64 {
    let k = dof as f64;
    let v = 2.0 / (9.0 * k);
    k * (1.0 - v + sigmas * v.sqrt()).powi(3)
}

/// Identify the parameter errors of `nominal` from identification poses.
pub fn identify(
    nominal: &RobotModel,
    poses: &[Measured],
    opts: &IdentifyOptions,
) -> Result<Identification, IdentifyError> {
    let trig = JointTrig::of(poses);
    let trig = if opts.nongeometric.compliance {
        trig.with_torques(poses, nominal)
    } else {
        trig
    };
    identify_with(nominal, poses, &trig, opts)
}

/// [`identify`] given the poses' joint trigonometry (`trig` = [`JointTrig::of`] `poses`), which
/// the analysis and every linearisation share (and the caller's metrics may too).
pub fn identify_with(
    nominal: &RobotModel,
    poses: &[Measured],
    trig: &JointTrig,
    opts: &IdentifyOptions,
) -> Result<Identification, IdentifyError> {
    opts.practical.check().map_err(IdentifyError::BadBounds)?;
    let weighted: Vec<Measured>;
    let poses = match &opts.point_weights {
        None => poses,
        Some(t) => {
            let reference = unit_weight_sigma_mm(t);
            weighted = poses
                .iter()
                .map(|m| Measured {
                    weight: m.weight * reference / t.sigma_mm(&m.p1),
                    ..m.clone()
                })
                .collect();
            &weighted
        }
    };
    let geometric = all_params(nominal.dof(), opts.identify_base, opts.identify_tool);
    // the non-geometric terms after the geometry; a compliance without a gravity lever is
    // held at zero before the analysis (its column is zero on every pose)
    let (terms, no_lever) = term_candidates(nominal, &opts.nongeometric);
    let analysed: Vec<ParamId> = geometric.iter().chain(&terms).copied().collect();
    let candidates: Vec<ParamId> = geometric
        .iter()
        .copied()
        .chain(params::term_params(
            nominal.dof(),
            &opts.nongeometric.families(),
        ))
        .collect();
    let rows = opts.obs.model.rows();
    // generic structure first: how many parameters can this model identify at all? (the
    // geometric ones: a term these poses do not determine is held at zero, never an error)
    let structural = structural_set(nominal, &opts.obs, &geometric);
    let k = structural.identified.len();
    let needed = k.div_ceil(rows) + 1;
    if poses.len() < needed.max(3) {
        return Err(IdentifyError::TooFewPoses {
            poses: poses.len(),
            rows: poses.len() * rows,
            parameters: k,
            needed: needed.max(3),
        });
    }
    let initial = initial_model(nominal, poses, opts)?;
    // every pose's gravity torques once: no parameter of the fit changes them
    let with_torques;
    let trig = if opts.nongeometric.compliance && trig.torques_of(&initial).is_none() {
        with_torques = trig.clone().with_torques(poses, &initial);
        &with_torques
    } else {
        trig
    };
    let (mut ident, sums) = identifiability::analyze_linearized(
        &initial,
        poses,
        trig,
        &opts.obs,
        &analysed,
        Some(&practical_bounds(opts)),
    );
    ident
        .dropped
        .extend(no_lever.into_iter().map(|param| Dropped {
            param,
            reason: NO_LEVER_REASON.to_owned(),
            kind: DropKind::Structural,
            predicted_sigma: None,
        }));
    let order = |p: &ParamId| candidates.iter().position(|c| c == p);
    ident.dropped.sort_by_key(|d| order(&d.param));
    // lost structurally on these poses is an error; held back as undetermined is a result
    let missing: Vec<String> = structural
        .identified
        .iter()
        .filter(|p| ident.structurally_dropped(p))
        .map(|p| p.name())
        .collect();
    if !missing.is_empty() {
        return Err(IdentifyError::RankDeficient { missing });
    }
    let mut params = ident.identified.clone();
    let solve = |params: &[ParamId], x0: &RobotModel, start: Option<crate::lsq::Linearization>| {
        let problem = CalibProblem::with_trig(poses, trig, &opts.obs, params);
        let start = start.unwrap_or_else(|| problem.linearize(x0));
        match opts.robust {
            None => Ok((
                solver::solve_from(&problem, x0.clone(), start, &opts.solver),
                Vec::new(),
            )),
            Some(loss) => {
                robust::solve_robust(x0, start, poses, &opts.obs, params, loss, &opts.solver)
            }
        }
    };
    // the analysis linearised at the initial model already: start the solver from it
    let start = sums.linearization(&params, opts.obs.direction_weight_mm);
    let (mut fit, mut rejected) = solve(&params, &initial, start)?;
    // a term whose estimate these data cannot tell from zero is held there and the fit redone
    // from where it stood: it would only fit the noise (docs/method.md §10)
    let insignificant =
        insignificant_terms(&initial, &fit, &params, poses.len() - rejected.len(), opts);
    if !insignificant.is_empty() {
        let held: Vec<ParamId> = insignificant.iter().map(|d| d.param).collect();
        let constrained = match opts.robust {
            None => hold_at_initial(&fit, &params, &held, &initial),
            Some(_) => None,
        };
        params.retain(|p| !held.contains(p));
        ident.identified.retain(|p| !held.contains(p));
        ident.dropped.extend(insignificant);
        ident.dropped.sort_by_key(|d| order(&d.param));
        fit = match constrained {
            Some(f) => f,
            None => {
                let back: Vec<f64> = held
                    .iter()
                    .map(|p| p.value(&initial) - p.value(&fit.state))
                    .collect();
                let x0 = params::retract(&fit.state, &held, &back);
                let (f, r) = solve(&params, &x0, None)?;
                rejected = r;
                f
            }
        };
    }
    let used = poses.len() - rejected.len();
    let sigma0_sq = unit_variance(fit.final_cost, used, opts.obs.model, params.len());
    let Covariance { std, correlation } = covariance(fit.normal_matrix, sigma0_sq);
    let corrected = fit.state;
    let base_dr =
        to_rotation_vector(&(corrected.base_rotation * initial.base_rotation.transpose()));
    let held = setup_quantities(opts);
    // the terms come last in the analysis' order, so they decide nothing about the geometry:
    // left out here, the analysis runs on the geometric columns only
    let geometric_identified: Vec<ParamId> =
        params.iter().filter(|p| !p.is_term()).copied().collect();
    let setup_relative = identifiability::setup_relative(
        &corrected,
        poses,
        trig,
        &opts.obs,
        &geometric_identified,
        &held,
        Some(&practical_bounds(opts)),
    )
    .into_iter()
    .map(|d| Dropped {
        reason: setup_relative_reason(&held, &d.reason),
        ..d
    })
    .collect();
    let (before, before_base) = match BeforeBase::of(opts) {
        BeforeBase::SetupRegistration => (nominal.clone(), BeforeBase::SetupRegistration),
        b => (initial.clone(), b),
    };
    let estimates = candidates
        .iter()
        .map(|p| {
            let pos = params.iter().position(|q| q == p);
            let error = match p {
                ParamId::BaseRotation(i) => base_dr[*i],
                _ => p.value(&corrected) - p.value(&initial),
            };
            Estimate {
                param: *p,
                nominal: p.value(&initial),
                error,
                std: pos.map(|i| std[i]),
                identified: pos.is_some(),
            }
        })
        .collect();
    Ok(Identification {
        options: *opts,
        initial,
        before,
        before_base,
        corrected,
        identifiability: ident,
        setup_relative,
        estimates,
        correlation,
        sigma0_mm: sigma0_sq.sqrt(),
        iterations: fit.iterations,
        termination: fit.termination,
        final_cost: fit.final_cost,
        rejected,
    })
}
