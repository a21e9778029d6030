//! The data simulator: a true robot (nominal + errors, base and tool transforms) measured by a
//! noisy laser tracker through a 1D stage. Pure and seeded (ChaCha8): same inputs and seed,
//! same data, bit for bit.
//!
//! Per pose: joint jitter (robot repeatability; P1 and P2 of one pose share it) → true flange
//! pose → P1 = ball + tracker noise; P2 = ball + travel·R·u_actual (+ stage cross-talk and
//! repeatability) + tracker noise; the full-pose rotation is measured as two stage directions
//! (flange x and y) projected onto SO(3). Tracker noise is isotropic Gaussian with
//! σ = (a + b·range)/k (AT960: a = 15 µm, b = 6 µm/m, k = 2: the MPE read as 2σ). A fraction of
//! poses can be made gross outliers (P1 and P2 displaced together).

#[cfg(test)]
mod tests;
pub mod truth;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::dataset::{Observation, PoseSet};
use crate::model::kinematics::forward;
use crate::model::rotation::{from_rotation_vector, project_so3};
use crate::model::RobotModel;
use crate::plan::{sample_poses, PlanError, Workspace};

pub use crate::identify::TrackerNoise;
pub use truth::{paper_errors, random_errors, ErrorTable};

/// Everything that defines a simulated data set apart from the robots.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Total poses.
    pub poses: usize,
    /// Of which for identification (the first ones).
    pub ident: usize,
    /// RNG seed.
    pub seed: u64,
    /// Sampling region.
    pub workspace: Workspace,
    /// Tracker noise; `None` for noise-free data.
    pub tracker: Option<TrackerNoise>,
    /// Joint jitter σ (rad) (1.2746e-5 rad ≈ ISO 9283 RP 0.02 mm for the TX60).
    pub joint_jitter_rad: f64,
    /// Stage travel (mm).
    pub stage_travel_mm: f64,
    /// Nominal stage axis in the flange frame (unit).
    pub stage_axis: Vector3<f64>,
    /// Misalignment of the real stage axis (rotation vector, rad).
    pub stage_misalignment_rad: Vector3<f64>,
    /// Systematic cross-travel deviation (mm per mm of travel) perpendicular to the axis.
    pub stage_cross_mm_per_mm: f64,
    /// Stage positioning repeatability σ (mm) along the axis.
    pub stage_repeatability_mm: f64,
    /// Fraction of poses that are gross outliers.
    pub outlier_fraction: f64,
    /// Size of a gross outlier (mm).
    pub outlier_mm: f64,
}

impl Default for SimConfig {
    /// docs/method.md §7: 300 poses (100 ident), seed 4802, paper cube, AT960 at (2550, 0, 0) mm.
    fn default() -> Self {
        SimConfig {
            poses: 300,
            ident: 100,
            seed: 4802,
            workspace: Workspace::default(),
            tracker: Some(TrackerNoise::at960(Vector3::new(2550.0, 0.0, 0.0))),
            joint_jitter_rad: 1.2746e-5,
            stage_travel_mm: 10.0,
            stage_axis: Vector3::y(),
            stage_misalignment_rad: Vector3::zeros(),
            stage_cross_mm_per_mm: 0.0,
            stage_repeatability_mm: 0.0,
            outlier_fraction: 0.0,
            outlier_mm: 1.0,
        }
    }
}

/// A simulated data set.
#[derive(Debug, Clone)]
pub struct SimData {
    /// Observations (identification poses first).
    pub observations: Vec<Observation>,
    /// Indices of gross-outlier poses.
    pub outliers: Vec<usize>,
}

fn gauss3<R: Rng>(rng: &mut R) -> Vector3<f64> {
    Vector3::new(
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
    )
}

/// Simulate measurements of `truth` at poses planned on `nominal`.
pub fn simulate(
    nominal: &RobotModel,
    truth: &RobotModel,
    cfg: &SimConfig,
) -> Result<SimData, PlanError> {
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let qs = sample_poses(nominal, &cfg.workspace, cfg.poses, &mut rng)?;
    Ok(simulate_at(truth, cfg, &qs))
}

