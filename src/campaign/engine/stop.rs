//! The stop rule of `campaign.stop_when = "predicted"`: a campaign that stops measuring
//! identification poses when it has enough.
//!
//! After each block of `stop_block` measured identification poses the engine identifies on
//! what is stored (the campaign's own recipe, [`super::identification_input`]) and predicts,
//! from that one identification ([`predict_check`]), the mean verification error at the plan's
//! verification poses ([`predicted_verification_biased`] of `plan::selection`: the parameter
//! covariance carried to the ball at each verification pose, plus the readings' noise there)
//! with the poses measured, without the last block, and with every planned identification pose.
//! It stops measuring identification poses ([`decide`]) once the prediction is at or below
//! `target_verify_mm`, the last block bought less than `stop_min_gain`, or the poses still
//! planned would buy less than `stop_remaining_gain`. A parameter the identification holds
//! back (practical test) but the whole plan identifies is in the predictions with its prior
//! error ([`crate::plan::selection::prior_error`]: the paper's Table 3), less what the
//! identified parameters absorb on the poses measured ([`held_back_bias`]): a hold-back that
//! costs accuracy is a gain the poses still planned would buy, one the others absorb is not
//! (the rule before measured on while any was held back). Comparing
//! predictions of one identification keeps the fit's own noise out of the gains: comparing each
//! check with the previous one (the rule before) followed the a-posteriori σ of two fits and
//! stopped after 45 to 75 poses of the same design. The remaining identification poses
//! are skipped, never measured; the verification poses are always measured in full; the final
//! identification uses the measured identification poses only, as always. Every check is
//! stored ([`crate::store::Store::add_ident_check`]) before the robot moves again, so a resume
//! keeps a stop (and its history) and ends the campaign without the skipped poses.
//!
//! The identification runs between robot moves, on a blocking thread: the robot stands at its
//! last pose, nothing moves, and an abort or a disarm ends the wait at once.

use std::collections::BTreeSet;

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::{identification_input, Run, Stop};
use crate::calibrate::{calibrate, IdentCheck, IdentStop, StopReason};
use crate::campaign::events::CampaignEvent;
use crate::config::{CellConfig, StopWhen};
use crate::dataset::PoseSet;
use crate::identify::identifiability::DropKind;
use crate::identify::ParamId;
use crate::identify::{all_params, Identification, TrackerNoise};
use crate::model::RobotModel;
use crate::plan::selection::{
    held_back_bias, predicted_verification_biased, Design, NoiseModel, PredictedError,
};
use crate::plan::Plan;
use crate::units::human::fmt_mm;

/// What one check's identification predicts (mm): the mean verification error with the
/// identification poses measured, and, from the same identification (its parameter
/// covariance's scale and linearisation point), without the last block and with every planned
/// identification pose measured. Comparing predictions of one identification, not of two, keeps
/// the fit's own noise (its a-posteriori σ of unit weight) out of the gains.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckPrediction {
    /// With the identification poses measured: mean and noise floor.
    pub now: PredictedError,
    /// Without the last block (`None`: no block before it, or too few poses to identify).
    pub before_block_mm: Option<f64>,
    /// With every planned identification pose.
    pub all_mm: f64,
    /// Parameters the whole plan identifies that this identification holds back (public
    /// names): each is in `now` and `before_block_mm` with its prior error, less what the
    /// identified parameters absorb ([`held_back_bias`]), and identified in `all_mm`.
    pub held_back: Vec<String>,
}

impl CheckPrediction {
    /// `(before − now) / before`: what the last block bought.
    pub fn block_gain(&self) -> Option<f64> {
        self.before_block_mm
            .filter(|b| b.is_finite() && *b > 0.0)
            .map(|b| (b - self.now.mean_mm) / b)
    }

