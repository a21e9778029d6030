//! Planned against actual duration of the campaign that measured a result: the estimate stored
//! with the campaign when it was created, and the time its journal says it spent measuring and
//! paused. Kept in the stored result (`campaign_time`) and shown by its views; a result of
//! `cellcal identify` (no campaign) has none.

use serde::{Deserialize, Serialize};

/// How long a campaign was planned to take and how long it took (s).
///
/// `measuring_s` is the time the campaign spent in the state `running` (setup, moves,
/// settling, readings, stage moves and technician answers, drift checks); `paused_s` the time
/// in `paused`. Neither counts the time before the start, while identifying, nor between a run
/// that ended (aborted, failed, or a process that died) and its resume.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignTime {
    /// The planner's estimate as stored with the campaign (its JSON object: `poses`,
    /// `readings`, `setup_s`, `motion_s`, `settle_s`, `measure_s`, `stage_s`, `total_s`);
    /// null for a campaign created without one.
    pub planned: Option<serde_json::Value>,
    /// The estimate's one-line summary ("300 poses, 600 readings, about 3 h 10 min"); null
    /// without an estimate.
    pub planned_summary: Option<String>,
    /// The estimate's total (s); null without an estimate.
    pub planned_s: Option<f64>,
    /// Time spent measuring (s): in the state `running`, pauses excluded.
    pub measuring_s: f64,
    /// Time spent paused (s), by the operator or a fault.
    pub paused_s: f64,
    /// `measuring_s / planned_s` (1.10: took 10 % longer than planned); null without an
    /// estimate.
    pub ratio: Option<f64>,
}