/// [`simulate`] at the given joints `qs` (rad; the first `cfg.ident` identify) instead of
/// sampled ones: `cfg.poses` and `cfg.workspace` are not used, every noise draw is seeded by
/// `cfg.seed` as in [`simulate`] (which is this at its sampled joints).
pub fn simulate_at(truth: &RobotModel, cfg: &SimConfig, qs: &[Vec<f64>]) -> SimData {
    let poses = qs.len();
    let mut noise_rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x9E37_79B9_7F4A_7C15);
    let n_out = (cfg.outlier_fraction * poses as f64).round() as usize;
    // deterministic, spread-out outlier choice
    let mut outliers: Vec<usize> = Vec::new();
    while outliers.len() < n_out.min(poses) {
        let i = noise_rng.random_range(0..poses);
        if !outliers.contains(&i) {
            outliers.push(i);
        }
    }
    outliers.sort_unstable();
    let u = cfg.stage_axis.normalize();
    let u_act = from_rotation_vector(&cfg.stage_misalignment_rad) * u;
    let cross_dir = {
        let v = Vector3::z().cross(&u);
        if v.norm() > 1e-9 {
            v.normalize()
        } else {
            Vector3::x()
        }
    };
    let measure = |p: Vector3<f64>, rng: &mut ChaCha8Rng| match &cfg.tracker {
        Some(t) => p + gauss3(rng) * t.sigma_mm(&p),
        None => p,
    };
    let mut observations = Vec::with_capacity(poses);
    for (i, q) in qs.iter().enumerate() {
        let qa: Vec<f64> = q
            .iter()
            .map(|v| {
                v + cfg.joint_jitter_rad * {
                    let z: f64 = StandardNormal.sample(&mut noise_rng);
                    z
                }
            })
            .collect();
        let fl = *forward(truth, &qa).flange();
        let r = truth.base_rotation * fl.r;
        let ball = truth.base_rotation * fl.transform_point(&truth.tool) + truth.base_translation;
        let stage = |axis: Vector3<f64>, cross: Vector3<f64>, rng: &mut ChaCha8Rng| {
            let travel = cfg.stage_travel_mm
                + cfg.stage_repeatability_mm * {
                    let z: f64 = StandardNormal.sample(rng);
                    z
                };
            r * (axis * travel + cross * cfg.stage_cross_mm_per_mm * cfg.stage_travel_mm)
        };
        let is_out = outliers.binary_search(&i).is_ok();
        let gross = if is_out {
            gauss3(&mut noise_rng).normalize() * cfg.outlier_mm
        } else {
            Vector3::zeros()
        };
        let p1 = measure(ball, &mut noise_rng) + gross;
        let p2 = measure(
            ball + stage(u_act, cross_dir, &mut noise_rng),
            &mut noise_rng,
        ) + gross;
        // full pose: two directions (flange x and y) measured the same way
        let px = measure(
            ball + r * Vector3::x() * cfg.stage_travel_mm,
            &mut noise_rng,
        );
        let py = measure(
            ball + r * Vector3::y() * cfg.stage_travel_mm,
            &mut noise_rng,
        );
        let p1b = measure(ball, &mut noise_rng);
        let lx = (px - p1b).normalize();
        let ly = (py - p1b).normalize();
        let rot = project_so3(&nalgebra::Matrix3::from_columns(&[lx, ly, lx.cross(&ly)]));
        observations.push(Observation {
            line: 0,
            id: i.to_string(),
            set: if i < cfg.ident {
                PoseSet::Ident
            } else {
                PoseSet::Verify
            },
            q: q.clone(),
            p1,
            p2: Some(p2),
            rotation: Some(Box::new(rot)),
        });
    }
    SimData {
        observations,
        outliers,
    }
}