    /// `(now − all) / now`: what the identification poses still planned would buy.
    pub fn remaining_gain(&self) -> Option<f64> {
        (self.all_mm.is_finite() && self.all_mm > 0.0 && self.now.mean_mm > 0.0)
            .then(|| (self.now.mean_mm - self.all_mm) / self.now.mean_mm)
    }
}

/// The rule's thresholds (`campaign.stop_min_gain`, `stop_remaining_gain`,
/// `target_verify_mm`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    /// Least gain of a block to go on.
    pub min_gain: f64,
    /// Least gain of the poses still planned to go on.
    pub remaining_gain: f64,
    /// Stop at or below this prediction (mm).
    pub target_mm: Option<f64>,
}

/// The rule: why to stop, if so. Stops at or below the target, else when the last block
/// gained less than `min_gain` (a worse prediction included), else when the poses still planned
/// would gain less than `remaining_gain`; a prediction that is not a finite positive number
/// never stops, and a gain not known (the first check has no block before it) never stops.
pub fn decide(
    predicted_mm: f64,
    block_gain: Option<f64>,
    remaining_gain: Option<f64>,
    t: &Thresholds,
) -> Option<StopReason> {
    if !(predicted_mm.is_finite() && predicted_mm > 0.0) {
        return None;
    }
    let below = |g: Option<f64>, min: f64| g.is_some_and(|g| g.is_finite() && g < min);
    if t.target_mm.is_some_and(|t| predicted_mm <= t) {
        Some(StopReason::Target)
    } else if below(block_gain, t.min_gain) {
        Some(StopReason::MinGain)
    } else if below(remaining_gain, t.remaining_gain) {
        Some(StopReason::RemainingGain)
    } else {
        None
    }
}

/// The rule of a running campaign: its settings, the planned identification and verification
/// joints and the checks made so far (stored ones included).
pub(super) struct StopRule {
    /// Identification poses per block.
    block: usize,
    thresholds: Thresholds,
    /// The planned identification poses: index and joints (rad), by index (rank order).
    ident: Vec<(usize, Vec<f64>)>,
    /// Joints of the planned verification poses (rad).
    verify_q: Vec<Vec<f64>>,
    /// The checks so far, by increasing pose count.
    checks: Vec<IdentCheck>,
    /// A count at which the identification failed (not checked again at that count).
    failed_at: Option<usize>,
}

/// Identification poses per block for this campaign ([`crate::config::CampaignSection::stop_block_for`]
/// with the candidate parameters of `nominal`'s joints and the identified frames).
pub fn stop_block(cfg: &CellConfig, nominal: &RobotModel) -> usize {
    let c = &cfg.campaign;
    let candidates = all_params(nominal.dof(), c.identify_base, c.identify_tool).len();
    c.stop_block_for(candidates)
}

impl StopRule {
    /// The rule of a calibration campaign with `stop_when = "predicted"` (`None` otherwise),
    /// with the `checks` already stored.
    pub(super) fn of(
        cfg: &CellConfig,
        nominal: &RobotModel,
        plan: &Plan,
        iso: bool,
        checks: Vec<IdentCheck>,
    ) -> Option<StopRule> {
        if iso || cfg.campaign.stop_when != StopWhen::Predicted {
            return None;
        }
        let of_set = |set: PoseSet| plan.poses.iter().filter(move |p| p.set == set);
        let mut ident: Vec<(usize, Vec<f64>)> = of_set(PoseSet::Ident)
            .map(|p| (p.index, p.q_rad.clone()))
            .collect();
        ident.sort_by_key(|(i, _)| *i);
        let c = &cfg.campaign;
        Some(StopRule {
            block: stop_block(cfg, nominal),
            thresholds: Thresholds {
                min_gain: c.stop_min_gain,
                remaining_gain: c.stop_remaining_gain,
                target_mm: c.target_verify_mm,
            },
            ident,
            verify_q: of_set(PoseSet::Verify).map(|p| p.q_rad.clone()).collect(),
            checks,
            failed_at: None,
        })
    }

