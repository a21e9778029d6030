//! Accuracy metrics of a model against measurements (paper eq. 13, ISO 9283 style).
//!
//! Position error `e = P1 − p_model` (mm): axial mean/max of |e_x|, |e_y|, |e_z|, mean, max,
//! RMS and 95th percentile of ‖e‖. Attitude (rad): full model — the angle of the rotation
//! vector of `R_meas · R_modelᵀ`; NP/OP — the angle between the measured and the modelled
//! stage axis; position model — not measured (`None`).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::identify::observation::{Measured, ObsConfig, ObsModel};
use crate::identify::problem::{split_map, JointTrig};
use crate::model::kinematics::{forward_from, Frames, Pose};
use crate::model::rotation::to_rotation_vector;
use crate::model::RobotModel;

/// Accuracy of a model on a set of poses (the `M` object of the JSON contract).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Number of poses.
    pub poses: usize,
    /// Mean comprehensive position error ‖e‖ (mm).
    pub position_mean_mm: f64,
    /// Max comprehensive position error (mm).
    pub position_max_mm: f64,
    /// RMS of ‖e‖ (mm).
    pub position_rms_mm: f64,
    /// 95th percentile of ‖e‖ (mm).
    pub position_p95_mm: f64,
    /// Mean |e_x|, |e_y|, |e_z| (mm).
    pub position_axial_mean_mm: [f64; 3],
    /// Max |e_x|, |e_y|, |e_z| (mm).
    pub position_axial_max_mm: [f64; 3],
    /// Mean attitude error (rad); null where nothing measures it.
    pub attitude_mean_rad: Option<f64>,
    /// Max attitude error (rad); null where nothing measures it.
    pub attitude_max_rad: Option<f64>,
    /// RMS attitude error (rad); null where nothing measures it.
    pub attitude_rms_rad: Option<f64>,
}

/// Percentile (0..=100) of values in any order (reordered in place), by linear interpolation
/// between the two order statistics around it, found by selection rather than a sort.
fn percentile(values: &mut [f64], pct: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let x = pct / 100.0 * (values.len() - 1) as f64;
    let (lo, hi) = (x.floor() as usize, x.ceil() as usize);
    let (_, &mut at_lo, above) = values.select_nth_unstable_by(lo, f64::total_cmp);
    let at_hi = if hi > lo {
        above
            .iter()
            .copied()
            .min_by(f64::total_cmp)
            .unwrap_or(at_lo)
    } else {
        at_lo
    };
    at_lo + (at_hi - at_lo) * (x - lo as f64)
}

/// One pose's position error (mm) and attitude error (rad, where measured).
type PoseError = (Vector3<f64>, Option<f64>);

/// Position and attitude errors per pose.
pub fn pose_errors(model: &RobotModel, poses: &[Measured], cfg: &ObsConfig) -> Vec<PoseError> {
    let [parts] = errors_of([model], poses, None, cfg);
    parts.concat()
}

/// [`pose_errors`] of `N` models on the same poses: each pose's joint sines and cosines once
/// for all models (from `trig`, the poses' [`JointTrig`], when given), each model's chain in
/// the measurement frame into reused frames (no allocation per pose, the twists' sines once
/// per model), over two fixed halves of the poses on two threads ([`split_map`]), so the
/// errors are the same bit for bit on any machine. Per model, the errors of each half in
/// order (not joined: the metrics read them where they are).
fn errors_of<const N: usize>(
    models: [&RobotModel; N],
    poses: &[Measured],
    trig: Option<&JointTrig>,
    cfg: &ObsConfig,
) -> [Vec<Vec<PoseError>>; N] {
    let bases = models.map(|m| Pose {
        r: m.base_rotation,
        p: m.base_translation,
    });
    let parts = split_map(poses.len(), |range| {
        let mut frames: [Frames; N] = std::array::from_fn(|_| Frames::new());
        let mut out: [Vec<_>; N] = std::array::from_fn(|_| Vec::with_capacity(range.len()));
        let mut own = Vec::new();
        for i in range {
            let m = &poses[i];
            let q_trig = match trig {
                Some(t) => t.pose(i),
                None => {
                    own.clear();
                    own.extend(m.q.iter().map(|q| q.sin_cos()));
                    &own
                }
            };
            for k in 0..N {
                let f = &mut frames[k];
                if models[k].has_terms() {
                    let angles = models[k].link_angles(&m.q);
                    forward_from(&bases[k], &models[k].joints, &angles, None, f);
                } else {
                    forward_from(&bases[k], &models[k].joints, &m.q, Some(q_trig), f);
                }
                let fl = f.flange();
                let e = m.p1 - fl.transform_point(&models[k].tool);
                out[k].push((e, attitude(m, &fl.r, cfg)));
            }
        }
        out
    });
    let mut per_model: [Vec<Vec<PoseError>>; N] = std::array::from_fn(|_| Vec::new());
    for part in parts {
        for (k, errors) in part.into_iter().enumerate() {
            per_model[k].push(errors);
        }
    }
    per_model
}

