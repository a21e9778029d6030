//! The dry run of a campaign (`cellcal predict`): a Monte Carlo over the configured tracker
//! noise and a stated spread of true parameter errors. Each trial draws a true robot (the
//! nominal model plus random MDH errors, [`ErrorSpread`]), simulates the identification poses
//! and fresh random verification poses with [`crate::simulate::simulate_at`], identifies the
//! campaign's way ([`crate::calibrate::calibrate`] with the campaign's identification options)
//! and measures the verification error against the noisy verification points, as a campaign
//! reports it, beside the noise floor (the true robot's error on the same points). Pure and
//! seeded: the same setup and seed give the same prediction, whatever the number of threads.

#[cfg(test)]
mod tests;

use nalgebra::Vector3;
use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::analysis::metrics::pose_errors;
use crate::calibrate::{calibrate, CalibrateError};
use crate::campaign::engine::identify_options;
use crate::campaign::estimate::estimate_campaign_time;
use crate::campaign::session::plan_request;
use crate::config::{CellConfig, DeviceMode};
use crate::dataset::{to_measured, Observation, PoseSet};
use crate::identify::observation::predict;
use crate::identify::{IdentifyOptions, TrackerNoise};
use crate::model::RobotModel;
use crate::plan::campaign::measurable_pool;
use crate::plan::selection::Selection;
use crate::plan::selection::{Design, NoiseModel, SelectionError};
use crate::plan::{plan_campaign, CampaignEstimate, Plan, PlanEntry, PlanError, PlanRequest};
use crate::simulate::truth::{apply_errors, random_errors_of};
use crate::simulate::{simulate_at, SimConfig};

/// Why a prediction could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PredictError {
    /// A setting is out of range (the message names it).
    #[error("{0}")]
    Invalid(String),
    /// No poses could be sampled.
    #[error("cannot sample poses: {0}")]
    Sampling(PlanError),
    /// Every trial's identification failed; the first failure.
    #[error("every trial's identification failed; the first: {0}")]
    Identify(CalibrateError),
}

from_cause!(PlanError => PredictError::Sampling);

/// The spread of the true parameter errors a trial draws: independent zero-mean Gaussians of
/// σ `length_mm` for every MDH length (d, a) and `angle_rad` for every angle (θ, α, β).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorSpread {
    /// σ of the length errors (mm).
    pub length_mm: f64,
    /// σ of the angle errors (rad).
    pub angle_rad: f64,
}

impl Default for ErrorSpread {
    /// [`crate::simulate::truth::random_errors`]' σ: 0.2 mm and 0.5 mrad (the size of the
    /// paper's Table 3 errors of the TX60, docs/method.md §7).
    fn default() -> Self {
        ErrorSpread {
            length_mm: crate::simulate::truth::RANDOM_LENGTH_SIGMA_MM,
            angle_rad: crate::simulate::truth::RANDOM_ANGLE_SIGMA_RAD,
        }
    }
}

/// What a campaign would be, as the Monte Carlo needs it.
#[derive(Debug, Clone)]
pub struct Setup {
    /// Nominal model the campaign identifies from (the configured tool).
    pub nominal: RobotModel,
    /// The campaign's identification options.
    pub opts: IdentifyOptions,
    /// Stage travel P1 → P2 (mm).
    pub stage_travel_mm: f64,
    /// The campaign's planning request: workspace box, tracker position, line of sight, tool.
    pub request: PlanRequest,
    /// Tracker noise (in the robot base frame); `None`: noise-free.
    pub tracker: Option<TrackerNoise>,
    /// Joint repeatability σ (rad), drawn per pose.
    pub joint_jitter_rad: f64,
    /// Spread of the true parameter errors.
    pub errors: ErrorSpread,
    /// Verification poses per trial (fresh random ones each trial).
    pub verify: usize,
}

/// Joint repeatability σ (rad) of a real robot's campaign: the TX60's ISO 9283 RP 0.02 mm
/// (the simulator's default).
pub const REAL_JOINT_JITTER_RAD: f64 = 1.2746e-5;

