//! The stop rule of `campaign.stop_when = "predicted"`: a campaign that stops measuring
//! identification poses when it has enough.
//!
//! After each block of `stop_block` measured identification poses the engine identifies on
//! what is stored (the campaign's own recipe, [`super::identification_input`]), predicts the
//! mean verification error of that identification at the plan's verification poses
//! ([`predicted_verification`] of `plan::selection`: the identification's parameter covariance
//! carried to the ball at each verification pose, plus the tracker's noise there), and stops measuring
//! identification poses once a block improves that prediction by less than `stop_min_gain`
//! ([`decide`]) or it is at or below `target_verify_mm`. The remaining identification poses
//! are skipped, never measured; the verification poses are always measured in full; the final
//! identification uses the measured identification poses only, as always. Every check is
//! stored ([`crate::store::Store::add_ident_check`]) before the robot moves again, so a resume
//! keeps a stop (and its history) and ends the campaign without the skipped poses.
//!
//! The identification runs between robot moves, on a blocking thread: the robot stands at its
//! last pose, nothing moves, and an abort or a disarm ends the wait at once.

use nalgebra::{DMatrix, Vector3};

use super::{identification_input, Run, Stop};
use crate::calibrate::{calibrate, IdentCheck, IdentStop, StopReason};
use crate::campaign::events::CampaignEvent;
use crate::config::{CellConfig, StopWhen};
use crate::dataset::PoseSet;
use crate::identify::{all_params, Identification, TrackerNoise};
use crate::model::RobotModel;
use crate::plan::selection::{predicted_verification, Design, NoiseModel, PredictedError};
use crate::plan::Plan;
use crate::units::human::fmt_mm;

/// The rule: the relative gain on the `previous` prediction and why to stop, if so. Stops at
/// or below `target_mm`, or when the gain `(previous − predicted) / previous` is below
/// `min_gain` (a worse prediction included); the first check stops only at the target; a
/// prediction that is not a finite positive number never stops.
pub fn decide(
    previous: Option<f64>,
    predicted_mm: f64,
    min_gain: f64,
    target_mm: Option<f64>,
) -> (Option<f64>, Option<StopReason>) {
    if !(predicted_mm.is_finite() && predicted_mm > 0.0) {
        return (None, None);
    }
    let gain = previous
        .filter(|p| p.is_finite() && *p > 0.0)
        .map(|p| (p - predicted_mm) / p);
    let stop = if target_mm.is_some_and(|t| predicted_mm <= t) {
        Some(StopReason::Target)
    } else if gain.is_some_and(|g| g < min_gain) {
        Some(StopReason::MinGain)
    } else {
        None
    };
    (gain, stop)
}

