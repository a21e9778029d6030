//! The calibration report: one self-contained HTML page (inline CSS with a print style sheet,
//! inline SVG plots drawn by `plotters`, no script, no external reference) built from a
//! [`ReportInput`] the caller gathers (the identify result and its per-pose errors, significance
//! indices and, for a stored campaign, its setup, journal and device facts).
//!
//! Pure: no I/O, no clock (the caller passes the time it was generated). Every text from the
//! input is HTML-escaped. Every number that the identify JSON holds is written with
//! `data-json="<JSON pointer>"` and `data-value="<the exact value>"` beside its rounded display,
//! so a reader (or a test) can check the page against the JSON it came from.

mod nongeometric;
mod page;
mod plots;
mod sections;

use sha2::{Digest, Sha256};

use crate::analysis::significance::{significance, Significance};
use crate::calibrate::{CalibrationResult, CampaignTime, IdentifyReport, SetupResult};
pub use crate::calibrate::{PoseError, PoseErrors, SetErrors};
use crate::model::RobotModel;
use crate::units::human::TimeZone;

pub use page::render;

/// Random joint configurations of the report's significance analysis (the paper's 50).
pub const SIGNIFICANCE_SAMPLES: usize = 50;
/// Seed of those configurations (`cellcal significance`'s default).
pub const SIGNIFICANCE_SEED: u64 = 1;

/// Everything the report shows; gathered by the caller, rendered by [`render`].
#[derive(Debug, Clone)]
pub struct ReportInput {
    /// The page title (`Campaign 3 "name"`, `identify d.csv`).
    pub title: String,
    /// Where the data came from, for a person (`campaign 3 in c.db`, `d.csv`).
    pub source: String,
    /// The identify result the page reports (the JSON contract).
    pub result: IdentifyReport,
    /// Per-pose errors before and after, or why they are not available.
    pub poses: Result<PoseErrors, String>,
    /// Significance indices of the nominal model's MDH parameters (paper Fig. 3).
    pub significance: Vec<Significance>,
    /// What the store knows of the campaign; `None` when the data did not come from a store.
    pub campaign: Option<CampaignFacts>,
    /// Software, input digests and times.
    pub provenance: Provenance,
    /// Remarks on how the page was built (e.g. a re-identification that differs).
    pub notes: Vec<String>,
}

impl ReportInput {
    /// The report of `result` with nothing else known yet (no per-pose errors, significance,
    /// campaign facts or notes).
    pub fn new(title: &str, source: &str, result: IdentifyReport, provenance: Provenance) -> Self {
        ReportInput {
            title: title.to_owned(),
            source: source.to_owned(),
            result,
            poses: Err("they were not computed".to_owned()),
            significance: Vec::new(),
            campaign: None,
            provenance,
            notes: Vec::new(),
        }
    }

    /// The report of a typed result: its contract and its stored per-pose errors (a result
    /// stored before they were kept says so, and how to get them).
    pub fn of_result(
        title: &str,
        source: &str,
        result: &CalibrationResult,
        provenance: Provenance,
    ) -> Self {
        let mut input = ReportInput::new(title, source, result.report.clone(), provenance);
        input.poses = result.residuals.clone().ok_or_else(|| {
            "this result was stored by an earlier cellcal, which kept no per-pose errors \
             (`cellcal identify --store` identifies the campaign again and reports them)"
                .to_owned()
        });
        input
    }

    /// With the significance indices of `nominal`'s MDH parameters.
    pub fn with_significance(mut self, nominal: &RobotModel) -> Self {
        self.significance = significance(nominal, SIGNIFICANCE_SAMPLES, SIGNIFICANCE_SEED);
        self
    }
}

