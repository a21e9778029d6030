//! A campaign's planned duration as clients see it ([`EstimateView`]).

use serde::Serialize;

use crate::campaign::time::CampaignEstimate;

/// The planned duration of a campaign, stored with it when it was created (s).
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct EstimateView {
    /// One line for people: "300 poses, 600 readings, about 3 h 10 min".
    pub summary: String,
    /// Poses to measure.
    pub poses: usize,
    /// Tracker readings.
    pub readings: usize,
    /// Setup steps (tool frame, base registration) (s).
    pub setup_s: f64,
    /// Robot moves, routes and via points included (s).
    pub motion_s: f64,
    /// Settling after each move (s).
    pub settle_s: f64,
    /// Tracker measuring (s).
    pub measure_s: f64,
    /// Stage moves, or the technician's readings of a manual stage (s).
    pub stage_s: f64,
    /// The whole campaign (s): the sum of the parts.
    pub total_s: f64,
    /// Stage positions a technician sets and reads (0 with a motorised stage).
    pub technician_readings: usize,
    /// Robot moves, via points and pre-poses included.
    pub moves: usize,
}

impl EstimateView {
    /// The view of `e`.
    pub fn of(e: &CampaignEstimate) -> EstimateView {
        EstimateView {
            summary: e.summary(),
            poses: e.poses,
            readings: e.readings,
            setup_s: e.setup_s,
            motion_s: e.motion_s,
            settle_s: e.settle_s,
            measure_s: e.measure_s,
            stage_s: e.stage_s,
            total_s: e.total_s,
            technician_readings: e.technician_readings,
            moves: e.moves,
        }
    }
}
