//! A campaign's time: the estimate stored with it when it is created ([`CampaignEstimate`]),
//! the time its journal says it spent measuring and paused ([`Elapsed`]), and both side by
//! side in the stored result ([`CampaignTime`]).
//!
//! How the journal's time is counted: every `state` entry opens a span of that state, which
//! ends at the next `state` entry. A span the next run opened after a process died without a
//! final state (a `running` or `paused` span followed by `idle` or `armed`, the first states of
//! a run) ends at the last entry the dead process wrote (other than a note: the next process
//! notes what it found before its first state). The span still open at the end of the journal
//! ends now while a live process runs the campaign, else at its last entry other than a note. Measuring
//! time is the sum of the `running` spans, paused time that of the `paused` spans.

use serde_json::Value;

use super::events::{CampaignEvent, CampaignState};
use crate::calibrate::CampaignTime;
use crate::store::{EntryAfter, Store, StoreError};

pub use crate::plan::CampaignEstimate;

/// The estimate stored with campaign `id` (`None`: created without one, or stored by a build
/// whose estimate does not read as this one's).
pub fn stored_estimate(store: &Store, id: i64) -> Result<Option<CampaignEstimate>, StoreError> {
    Ok(store
        .campaign_estimate(id)?
        .and_then(|t| serde_json::from_str(&t).ok()))
}

/// The journal kind of a state change (`CampaignEvent::State`).
const STATE_KIND: &str = "state";
/// The journal kind of a note (`CampaignEvent::Note`).
const NOTE_KIND: &str = "note";

/// The time a campaign spent measuring and paused, from its journal (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Elapsed {
    /// Closed `running` spans (ms).
    measuring_ms: i64,
    /// Closed `paused` spans (ms).
    paused_ms: i64,
    /// The span open at the journal's end: whether it is `running` (else `paused`), its
    /// start, and the journal's last entry (ms since the Unix epoch).
    open: Option<(bool, i64, i64)>,
    /// The journal has a `running` state.
    ran: bool,
}

impl Elapsed {
    /// Count the `state` entries of a journal whose last entry was written at `last_at_ms`.
    pub fn of(states: &[EntryAfter<CampaignEvent>], last_at_ms: Option<i64>) -> Elapsed {
        let mut e = Elapsed::default();
        let mut open: Option<(bool, i64)> = None;
        for s in states {
            let CampaignEvent::State { state } = &s.entry.event else {
                continue;
            };
            if let Some((running, from)) = open.take() {
                // a new run's first state: the previous process died; its span ended at its
                // last entry
                let new_run = matches!(state, CampaignState::Idle | CampaignState::Armed);
                let to = match (new_run, s.previous_at_ms) {
                    (true, Some(p)) => p,
                    _ => s.entry.at_ms,
                };
                e.add(running, (to - from).max(0));
            }
            e.ran |= *state == CampaignState::Running;
            open = match state {
                CampaignState::Running => Some((true, s.entry.at_ms)),
                CampaignState::Paused { .. } => Some((false, s.entry.at_ms)),
                _ => None,
            };
        }
        e.open = open.map(|(running, from)| (running, from, last_at_ms.unwrap_or(from).max(from)));
        e
    }

    /// Campaign `id`'s, from its stored journal. Where a dead process stopped is its last
    /// entry other than a note: the next process journals notes (interrupted, taken over,
    /// resumed with changes) before its first state.
    pub fn stored(store: &Store, id: i64) -> Result<Elapsed, StoreError> {
        let states = store.entries_of_kind::<CampaignEvent>(id, STATE_KIND, NOTE_KIND)?;
        Ok(Elapsed::of(&states, store.last_event_at(id, NOTE_KIND)?))
    }

    fn add(&mut self, running: bool, ms: i64) {
        if running {
            self.measuring_ms += ms;
        } else {
            self.paused_ms += ms;
        }
    }

    /// Measuring and paused time (s): an open span ends at `now_ms` when a live process runs
    /// the campaign (`Some`), else at the journal's last entry.
    pub fn seconds(&self, now_ms: Option<i64>) -> (f64, f64) {
        let mut e = *self;
        if let Some((running, from, last)) = self.open {
            e.add(running, (now_ms.unwrap_or(last).max(last) - from).max(0));
        }
        (e.measuring_ms as f64 / 1000.0, e.paused_ms as f64 / 1000.0)
    }
}

/// Campaign `id`'s planned against actual time, as its result keeps it (read when it
/// identifies: every span is closed then); `None` for a campaign that has no estimate and
/// never ran (e.g. an imported one: nothing to say).
pub fn campaign_time(store: &Store, id: i64) -> Result<Option<CampaignTime>, StoreError> {
    let estimate = stored_estimate(store, id)?;
    let elapsed = Elapsed::stored(store, id)?;
    if estimate.is_none() && !elapsed.ran {
        return Ok(None);
    }
    let (measuring_s, paused_s) = elapsed.seconds(None);
    let planned_s = estimate.as_ref().map(|e| e.total_s);
    Ok(Some(CampaignTime {
        planned: estimate.as_ref().and_then(|e| serde_json::to_value(e).ok()),
        planned_summary: estimate.as_ref().map(CampaignEstimate::summary),
        planned_s,
        measuring_s,
        paused_s,
        ratio: planned_s
            .filter(|p| *p > 0.0)
            .map(|p| measuring_s / p)
            .filter(|r| r.is_finite()),
    }))
}

/// The estimate as the store keeps it (a JSON object).
pub(super) fn estimate_json(e: &CampaignEstimate) -> Option<String> {
    serde_json::to_value(e)
        .ok()
        .filter(Value::is_object)
        .map(|v| v.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::JournalEntry;

    fn state(
        seq: i64,
        at_ms: i64,
        previous_at_ms: i64,
        state: CampaignState,
    ) -> EntryAfter<CampaignEvent> {
        EntryAfter {
            entry: JournalEntry {
                seq,
                at_ms,
                event: CampaignEvent::State { state },
            },
            previous_at_ms: Some(previous_at_ms),
        }
    }

    fn paused() -> CampaignState {
        CampaignState::Paused {
            reason: "paused by the operator".into(),
        }
    }

    #[test]
    fn measuring_time_excludes_pauses_waits_identification_and_a_dead_process_s_gap() {
        use CampaignState::*;
        let journal = [
            state(1, 0, 0, Armed),
            state(2, 5_000, 0, Running),
            state(3, 65_000, 64_000, paused()),
            state(4, 95_000, 65_000, Running),
            // the process dies at 100 s (its last entry); a new one starts at 1000 s
            state(5, 1_000_000, 100_000, Idle),
            state(6, 1_001_000, 1_000_000, Armed),
            state(7, 1_002_000, 1_001_000, Running),
            state(8, 1_012_000, 1_011_000, Identifying),
            state(9, 1_020_000, 1_012_000, Done),
        ];
        let e = Elapsed::of(&journal, Some(1_020_000));
        // 60 s + 5 s + 10 s running, 30 s paused
        assert_eq!(e.seconds(None), (75.0, 30.0));
        assert_eq!(e.seconds(Some(5_000_000)), (75.0, 30.0), "nothing open");
        // while running: the open span ends now, or at the last entry without a live process
        let e = Elapsed::of(&journal[..4], Some(97_000));
        assert_eq!(e.seconds(Some(99_000)), (64.0, 30.0));
        assert_eq!(e.seconds(None), (62.0, 30.0));
        assert_eq!(Elapsed::of(&[], None).seconds(Some(9)), (0.0, 0.0));
    }
}