/// The rule of a running campaign: its settings, the planned verification joints and the
/// checks made so far (stored ones included).
pub(super) struct StopRule {
    /// Identification poses per block.
    block: usize,
    min_gain: f64,
    target_mm: Option<f64>,
    /// Identification poses planned.
    ident_planned: usize,
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
        Some(StopRule {
            block: stop_block(cfg, nominal),
            min_gain: cfg.campaign.stop_min_gain,
            target_mm: cfg.campaign.target_verify_mm,
            ident_planned: of_set(PoseSet::Ident).count(),
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
            && ident_done < self.ident_planned
            && self
                .checks
                .last()
                .is_none_or(|c| c.after_poses < ident_done)
            && self.failed_at != Some(ident_done)
            && self.stopped().is_none()
    }

    /// The check of `predicted` after `after_poses` identification poses.
    fn check(&self, after_poses: usize, predicted: &PredictedError) -> IdentCheck {
        let previous = self.checks.last().map(|c| c.predicted_mm);
        let (gain, stopped) = decide(previous, predicted.mean_mm, self.min_gain, self.target_mm);
        IdentCheck {
            after_poses,
            predicted_mm: predicted.mean_mm,
            noise_floor_mm: predicted.noise_floor_mm,
            gain,
            stopped,
        }
    }

    /// The `ident_stopped` event of the check that stopped the identification poses.
    pub(super) fn stopped_event(&self) -> Option<CampaignEvent> {
        let c = self.stopped()?;
        let at = self.checks.iter().position(|x| x.stopped.is_some())?;
        Some(CampaignEvent::IdentStopped {
            after_poses: c.after_poses,
            skipped: self.ident_planned.saturating_sub(c.after_poses),
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
            ident_planned: self.ident_planned,
            predicted_mm: stop.or(self.checks.last()).map(|c| c.predicted_mm),
            stop_min_gain: self.min_gain,
            target_verify_mm: self.target_mm,
            history: self.checks.clone(),
        }
    }
}

/// The predicted verification error of identification `id` (stage travel `travel_mm`) at
/// `verify_q` ([`predicted_verification`]): its covariance over the identified parameters (σ
/// and correlations as it reports them: the a-posteriori σ of unit weight, so a cell noisier
/// than the tracker's model asks for more poses), the identified model (measurement frame, the
/// ball as its tool) as the linearisation point, and the AT960 noise model with the tracker at
/// the measurement frame's origin (the measurement frame is the tracker's). `None` when a σ is
/// not finite.
fn predicted_of(
    id: &Identification,
    travel_mm: f64,
    verify_q: &[Vec<f64>],
) -> Option<PredictedError> {
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
    let p = predicted_verification(&design, &cov, verify_q);
    (p.mean_mm.is_finite()).then_some(p)
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
        let work = tokio::task::spawn_blocking(move || {
            calibrate(&input.nominal, &input.rows, &input.opts, input.travel)
                .map(|(_, id)| predicted_of(&id, input.travel, &verify_q))
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
                    .map(|g| format!(", {:.1} % better than the last block", 100.0 * g))
                    .unwrap_or_default();
                self.journal(CampaignEvent::Note {
                    text: format!(
                        "stop rule: after {ident_done} identification poses the predicted \
                         verification error is {} mm{gain}; measuring on",
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

    #[test]
    fn the_rule_stops_on_a_small_gain_or_at_the_target_and_never_on_nonsense() {
        // first check: no gain, stops only at the target
        assert_eq!(decide(None, 0.05, 0.02, None), (None, None));
        assert_eq!(
            decide(None, 0.03, 0.02, Some(0.03)),
            (None, Some(StopReason::Target))
        );
        // a 10 % gain goes on, a 1 % gain stops, a worse prediction stops
        let (g, s) = decide(Some(0.05), 0.045, 0.02, None);
        assert!((g.unwrap() - 0.1).abs() < 1e-12 && s.is_none());
        let (g, s) = decide(Some(0.05), 0.0495, 0.02, None);
        assert!((g.unwrap() - 0.01).abs() < 1e-12);
        assert_eq!(s, Some(StopReason::MinGain));
        assert_eq!(
            decide(Some(0.05), 0.06, 0.02, None).1,
            Some(StopReason::MinGain)
        );
        // 3 % goes on
        assert_eq!(decide(Some(0.05), 0.0485, 0.02, None).1, None);
        // the target wins over the gain; min_gain 0 stops only on a worse prediction
        assert_eq!(
            decide(Some(0.05), 0.0499, 0.02, Some(0.06)).1,
            Some(StopReason::Target)
        );
        assert_eq!(decide(Some(0.05), 0.0499, 0.0, None).1, None);
        assert_eq!(decide(Some(0.05), 0.05, 0.0, None).1, None);
        assert_eq!(
            decide(Some(0.05), 0.0501, 0.0, None).1,
            Some(StopReason::MinGain)
        );
        // NaN, inf, zero: never a stop
        for p in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            assert_eq!(decide(Some(0.05), p, 0.02, Some(1.0)), (None, None));
        }
        assert_eq!(decide(Some(f64::NAN), 0.05, 0.02, None), (None, None));
    }

    fn rule(block: usize, planned: usize) -> StopRule {
        StopRule {
            block,
            min_gain: 0.02,
            target_mm: None,
            ident_planned: planned,
            verify_q: Vec::new(),
            checks: Vec::new(),
            failed_at: None,
        }
    }

    fn predicted(mm: f64) -> PredictedError {
        PredictedError {
            mean_mm: mm,
            noise_floor_mm: 0.02,
        }
    }

    #[test]
    fn checks_fall_due_after_whole_blocks_once_and_never_after_a_stop() {
        let mut r = rule(10, 35);
        let due: Vec<usize> = (0..=35).filter(|n| r.due(*n)).collect();
        assert_eq!(due, [10, 20, 30], "whole blocks, not the last pose");
        for (n, mm) in [(10, 0.05), (20, 0.04)] {
            let c = r.check(n, &predicted(mm));
            r.checks.push(c);
        }
        assert!(!r.due(20), "a count is checked once");
        assert_eq!(r.summary(20).reason, StopReason::Planned);
        let c = r.check(30, &predicted(0.0396));
        assert_eq!(c.stopped, Some(StopReason::MinGain));
        r.checks.push(c);
        assert!(r.stopped().is_some() && !r.due(40));
        let s = r.summary(30);
        assert_eq!(
            (s.reason, s.ident_measured, s.ident_planned, s.history.len()),
            (StopReason::MinGain, 30, 35, 3)
        );
        assert_eq!(s.predicted_mm, Some(0.0396));
    }
}
