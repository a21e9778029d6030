//! Progress lines of a campaign run, made from its journalled events: one per measured pose
//! (pose n of N and its set, elapsed, estimated time left from the pace measured so far, the
//! last deviation, faults so far) and one per state change, fault, drift check, stop, note and
//! technician question. `cellcal run --progress lines` prints them on stderr after `progress: `;
//! `cellcal serve` logs them after `campaign ID progress: `. The times are the journal's
//! (`at_ms`), so a line says what the journal says and this module reads no clock.
//!
//! The pose line (a contract: see `docs/cli.md`):
//! `pose 12/300 ident · elapsed 4 min 10 s · left ~1 h 05 min · last 0.021 mm · faults 0`.

use std::collections::HashMap;
use std::time::Duration;

use crate::calibrate::StopReason;
use crate::campaign::events::fault_kind_name;
use crate::campaign::{CampaignContext, CampaignEvent, CampaignState, Journalled};
use crate::dataset::PoseSet;
use crate::plan::Plan;
use crate::units::human::{fmt_duration, fmt_mm};

/// The progress formatter of one run: it counts what the run's events say (poses measured in
/// this run, faults, time spent measuring) and writes each event's line. Feed it every event of
/// the run, in journal order, once.
#[derive(Debug, Clone, Default)]
pub struct Progress {
    /// The set of each planned pose index.
    sets: HashMap<usize, PoseSet>,
    /// When the run first started measuring (`running`), ms since the epoch.
    started_ms: Option<i64>,
    /// Time spent running (not paused, not waiting to start) before `running_since`.
    active_ms: i64,
    /// Since when the run is running, while it is.
    running_since: Option<i64>,
    /// A pause was seen since the last `running` (the next one is a resume).
    paused: bool,
    /// Poses measured in this run.
    measured: usize,
    /// The pace's starting point: (active time, poses measured in this run) then.
    anchor: (i64, usize),
    /// Device faults so far in this run.
    faults: usize,
}

impl Progress {
    /// The formatter of a run of `plan` (the identification or verification set of each pose).
    pub fn new(plan: &Plan) -> Progress {
        Progress {
            sets: plan.poses.iter().map(|p| (p.index, p.set)).collect(),
            ..Progress::default()
        }
    }

    /// The formatter of a campaign's run: its plan's sets, none for an ISO 9283 campaign
    /// (whose poses are cycles, not identification or verification poses).
    pub fn for_campaign(ctx: &CampaignContext) -> Progress {
        match ctx.iso {
            Some(_) => Progress::default(),
            None => Progress::new(&ctx.plan),
        }
    }

    /// Device faults counted so far.
    pub fn faults(&self) -> usize {
        self.faults
    }

    /// Take the event `e` into the counts; its line (without prefix), or `None` for an event
    /// that has none (the result, whose `done` follows; a journal row of unknown kind).
    pub fn line(&mut self, e: &Journalled) -> Option<String> {
        let t = e.at_ms;
        let text = match &e.event {
            CampaignEvent::Measured {
                pose,
                done,
                total,
                deviation_mm,
                ..
            } => self.pose_line(t, *pose, *done, *total, *deviation_mm),
            CampaignEvent::State { state } => {
                let name = self.state_change(t, state);
                match state.reason() {
                    Some(reason) => format!("state {name}: {reason}{}", self.tail(t)),
                    None => format!("state {name}{}", self.tail(t)),
                }
            }
            CampaignEvent::Setup { result } => {
                if self.measured == 0 {
                    // the pace starts after the setup: it is measured once
                    self.anchor = (self.active_at(t), 0);
                }
                let parts: Vec<String> = [
                    result.tool_frame.as_ref().map(|f| {
                        format!("tool frame (sphere fit RMS {} mm)", fmt_mm(f.sphere_rms_mm))
                    }),
                    result.base.as_ref().map(|b| {
                        format!(
                            "base registration (RMS {} mm over {} poses)",
                            fmt_mm(b.rms_mm),
                            b.poses
                        )
                    }),
                ]
                .into_iter()
                .flatten()
                .collect();
                let what = if parts.is_empty() {
                    "nothing to measure".to_owned()
                } else {
                    parts.join(", ")
                };
                format!("setup measured: {what}{}", self.tail(t))
            }
            CampaignEvent::Fault {
                device,
                kind,
                message,
                action,
            } => {
                self.faults += 1;
                format!(
                    "fault {} {} ({action}): {message}{}",
                    device.name(),
                    fault_kind_name(*kind),
                    self.tail(t)
                )
            }
            CampaignEvent::Drift { drift_mm, max_mm } => format!(
                "drift {} mm (max {} mm){}",
                fmt_mm(*drift_mm),
                fmt_mm(*max_mm),
                self.tail(t)
            ),
            CampaignEvent::Stopped {
                reason,
                robot,
                stage,
            } => format!("stopped ({reason}): robot {robot}; stage {stage}"),
            CampaignEvent::IdentStopped {
                after_poses,
                skipped,
                reason,
                predicted_mm,
                history,
            } => {
                let last = history.last();
                let why = match (reason, last.and_then(|c| c.gain)) {
                    (StopReason::Target, _) => "at the target".to_owned(),
                    (StopReason::RemainingGain, _) => match last.and_then(|c| c.remaining_gain) {
                        Some(g) => format!("the poses still planned would gain {:.1} %", 100.0 * g),
                        None => reason.as_str().to_owned(),
                    },
                    (_, Some(g)) => format!("the last block gained {:.1} %", 100.0 * g),
                    (_, None) => reason.as_str().to_owned(),
                };
                format!(
                    "identification poses stopped after {after_poses}, {skipped} skipped: predicted \
                     verification error {} mm, {why}",
                    fmt_mm(*predicted_mm)
                )
            }
            CampaignEvent::Note { text } => format!("note: {text}"),
            CampaignEvent::Devices {
                tracker,
                robot,
                stage,
            } => {
                let said = |s: &Option<String>| {
                    s.clone()
                        .filter(|s| !s.is_empty())
                        .unwrap_or_else(|| "(cannot say)".to_owned())
                };
                format!(
                    "devices: tracker {}; robot {}; stage {}",
                    said(tracker),
                    said(robot),
                    said(stage)
                )
            }
            CampaignEvent::Prompt { id, text, .. } => {
                format!("waiting for the technician ({id}): {text}")
            }
            CampaignEvent::Result { .. } | CampaignEvent::Other(_) => return None,
        };
        Some(text)
    }