    /// The check that stopped the identification poses, if one did.
    pub(super) fn stopped(&self) -> Option<&IdentCheck> {
        self.checks.iter().find(|c| c.stopped.is_some())
    }

    /// Whether a check is due with `ident_done` identification poses measured: a whole number
    /// of blocks, some planned ones left, not checked (or failed) at that count, not stopped.
    fn due(&self, ident_done: usize) -> bool {
        ident_done > 0
            && ident_done.is_multiple_of(self.block)
            && ident_done < self.ident.len()
            && self
                .checks
                .last()
                .is_none_or(|c| c.after_poses < ident_done)
            && self.failed_at != Some(ident_done)
            && self.stopped().is_none()
    }

    /// The check of `predicted` after `after_poses` identification poses.
    fn check(&self, after_poses: usize, predicted: &CheckPrediction) -> IdentCheck {
        let (gain, remaining_gain) = (predicted.block_gain(), predicted.remaining_gain());
        let stopped = decide(
            predicted.now.mean_mm,
            gain,
            remaining_gain,
            &self.thresholds,
        );
        IdentCheck {
            after_poses,
            predicted_mm: predicted.now.mean_mm,
            noise_floor_mm: predicted.now.noise_floor_mm,
            gain,
            stopped,
            predicted_all_mm: Some(predicted.all_mm),
            remaining_gain,
            held_back: predicted.held_back.clone(),
        }
    }

    /// The joints of the identification poses measured (`measured`: their indices), by index,
    /// and of those still planned.
    fn split_ident(&self, measured: &BTreeSet<usize>) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let (done, rest): (Vec<_>, Vec<_>) =
            self.ident.iter().partition(|(i, _)| measured.contains(i));
        let q = |v: Vec<&(usize, Vec<f64>)>| v.into_iter().map(|(_, q)| q.clone()).collect();
        (q(done), q(rest))
    }

    /// The `ident_stopped` event of the check that stopped the identification poses.
    pub(super) fn stopped_event(&self) -> Option<CampaignEvent> {
        let c = self.stopped()?;
        let at = self.checks.iter().position(|x| x.stopped.is_some())?;
        Some(CampaignEvent::IdentStopped {
            after_poses: c.after_poses,
            skipped: self.ident.len().saturating_sub(c.after_poses),
            reason: c.stopped?,
            predicted_mm: c.predicted_mm,
            history: self.checks[..=at].to_vec(),
        })
    }

    /// The result's `ident_stop` with `ident_measured` identification poses measured.
    pub(super) fn summary(&self, ident_measured: usize) -> IdentStop {
        let stop = self.stopped();
        IdentStop {
            reason: stop.and_then(|c| c.stopped).unwrap_or(StopReason::Planned),
            ident_measured,
            ident_planned: self.ident.len(),
            predicted_mm: stop.or(self.checks.last()).map(|c| c.predicted_mm),
            stop_min_gain: self.thresholds.min_gain,
            stop_remaining_gain: Some(self.thresholds.remaining_gain),
            target_verify_mm: self.thresholds.target_mm,
            history: self.checks.clone(),
        }
    }
}