impl Setup {
    /// The setup of the campaign `cfg` describes on `nominal` (its robot file; the tool is set
    /// to `[campaign] tool_mm`): the campaign's identification options and planning request,
    /// the AT960 noise at `[tracker] position_mm` (scaled by `[sim] tracker_noise_scale` when
    /// the tracker is simulated), the joint repeatability of `[sim]` when the robot is
    /// simulated (else [`REAL_JOINT_JITTER_RAD`]), `poses − ident` verification poses and the
    /// default [`ErrorSpread`].
    pub fn of_config(cfg: &CellConfig, nominal: &RobotModel) -> Setup {
        let mut nominal = nominal.clone();
        nominal.tool = Vector3::from(cfg.campaign.tool_mm);
        let sim = |mode: DeviceMode| cfg.sim.as_ref().filter(|_| mode == DeviceMode::Sim);
        let noise_scale = sim(cfg.tracker.mode).map_or(1.0, |s| s.tracker_noise_scale);
        let tracker = (noise_scale > 0.0).then(|| {
            let mut t = TrackerNoise::at960(Vector3::from(cfg.tracker.position_mm));
            t.a_um *= noise_scale;
            t.b_um_per_m *= noise_scale;
            t
        });
        Setup {
            nominal,
            opts: identify_options(cfg),
            stage_travel_mm: cfg.stage.travel_mm,
            request: plan_request(cfg),
            tracker,
            joint_jitter_rad: sim(cfg.robot_controller.mode)
                .map_or(REAL_JOINT_JITTER_RAD, |s| s.joint_jitter_rad),
            errors: ErrorSpread::default(),
            verify: cfg.campaign.poses.saturating_sub(cfg.campaign.ident),
        }
    }
}

impl Setup {
    /// The selection's [`Design`] of this setup (the same nominal model, options and noise),
    /// its parameters those the identification keeps on `poses`.
    pub fn design(&self, poses: &[Vec<f64>]) -> Result<Design, SelectionError> {
        let tracker = self.tracker.unwrap_or(TrackerNoise {
            a_um: 0.0,
            b_um_per_m: 0.0,
            ..TrackerNoise::at960(self.request.tracker_mm)
        });
        Design::new(
            self.nominal.clone(),
            self.opts.obs,
            self.stage_travel_mm,
            NoiseModel {
                tracker,
                joint_jitter_rad: self.joint_jitter_rad,
            },
            self.opts.identify_base,
            self.opts.identify_tool,
            poses,
        )
    }
}

impl Setup {
    /// The plan of this setup's campaign with `ident` identification poses chosen by
    /// `selection` and [`Setup::verify`] random verification poses, seeded `seed`: what
    /// [`plan_campaign`] plans for the configured campaign with these counts.
    pub fn plan(&self, selection: Selection, ident: usize, seed: u64) -> Result<Plan, PlanError> {
        let req = self.plan_request(selection, ident, seed);
        plan_campaign(&self.nominal, &req)
    }

    /// The planning request of [`Setup::plan`].
    pub fn plan_request(&self, selection: Selection, ident: usize, seed: u64) -> PlanRequest {
        PlanRequest {
            ident,
            poses: ident + self.verify,
            seed,
            selection,
            ..self.request.clone()
        }
    }
}

/// The identification poses of `plan` in their rank order (pose index: an optimal plan's
/// best prefix first).
pub fn ident_poses(plan: &Plan) -> Vec<Vec<f64>> {
    let mut ident: Vec<&PlanEntry> = plan
        .poses
        .iter()
        .filter(|p| p.set == PoseSet::Ident)
        .collect();
    ident.sort_by_key(|p| p.index);
    ident.into_iter().map(|p| p.q_rad.clone()).collect()
}

/// The planned duration of `plan` (planned by `setup` as [`Setup::plan`] with `req`) on the
/// cell `cfg` configures: the time model's walk of it ([`estimate_campaign_time`]).
pub fn campaign_time(
    cfg: &CellConfig,
    setup: &Setup,
    req: &PlanRequest,
    plan: &Plan,
) -> CampaignEstimate {
    estimate_campaign_time(cfg, &setup.nominal, req, plan)
}

/// Which identification poses a trial measures.
#[derive(Debug, Clone, Copy)]
pub enum IdentPoses<'a> {
    /// `n` random poses drawn afresh in every trial (as a campaign samples them).
    Random(usize),
    /// These joints (rad) in every trial (a selected design).
    Given(&'a [Vec<f64>]),
}

impl IdentPoses<'_> {
    /// Number of identification poses.
    pub fn count(&self) -> usize {
        match self {
            IdentPoses::Random(n) => *n,
            IdentPoses::Given(qs) => qs.len(),
        }
    }
}

/// One trial's outcome.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trial {
    /// Mean position error of the identified model at the noisy verification points (mm):
    /// what the campaign's result reports as the verification error.
    pub verify_mean_mm: f64,
    /// The same of the true robot: the noise floor (mm).
    pub floor_mm: f64,
    /// Mean position error of the identified model against the true robot, noise-free (mm).
    pub model_mean_mm: f64,
    /// Standard deviation of the single verification poses' errors (mm).
    pub pose_sd_mm: f64,
}

/// The Monte Carlo's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    /// Identification poses per trial.
    pub ident: usize,
    /// Verification poses per trial.
    pub verify: usize,
    /// The trials whose identification ran, in trial order.
    pub trials: Vec<Trial>,
    /// Trials whose identification failed.
    pub failed: usize,
}