    /// Count a measured pose; its line.
    fn pose_line(
        &mut self,
        t: i64,
        pose: usize,
        done: usize,
        total: usize,
        deviation_mm: Option<f64>,
    ) -> String {
        self.measured += 1;
        let active = self.active_at(t);
        let (at, before) = self.anchor;
        let left = if done >= total {
            "left 0 s".to_owned()
        } else {
            let pace_ms = (active - at).max(0) as f64 / (self.measured - before).max(1) as f64;
            let left_ms = pace_ms * (total - done) as f64;
            format!(
                "left ~{}",
                fmt_duration(Duration::from_millis(left_ms as u64))
            )
        };
        if self.measured == 1 {
            // from the second pose on, the pace is that of poses alone
            self.anchor = (active, 1);
        }
        let set = match self.sets.get(&pose) {
            Some(s) => format!(" {}", s.as_str()),
            None => String::new(),
        };
        let last = match deviation_mm {
            Some(d) if d.is_finite() => format!("{} mm", fmt_mm(d)),
            _ => "n/a".to_owned(),
        };
        format!(
            "pose {done}/{total}{set} · elapsed {} · {left} · last {last} · faults {}",
            fmt_duration(self.elapsed(t)),
            self.faults
        )
    }

    /// Follow a state change at `t` on the clocks; its name in the line (`resumed` for a
    /// `running` after a pause).
    fn state_change(&mut self, t: i64, state: &CampaignState) -> &'static str {
        match state {
            CampaignState::Running => {
                self.started_ms.get_or_insert(t);
                if self.running_since.is_none() {
                    self.running_since = Some(t);
                }
                if std::mem::take(&mut self.paused) {
                    return "resumed";
                }
            }
            _ => {
                if let Some(since) = self.running_since.take() {
                    self.active_ms += (t - since).max(0);
                }
                if matches!(state, CampaignState::Paused { .. }) {
                    self.paused = true;
                }
            }
        }
        state.name()
    }

    /// Time spent running up to `t` (ms).
    fn active_at(&self, t: i64) -> i64 {
        self.active_ms + self.running_since.map_or(0, |s| (t - s).max(0))
    }

    /// Wall time since the run started measuring.
    fn elapsed(&self, t: i64) -> Duration {
        let ms = self.started_ms.map_or(0, |s| (t - s).max(0));
        Duration::from_millis(ms as u64)
    }

    /// ` · elapsed … · faults n` once the run has started, else nothing.
    fn tail(&self, t: i64) -> String {
        match self.started_ms {
            Some(_) => format!(
                " · elapsed {} · faults {}",
                fmt_duration(self.elapsed(t)),
                self.faults
            ),
            None => String::new(),
        }
    }
}

#[cfg(test)]
mod tests;