/// What the campaign store knows of a campaign beyond its result.
#[derive(Debug, Clone, Default)]
pub struct CampaignFacts {
    /// Campaign id.
    pub id: i64,
    /// Human name.
    pub name: String,
    /// Stored state (`done`, …).
    pub state: String,
    /// Creation time (ms since the Unix epoch).
    pub created_at_ms: i64,
    /// Plan seed.
    pub seed: u64,
    /// Poses measured and planned.
    pub poses_done: usize,
    /// Poses planned.
    pub poses_total: usize,
    /// The stored cell setup result, if the campaign ran the setup.
    pub setup: Option<SetupResult>,
    /// Drift checks from the journal, in order.
    pub drift: Vec<DriftCheck>,
    /// Device faults from the journal, in order.
    pub faults: Vec<FaultEntry>,
    /// Devices: what the configuration names and what the journal recorded of them.
    pub devices: Vec<DeviceEntry>,
    /// Time of the first and the last journal entry (ms since the Unix epoch).
    pub journal_span_ms: Option<(i64, i64)>,
    /// Number of journal entries.
    pub journal_entries: usize,
    /// Planned against actual time (the stored result's, else from the store).
    pub time: Option<CampaignTime>,
}

/// One drift check at the reference pose.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftCheck {
    /// When (ms since the Unix epoch).
    pub at_ms: i64,
    /// Distance from the reference measurement (mm).
    pub drift_mm: f64,
    /// Threshold (mm).
    pub max_mm: f64,
}

/// One device fault and what the engine did.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultEntry {
    /// When (ms since the Unix epoch).
    pub at_ms: i64,
    /// Device (`tracker`, `robot`, `stage`).
    pub device: String,
    /// Fault kind.
    pub kind: String,
    /// Driver message.
    pub message: String,
    /// Action taken.
    pub action: String,
}

/// A device of the cell.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceEntry {
    /// `tracker`, `robot` or `stage`.
    pub device: String,
    /// How the configuration connects to it (protocol, address or port, simulated or real).
    pub configured: String,
    /// What the device said it is (model, serial, firmware), when recorded.
    pub identity: Option<String>,
}

/// Where the report's numbers come from.
#[derive(Debug, Clone, PartialEq)]
pub struct Provenance {
    /// This software's version.
    pub software_version: String,
    /// The git commit it was built from, when known.
    pub git_hash: Option<String>,
    /// When the report was generated (ms since the Unix epoch).
    pub generated_at_ms: i64,
    /// The inputs and their SHA-256 digests.
    pub inputs: Vec<InputDigest>,
    /// The zone the page shows its times in (ISO 8601 with the offset); UTC unless the caller
    /// gives one ([`Provenance::in_time_zone`]: the page is pure and reads no system zone).
    pub time_zone: TimeZone,
}

impl Provenance {
    /// This build's identity ([`crate::build_info`]), generated at `at_ms`, with `inputs`.
    pub fn of_this_build(generated_at_ms: i64, inputs: Vec<InputDigest>) -> Provenance {
        use crate::build_info::{GIT_HASH, VERSION};
        Provenance {
            software_version: VERSION.to_owned(),
            git_hash: (GIT_HASH != "unknown").then(|| GIT_HASH.to_owned()),
            generated_at_ms,
            inputs,
            time_zone: TimeZone::UTC,
        }
    }

    /// With the page's times shown in `tz` (the caller's local zone, `units::human::local_time_zone`).
    pub fn in_time_zone(mut self, tz: TimeZone) -> Provenance {
        self.time_zone = tz;
        self
    }
}

/// One input of the result and its digest.
#[derive(Debug, Clone, PartialEq)]
pub struct InputDigest {
    /// What it is (`cell configuration (as stored)`, `robot model`, `measurement CSV`).
    pub what: String,
    /// Its name (a path, or how the store holds it).
    pub name: String,
    /// SHA-256 of its bytes, lowercase hex.
    pub sha256: String,
}

impl InputDigest {
    /// The digest of `bytes`.
    pub fn of(what: &str, name: &str, bytes: &[u8]) -> InputDigest {
        let digest = Sha256::digest(bytes);
        InputDigest {
            what: what.to_owned(),
            name: name.to_owned(),
            sha256: digest.iter().map(|b| format!("{b:02x}")).collect(),
        }
    }
}

#[cfg(test)]
mod tests;