fn mean(v: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = v.clone().count().max(1);
    v.sum::<f64>() / n as f64
}

fn sd(v: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = v.clone().count();
    if n < 2 {
        return 0.0;
    }
    let m = mean(v.clone());
    (v.map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1) as f64).sqrt()
}

impl Prediction {
    /// Mean over the trials of the verification error (mm).
    pub fn mean_mm(&self) -> f64 {
        mean(self.trials.iter().map(|t| t.verify_mean_mm))
    }

    /// Standard deviation over the trials of the verification error (mm): how much one
    /// campaign's figure varies with its noise, its truth and (random poses) its poses.
    pub fn spread_mm(&self) -> f64 {
        sd(self.trials.iter().map(|t| t.verify_mean_mm))
    }

    /// Mean over the trials of the noise floor (mm).
    pub fn floor_mm(&self) -> f64 {
        mean(self.trials.iter().map(|t| t.floor_mm))
    }

    /// Mean over the trials of the noise-free model error (mm).
    pub fn model_mean_mm(&self) -> f64 {
        mean(self.trials.iter().map(|t| t.model_mean_mm))
    }

    /// Verification error over noise floor, trial by trial, averaged.
    pub fn ratio_to_floor(&self) -> f64 {
        mean(
            self.trials
                .iter()
                .map(|t| t.verify_mean_mm / t.floor_mm.max(f64::MIN_POSITIVE)),
        )
    }

    /// Standard deviation of a single verification pose's error (mm; root mean square of the
    /// trials' values).
    pub fn pose_sd_mm(&self) -> f64 {
        mean(self.trials.iter().map(|t| t.pose_sd_mm * t.pose_sd_mm)).sqrt()
    }

    /// Standard error (mm) of the mean verification error measured on `v` random
    /// verification poses of one identified model: σ_pose/√v (the poses and their noise are
    /// independent draws).
    pub fn standard_error_mm(&self, v: usize) -> f64 {
        standard_error_mm(self.pose_sd_mm(), v)
    }
}

/// σ/√v: the standard error of the mean of `v` independent values of standard deviation σ.
pub fn standard_error_mm(pose_sd_mm: f64, v: usize) -> f64 {
    pose_sd_mm / (v.max(1) as f64).sqrt()
}