/// What identification `id` (stage travel `travel_mm`) predicts at `verify_q`
/// ([`predicted_verification_biased`]; [`CheckPrediction`]): its covariance over the identified
/// parameters (σ and correlations as it reports them: the a-posteriori σ of unit weight, so a
/// cell noisier than the tracker's model asks for more poses), the identified model
/// (measurement frame, the ball as its tool) as the linearisation point, and the AT960 noise
/// model with the tracker at the measurement frame's origin (the measurement frame is the
/// tracker's). `measured_q`: the identification poses it used, by index (blocks of `block`, the
/// last one last); `rest_q`: those still planned. The predictions without the last block and
/// with every planned pose are the design's, its tracker noise scaled by the identification's
/// own: so that the design's covariance of `measured_q` has the identification's parameter part
/// at `verify_q`, the verification readings as noisy (the gains do not depend on that scale,
/// nor on the fit's noisy estimate of it); they are given as ratios to `now`. The parameters it
/// held back (practical test) that the whole plan identifies are in `now` and the prediction
/// without the last block with their prior error less what the identified ones absorb
/// ([`held_back_bias`]), and identified in the prediction with every planned pose (the whole
/// plan's parameter set). `None` when a σ is not finite or the prediction is not a number.
pub fn predict_check(
    id: &Identification,
    travel_mm: f64,
    verify_q: &[Vec<f64>],
    measured_q: &[Vec<f64>],
    block: usize,
    rest_q: &[Vec<f64>],
) -> Option<CheckPrediction> {
    let params = id.identifiability.identified.clone();
    let std: Vec<f64> = params
        .iter()
        .map(|p| {
            id.estimates
                .iter()
                .find(|e| e.param == *p)
                .and_then(|e| e.std)
                .unwrap_or(f64::NAN)
        })
        .collect();
    if std.iter().any(|s| !s.is_finite()) || id.correlation.nrows() != params.len() {
        return None;
    }
    let k = params.len();
    let cov = DMatrix::from_fn(k, k, |i, j| id.correlation[(i, j)] * std[i] * std[j]);
    let design = Design {
        model: id.corrected.clone(),
        obs: id.options.obs,
        stage_travel_mm: travel_mm,
        noise: NoiseModel {
            tracker: TrackerNoise::at960(Vector3::zeros()),
            joint_jitter_rad: 0.0,
        },
        params,
    };
    let all: Vec<Vec<f64>> = measured_q.iter().chain(rest_q).cloned().collect();
    // what the whole plan identifies (the structural and practical test of the campaign's
    // identification, at this identification's model), and the parameters this identification
    // held back by the practical test that the whole plan would identify: their errors stay
    // in this model, less what the identified parameters absorb
    let whole = Design::new(
        id.corrected.clone(),
        id.options.obs,
        travel_mm,
        design.noise,
        id.options.identify_base,
        id.options.identify_tool,
        &all,
    )
    .ok();
    let held: Vec<ParamId> = whole
        .as_ref()
        .map(|whole| {
            id.identifiability
                .dropped
                .iter()
                .filter(|d| d.kind != DropKind::Structural && whole.params.contains(&d.param))
                .map(|d| d.param)
                .collect()
        })
        .unwrap_or_default();
    let bias = |set: &[Vec<f64>]| -> Option<Option<Vec<Matrix3<f64>>>> {
        if held.is_empty() {
            Some(None)
        } else {
            held_back_bias(&design, &held, set, verify_q).map(Some)
        }
    };
    let bias_now = bias(measured_q)?;
    let now = predicted_verification_biased(&design, &cov, verify_q, bias_now.as_deref());
    if !now.mean_mm.is_finite() {
        return None;
    }
    // κ: the identification's parameter part at the verification poses over the design's for
    // the same poses (≈ its a-posteriori σ² over the tracker model's); the readings are as
    // much noisier as the fit saw, so the gains are the design's with the noise scaled by √κ
    let jv: Vec<DMatrix<f64>> = verify_q
        .iter()
        .map(|q| design.position_jacobian(q))
        .collect();
    let part =
        |c: &DMatrix<f64>| -> f64 { jv.iter().map(|j| (j * c * j.transpose()).trace()).sum() };
    let kappa = design
        .covariance(measured_q)
        .map(|c| part(&cov) / part(&c))
        .filter(|s| s.is_finite() && *s > 0.0);
    let scale = |mut d: Design| {
        if let Some(k) = kappa {
            d.noise.tracker.k /= k.sqrt();
        }
        d
    };
    let scaled = scale(design.clone());
    let predict = |d: &Design, set: &[Vec<f64>], bias: Option<&[Matrix3<f64>]>| -> Option<f64> {
        let c = d.covariance(set)?;
        Some(predicted_verification_biased(d, &c, verify_q, bias).mean_mm).filter(|m| m.is_finite())
    };
    let now_scaled = predict(&scaled, measured_q, bias_now.as_deref()).filter(|_| kappa.is_some());
    let before_block_mm = measured_q
        .len()
        .checked_sub(block)
        .filter(|n| *n > 0)
        .and_then(|n| {
            let set = &measured_q[..n];
            predict(&scaled, set, bias(set)?.as_deref())
        });
    let all_mm = match whole {
        // the whole plan identifies the held-back parameters: none left at nominal
        Some(whole) if !held.is_empty() => predict(&scale(whole), &all, None),
        _ if rest_q.is_empty() => now_scaled,
        _ => predict(&scaled, &all, None),
    };
    let held_back = held.iter().map(|p| p.name()).collect();
    // in the reported prediction's terms: the same ratios to it
    let to_now = |x: Option<f64>| now_scaled.zip(x).map(|(n, x)| now.mean_mm * x / n);
    Some(CheckPrediction {
        now,
        before_block_mm: to_now(before_block_mm),
        all_mm: to_now(all_mm).unwrap_or(f64::NAN),
        held_back,
    })
}