/// The attitude error of one pose given the modelled flange rotation `r` (measurement frame).
fn attitude(m: &Measured, r: &Matrix3<f64>, cfg: &ObsConfig) -> Option<f64> {
    match cfg.model {
        ObsModel::Position => None,
        ObsModel::Np | ObsModel::Op => m.direction.map(|d| {
            let l = r * cfg.stage_axis;
            d.cross(&l).norm().atan2(d.dot(&l))
        }),
        ObsModel::Full => m
            .rotation
            .as_deref()
            .map(|meas| to_rotation_vector(&(meas * r.transpose())).norm()),
    }
}

/// Metrics of `model` on `poses`.
pub fn evaluate(model: &RobotModel, poses: &[Measured], cfg: &ObsConfig) -> Metrics {
    let [parts] = errors_of([model], poses, None, cfg);
    summarize(&parts)
}

/// Metrics of two models on the same poses (as [`evaluate`] gives each) in one pass: the
/// joints' sines and cosines once for both, or none given `trig` ([`JointTrig::of`] the poses).
pub fn evaluate_pair(
    a: &RobotModel,
    b: &RobotModel,
    poses: &[Measured],
    trig: Option<&JointTrig>,
    cfg: &ObsConfig,
) -> (Metrics, Metrics) {
    assert!(
        trig.is_none_or(|t| t.covers(poses.len())),
        "a joint table of other poses"
    );
    let [ea, eb] = errors_of([a, b], poses, trig, cfg);
    (summarize(&ea), summarize(&eb))
}

/// The metrics of per-pose position and attitude errors, given in consecutive parts.
fn summarize(parts: &[Vec<PoseError>]) -> Metrics {
    let errs = || parts.iter().flatten();
    let count = parts.iter().map(Vec::len).sum::<usize>();
    let n = count.max(1) as f64;
    let mut norms: Vec<f64> = Vec::with_capacity(count);
    norms.extend(errs().map(|(e, _)| e.norm()));
    let mut axial_mean = [0.0; 3];
    let mut axial_max = [0.0f64; 3];
    for (e, _) in errs() {
        for k in 0..3 {
            axial_mean[k] += e[k].abs() / n;
            axial_max[k] = axial_max[k].max(e[k].abs());
        }
    }
    let atts: Vec<f64> = errs().filter_map(|(_, a)| *a).collect();
    let has_att = !atts.is_empty() && atts.len() == count;
    let mean = norms.iter().sum::<f64>() / n;
    let rms = (norms.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    Metrics {
        poses: count,
        position_mean_mm: mean,
        position_max_mm: norms.iter().copied().fold(0.0, f64::max),
        position_rms_mm: rms,
        position_p95_mm: percentile(&mut norms, 95.0),
        position_axial_mean_mm: axial_mean,
        position_axial_max_mm: axial_max,
        attitude_mean_rad: has_att.then(|| atts.iter().sum::<f64>() / atts.len() as f64),
        attitude_max_rad: has_att.then(|| atts.iter().copied().fold(0.0, f64::max)),
        attitude_rms_rad: has_att
            .then(|| (atts.iter().map(|a| a * a).sum::<f64>() / atts.len() as f64).sqrt()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The percentile of sorted values, interpolated as [`percentile`] does.
    fn of_sorted(sorted: &[f64], pct: f64) -> f64 {
        let x = pct / 100.0 * (sorted.len() - 1) as f64;
        let (lo, hi) = (x.floor() as usize, x.ceil() as usize);
        sorted[lo] + (sorted[hi] - sorted[lo]) * (x - lo as f64)
    }

    #[test]
    fn percentile_by_selection_is_percentile_of_the_sorted() {
        let mut state = 12345u64;
        for n in [1, 2, 3, 7, 20, 101, 1000] {
            let v: Vec<f64> = (0..n)
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (state >> 11) as f64 / (1u64 << 53) as f64
                })
                .collect();
            let mut sorted = v.clone();
            sorted.sort_by(f64::total_cmp);
            for pct in [0.0, 50.0, 95.0, 99.9, 100.0] {
                let mut work = v.clone();
                let got = percentile(&mut work, pct);
                assert_eq!(
                    got.to_bits(),
                    of_sorted(&sorted, pct).to_bits(),
                    "{n} {pct}"
                );
            }
        }
        assert!(percentile(&mut [], 95.0).is_nan());
    }

    #[test]
    fn percentile_interpolates() {
        let v = [5.0, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(percentile(&mut v.clone(), 50.0), 3.0);
        assert_eq!(percentile(&mut v.clone(), 100.0), 5.0);
        assert!((percentile(&mut v.clone(), 95.0) - 4.8).abs() < 1e-12);
    }
}