/// `n` random poses a campaign could measure, drawn as [`plan_campaign`] draws them
/// ([`measurable_pool`]: in the workspace box, the ball facing the tracker, one wrist side, a
/// checked move to and from the drift reference).
pub fn random_poses(
    setup: &Setup,
    n: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<Vec<f64>>, PlanError> {
    Ok(measurable_pool(&setup.nominal, &setup.request, n, rng)?.poses)
}

/// The seed of trial `t` of a run seeded `seed`.
fn trial_seed(seed: u64, t: usize) -> u64 {
    seed ^ (t as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// A trial's true robot and the model identified from its simulated identification data.
#[derive(Debug, Clone)]
pub struct Identified {
    /// The true robot (nominal plus the drawn errors).
    pub truth: RobotModel,
    /// The identified (corrected) model.
    pub model: RobotModel,
}

/// Draw a truth from `rng` and identify it from simulated data at the poses `ident` (the
/// campaign's way: [`calibrate`] with the setup's options). The identification data is simulated
/// together with `verify` further poses (same noise stream), whose simulated rows are returned.
fn identify_trial(
    setup: &Setup,
    ident: IdentPoses,
    verify: usize,
    rng: &mut ChaCha8Rng,
) -> Result<(Identified, Vec<Observation>), PredictError> {
    let errors = random_errors_of(
        setup.nominal.dof(),
        rng.next_u64(),
        setup.errors.length_mm,
        setup.errors.angle_rad,
    );
    let truth = apply_errors(&setup.nominal, &errors).map_err(PredictError::Invalid)?;
    let sim_seed = rng.next_u64();
    let mut qs = match ident {
        IdentPoses::Random(n) => random_poses(setup, n, rng)?,
        IdentPoses::Given(qs) => qs.to_vec(),
    };
    qs.extend(random_poses(setup, verify, rng)?);
    let data = simulate_at(&truth, &sim_config(setup, ident.count(), sim_seed), &qs);
    let (_, id) = calibrate(
        &setup.nominal,
        &data.observations,
        &setup.opts,
        setup.stage_travel_mm,
    )
    .map_err(PredictError::Identify)?;
    let verify_rows = data
        .observations
        .into_iter()
        .filter(|o| o.set == PoseSet::Verify)
        .collect();
    Ok((
        Identified {
            truth,
            model: id.corrected,
        },
        verify_rows,
    ))
}

/// The simulator's settings for a setup: `ident` identification poses, noise seeded `seed`.
fn sim_config(setup: &Setup, ident: usize, seed: u64) -> SimConfig {
    SimConfig {
        ident,
        seed,
        tracker: setup.tracker,
        joint_jitter_rad: setup.joint_jitter_rad,
        stage_travel_mm: setup.stage_travel_mm,
        stage_axis: setup.opts.obs.stage_axis,
        ..SimConfig::default()
    }
}

/// Draw a truth from a seed and identify it from `ident` (see [`monte_carlo`]); for checks of a
/// single identified model (e.g. [`verification_errors`] on many verification sets).
pub fn identify_once(
    setup: &Setup,
    ident: IdentPoses,
    seed: u64,
) -> Result<Identified, PredictError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    identify_trial(setup, ident, 0, &mut rng).map(|(id, _)| id)
}

/// Position errors (mm) of `id.model` at `v` fresh random verification poses measured with the
/// setup's noise (seeded `seed`), and of the truth at the same points (the noise floor).
pub fn verification_errors(
    setup: &Setup,
    id: &Identified,
    v: usize,
    seed: u64,
) -> Result<(Vec<f64>, Vec<f64>), PredictError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let qs = random_poses(setup, v, &mut rng)?;
    let data = simulate_at(&id.truth, &sim_config(setup, 0, rng.next_u64()), &qs);
    errors_at(setup, id, &data.observations)
}

/// Position errors (mm) of `id.model` and of `id.truth` at the simulated rows `rows`.
fn errors_at(
    setup: &Setup,
    id: &Identified,
    rows: &[Observation],
) -> Result<(Vec<f64>, Vec<f64>), PredictError> {
    let verify = to_measured(rows, setup.opts.obs.model, setup.stage_travel_mm)
        .map_err(|e| PredictError::Identify(e.into()))?;
    let norms = |m: &RobotModel| -> Vec<f64> {
        pose_errors(m, &verify, &setup.opts.obs)
            .iter()
            .map(|(e, _)| e.norm())
            .collect()
    };
    Ok((norms(&id.model), norms(&id.truth)))
}

/// One trial: truth, data, identification, verification.
fn trial(setup: &Setup, ident: IdentPoses, seed: u64) -> Result<Trial, PredictError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (id, rows) = identify_trial(setup, ident, setup.verify, &mut rng)?;
    let (after, floor) = errors_at(setup, &id, &rows)?;
    let model_mean_mm = mean(rows.iter().map(|o| {
        let p = |r: &RobotModel| -> Vector3<f64> { predict(r, &o.q).p };
        (p(&id.model) - p(&id.truth)).norm()
    }));
    Ok(Trial {
        verify_mean_mm: mean(after.iter().copied()),
        floor_mm: mean(floor.iter().copied()),
        model_mean_mm,
        pose_sd_mm: sd(after.iter().copied()),
    })
}

/// Run `trials` trials of identification poses `ident` seeded by `seed`, on up to `threads`
/// threads (the outcome does not depend on it). Each trial draws its own truth, noise and
/// verification poses (and, for [`IdentPoses::Random`], identification poses); a trial whose
/// identification fails is counted in [`Prediction::failed`].
pub fn monte_carlo(
    setup: &Setup,
    ident: IdentPoses,
    trials: usize,
    seed: u64,
    threads: usize,
) -> Result<Prediction, PredictError> {
    if trials == 0 {
        return Err(PredictError::Invalid("trials must be at least 1".into()));
    }
    if ident.count() == 0 {
        return Err(PredictError::Invalid(
            "at least one identification pose is needed".into(),
        ));
    }
    if setup.verify == 0 {
        return Err(PredictError::Invalid(
            "at least one verification pose is needed".into(),
        ));
    }
    let threads = threads.clamp(1, trials);
    let mut outcomes: Vec<Option<Result<Trial, PredictError>>> = vec![None; trials];
    std::thread::scope(|s| {
        for (k, chunk) in outcomes.chunks_mut(trials.div_ceil(threads)).enumerate() {
            let first = k * trials.div_ceil(threads);
            s.spawn(move || {
                for (i, slot) in chunk.iter_mut().enumerate() {
                    *slot = Some(trial(setup, ident, trial_seed(seed, first + i)));
                }
            });
        }
    });
    let mut out = Prediction {
        ident: ident.count(),
        verify: setup.verify,
        trials: Vec::with_capacity(trials),
        failed: 0,
    };
    let mut first_error = None;
    for o in outcomes.into_iter().flatten() {
        match o {
            Ok(t) => out.trials.push(t),
            Err(PredictError::Identify(e)) => {
                out.failed += 1;
                first_error.get_or_insert(e);
            }
            Err(e) => return Err(e),
        }
    }
    match first_error {
        Some(e) if out.trials.is_empty() => Err(PredictError::Identify(e)),
        _ => Ok(out),
    }
}