impl Run<'_> {
    /// Before an identification pose: run the stop rule's check when one is due with
    /// `ident_done` identification poses measured; `true` when the identification poses are
    /// stopped (the pose is skipped). A check is stored before this returns; a stop is
    /// journalled (`ident_stopped`). An identification that fails is journalled as a note and
    /// the campaign measures on. Not cancel-safe: one step of the run, ended by the abort token
    /// or a disarm (the identification is waited for [`super::guarded`]-like), never by
    /// dropping it.
    pub(super) async fn ident_stopped(
        &mut self,
        rule: &mut StopRule,
        ident_done: usize,
    ) -> Result<bool, Stop> {
        if rule.stopped().is_some() {
            return Ok(true);
        }
        if !rule.due(ident_done) {
            return Ok(false);
        }
        let input = identification_input(self.ctx).await?;
        let verify_q = rule.verify_q.clone();
        let measured: BTreeSet<usize> = input
            .rows
            .iter()
            .filter(|o| o.set == PoseSet::Ident)
            .filter_map(|o| o.id.parse().ok())
            .collect();
        let (measured_q, rest_q) = rule.split_ident(&measured);
        let block = rule.block;
        let work = tokio::task::spawn_blocking(move || {
            calibrate(&input.nominal, &input.rows, &input.opts, input.travel).map(|(_, id)| {
                predict_check(&id, input.travel, &verify_q, &measured_q, block, &rest_q)
            })
        });
        // the robot stands; an abort or a disarm ends the wait at once (the thread's result
        // is dropped)
        let control = &self.ctx.control;
        let mut armed = control.armed.subscribe();
        let r = tokio::select! {
            biased;
            _ = control.abort.cancelled() => return Err(Stop::Aborted),
            _ = armed.wait_for(|a| !*a) => return Err(Stop::Disarmed),
            r = work => r.map_err(|e| super::CampaignError::Task(e.to_string()))?,
        };
        let predicted = match r {
            Ok(Some(p)) => p,
            Ok(None) | Err(_) => {
                rule.failed_at = Some(ident_done);
                let why = match r {
                    Err(e) => e.to_string(),
                    _ => "a parameter's σ is not finite".to_owned(),
                };
                self.journal(CampaignEvent::Note {
                    text: format!(
                        "stop rule: no identification after {ident_done} identification poses \
                         ({why}); measuring on"
                    ),
                })
                .await?;
                return Ok(false);
            }
        };
        let check = rule.check(ident_done, &predicted);
        let id = self.ctx.campaign_id;
        let stored = check.clone();
        // durable before the robot moves again: a resume keeps the decision
        self.store(move |s| s.add_ident_check(id, ident_done, &stored))
            .await?;
        rule.checks.push(check.clone());
        match rule.stopped_event() {
            Some(event) => {
                self.journal(event).await?;
                Ok(true)
            }
            None => {
                let gain = check
                    .gain
                    .map(|g| format!(", {:.1} % better than without the last block", 100.0 * g))
                    .unwrap_or_default();
                let rest = check
                    .remaining_gain
                    .map(|g| format!(", the poses still planned would gain {:.1} %", 100.0 * g))
                    .unwrap_or_default();
                let held = if check.held_back.is_empty() {
                    String::new()
                } else {
                    format!(
                        ", {} held back (priced at their error before calibration; the whole \
                         plan identifies them)",
                        check.held_back.join(", ")
                    )
                };
                self.journal(CampaignEvent::Note {
                    text: format!(
                        "stop rule: after {ident_done} identification poses the predicted \
                         verification error is {} mm{gain}{rest}{held}; measuring on",
                        fmt_mm(check.predicted_mm)
                    ),
                })
                .await?;
                Ok(false)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(min_gain: f64, remaining_gain: f64, target_mm: Option<f64>) -> Thresholds {
        Thresholds {
            min_gain,
            remaining_gain,
            target_mm,
        }
    }

    #[test]
    fn the_rule_stops_on_a_small_gain_or_at_the_target_and_never_on_nonsense() {
        let d = t(0.02, 0.05, None);
        // first check: no block gain; a large remaining gain goes on, a small one stops
        assert_eq!(decide(0.05, None, Some(0.10), &d), None);
        assert_eq!(decide(0.05, None, None, &d), None);
        assert_eq!(
            decide(0.05, None, Some(0.049), &d),
            Some(StopReason::RemainingGain)
        );
        assert_eq!(
            decide(0.03, None, Some(0.5), &t(0.02, 0.05, Some(0.03))),
            Some(StopReason::Target)
        );
        // a 10 % block goes on, a 1 % block stops, a worse prediction stops
        assert_eq!(decide(0.05, Some(0.10), Some(0.2), &d), None);
        assert_eq!(
            decide(0.05, Some(0.01), Some(0.2), &d),
            Some(StopReason::MinGain)
        );
        assert_eq!(
            decide(0.05, Some(-0.01), Some(0.2), &d),
            Some(StopReason::MinGain)
        );
        // the block's reason wins over the remaining one, the target over both
        assert_eq!(
            decide(0.05, Some(0.01), Some(0.01), &d),
            Some(StopReason::MinGain)
        );
        assert_eq!(
            decide(0.05, Some(0.01), Some(0.01), &t(0.02, 0.05, Some(0.06))),
            Some(StopReason::Target)
        );
        // 0 turns a gain rule off but for a worse prediction
        let off = t(0.0, 0.0, None);
        assert_eq!(decide(0.05, Some(0.0), Some(0.0), &off), None);
        assert_eq!(
            decide(0.05, Some(-0.001), Some(0.0), &off),
            Some(StopReason::MinGain)
        );
        // NaN, inf, zero: never a stop
        for p in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            assert_eq!(
                decide(p, Some(0.0), Some(0.0), &t(0.02, 0.05, Some(1.0))),
                None
            );
        }
        assert_eq!(decide(0.05, Some(f64::NAN), Some(f64::NAN), &d), None);
    }

    fn rule(block: usize, planned: usize) -> StopRule {
        StopRule {
            block,
            thresholds: t(0.02, 0.05, None),
            ident: (0..planned).map(|i| (i, vec![0.0; 6])).collect(),
            verify_q: Vec::new(),
            checks: Vec::new(),
            failed_at: None,
        }
    }

    fn predicted(mm: f64, before: Option<f64>, all: f64) -> CheckPrediction {
        CheckPrediction {
            now: PredictedError {
                mean_mm: mm,
                noise_floor_mm: 0.02,
            },
            before_block_mm: before,
            all_mm: all,
            held_back: Vec::new(),
        }
    }

    #[test]
    fn checks_fall_due_after_whole_blocks_once_and_never_after_a_stop() {
        let mut r = rule(10, 35);
        let due: Vec<usize> = (0..=35).filter(|n| r.due(*n)).collect();
        assert_eq!(due, [10, 20, 30], "whole blocks, not the last pose");
        for (n, mm, before) in [(10, 0.05, None), (20, 0.04, Some(0.045))] {
            let c = r.check(n, &predicted(mm, before, 0.03));
            assert_eq!(c.stopped, None);
            r.checks.push(c);
        }
        assert!(!r.due(20), "a count is checked once");
        assert_eq!(r.summary(20).reason, StopReason::Planned);
        // the last block bought 1 %
        let c = r.check(30, &predicted(0.0396, Some(0.04), 0.03));
        assert_eq!(c.stopped, Some(StopReason::MinGain));
        assert!((c.gain.unwrap() - 0.01).abs() < 1e-12);
        assert!((c.remaining_gain.unwrap() - (1.0 - 0.03 / 0.0396)).abs() < 1e-12);
        assert_eq!(c.predicted_all_mm, Some(0.03));
        r.checks.push(c);
        assert!(r.stopped().is_some() && !r.due(40));
        let s = r.summary(30);
        assert_eq!(
            (s.reason, s.ident_measured, s.ident_planned, s.history.len()),
            (StopReason::MinGain, 30, 35, 3)
        );
        assert_eq!(s.predicted_mm, Some(0.0396));
        assert_eq!(s.stop_remaining_gain, Some(0.05));
    }

    #[test]
    fn the_poses_still_planned_stop_the_rule_when_they_would_buy_too_little() {
        let mut r = rule(10, 100);
        // each block still buys 3 %, but the 60 poses left would buy only 4 %
        let c = r.check(40, &predicted(0.0260, Some(0.0268), 0.0250));
        assert_eq!(c.stopped, Some(StopReason::RemainingGain));
        r.checks.push(c);
        let s = r.summary(40);
        assert_eq!(
            (s.reason, s.ident_measured),
            (StopReason::RemainingGain, 40)
        );
        let Some(CampaignEvent::IdentStopped {
            after_poses,
            skipped,
            reason,
            ..
        }) = r.stopped_event()
        else {
            panic!("an ident_stopped event");
        };
        assert_eq!(
            (after_poses, skipped, reason),
            (40, 60, StopReason::RemainingGain)
        );
    }

    /// A held-back parameter is in the predictions (its prior error, less what the others
    /// absorb): the rule decides on them as on any check, and the check names it.
    #[test]
    fn a_parameter_held_back_is_decided_on_by_the_predictions_that_price_it() {
        let r = rule(10, 100);
        // what it leaves is small: the last block and the poses still planned buy little
        let mut p = predicted(0.0260, Some(0.0268), 0.0250);
        p.held_back = vec!["d5".into(), "a5".into()];
        let c = r.check(40, &p);
        assert_eq!(c.stopped, Some(StopReason::RemainingGain));
        assert_eq!(c.held_back, ["d5", "a5"]);
        // what it leaves is large: the poses still planned, which identify it, buy 20 %
        p.all_mm = 0.0208;
        assert_eq!(r.check(40, &p).stopped, None);
        // the target stops it too
        let mut r = rule(10, 100);
        r.thresholds.target_mm = Some(0.03);
        assert_eq!(r.check(40, &p).stopped, Some(StopReason::Target));
    }

    #[test]
    fn the_split_follows_the_measured_indices_in_rank_order() {
        let mut r = rule(2, 5);
        for (i, p) in r.ident.iter_mut() {
            p[0] = *i as f64;
        }
        let (done, rest) = r.split_ident(&BTreeSet::from([3, 0]));
        let first = |v: Vec<Vec<f64>>| v.iter().map(|q| q[0]).collect::<Vec<_>>();
        assert_eq!(first(done), [0.0, 3.0]);
        assert_eq!(first(rest), [1.0, 2.0, 4.0]);
    }
}
