//! The calibration report of a stored campaign: gathers from the store alone what
//! [`crate::report::html`] shows — the stored typed result (contract and per-pose residuals as
//! the campaign's identification left them: nothing is identified again), the significance
//! indices of the stored nominal model, the setup result, drift checks and faults from the
//! journal, the configured devices, the digests of the stored configuration and robot file, and
//! the journal's times.

use std::path::Path;

use super::stored::{load_stored, StoredError};
use crate::analysis::significance::significance;
use crate::calibrate::{CalibrationResult, SetupResult};
use crate::campaign::events::{fault_kind_name, CampaignEvent, Journalled};
use crate::config::cell::{CellConfig, DeviceMode, StageMode};
use crate::config::parse_cell_config;
use crate::report::html::{
    CampaignFacts, DeviceEntry, DriftCheck, FaultEntry, InputDigest, Provenance, ReportInput,
    SIGNIFICANCE_SAMPLES, SIGNIFICANCE_SEED,
};
use crate::store::{Store, StoreError};
use crate::units::human::local_time_zone;

/// Why a stored campaign has no calibration report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The store could not be read, or the campaign does not exist.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// An ISO 9283 campaign: its result is the ISO figures, not an identification.
    #[error(
        "campaign {0} is an ISO 9283 campaign: it has no calibration report; its figures are \
         `cellcal iso9283 --campaign {0}` (GET /api/campaigns/{0}/result)"
    )]
    NotCalibration(i64),
}

/// The report input of campaign `id` in `store`, or `None` while it has no result.
/// `store_name` names the store file in the page; `generated_at_ms` is the page's time. Only a
/// store failure is an error: a part that is not there (per-pose errors of a result stored by
/// an earlier cellcal, significance indices of a stored robot file that no longer parses) is
/// reported missing, with the reason, in the page.
pub fn campaign_report(
    store: &Store,
    id: i64,
    store_name: &str,
    generated_at_ms: i64,
) -> Result<Option<ReportInput>, ReportError> {
    if super::iso::is_iso_campaign(store, id)? {
        return Err(ReportError::NotCalibration(id));
    }
    let Some(result) = store.latest_result_as::<CalibrationResult>(id)? else {
        return Ok(None);
    };
    let (facts, inputs) = campaign_facts(store, id)?;
    let title = format!("Calibration report: campaign {id} \"{}\"", facts.name);
    let provenance =
        Provenance::of_this_build(generated_at_ms, inputs).in_time_zone(local_time_zone());
    let mut input = ReportInput::of_result(
        &title,
        &format!("campaign {id} in {store_name}"),
        &result,
        provenance,
    );
    // the significance indices are the nominal model's (with the campaign's setup): parsed
    // from the store, nothing identified
    match load_stored(store, id, None) {
        Ok(c) => {
            input.significance = significance(&c.nominal, SIGNIFICANCE_SAMPLES, SIGNIFICANCE_SEED);
            if result.residuals.is_none() {
                // a result stored before the per-pose errors were kept: evaluated from its
                // corrected model, once per page
                match result.evaluate_residuals(&c.nominal, &c.opts, &c.rows, c.travel_mm) {
                    Ok(poses) => {
                        input.poses = Ok(poses);
                        input.notes.push(
                            "This result was stored by an earlier cellcal, which kept no \
                             per-pose errors: the per-pose plots evaluate the stored measurements \
                             under the stored result's corrected model (nothing was identified \
                             again)."
                                .to_owned(),
                        );
                    }
                    Err(e) => {
                        input.poses = Err(format!(
                            "this result was stored by an earlier cellcal, which kept none, and \
                             its corrected model does not give them: {e}"
                        ))
                    }
                }
            }
        }
        Err(StoredError::Store(e)) => return Err(e.into()),
        Err(e) => input.notes.push(format!(
            "No significance indices: the campaign's nominal model: {e}"
        )),
    }
    let mut facts = facts;
    if result.campaign_time.is_some() {
        // what the result kept when the campaign identified
        facts.time = result.campaign_time.clone();
    }
    input.campaign = Some(facts);
    Ok(Some(input))
}

/// What the store knows of campaign `id` besides its result, and the digests of its stored
/// configuration and robot file.
pub fn campaign_facts(
    store: &Store,
    id: i64,
) -> Result<(CampaignFacts, Vec<InputDigest>), StoreError> {
    let row = store.campaign(id)?;
    let (done, total) = store.pose_counts(id)?;
    let events = store.events::<CampaignEvent>(id)?;
    let cfg = parse_cell_config(&row.config_toml, Path::new("stored configuration"));
    let inputs = vec![
        stored_digest("cell configuration (as stored)", &row.config_toml),
        stored_digest("robot model file (as stored)", &row.robot_toml),
    ];
    let facts = CampaignFacts {
        id,
        name: row.name,
        state: row.state.name().to_owned(),
        created_at_ms: row.created_at_ms,
        seed: row.seed,
        poses_done: done,
        poses_total: total,
        setup: SetupResult::load(store, id)?,
        drift: events.iter().filter_map(drift_check).collect(),
        faults: events.iter().filter_map(fault).collect(),
        devices: with_identities(devices(cfg.as_ref().ok()), &events),
        journal_span_ms: events
            .first()
            .zip(events.last())
            .map(|(a, b)| (a.at_ms, b.at_ms)),
        journal_entries: events.len(),
        time: super::time::campaign_time(store, id)?,
    };
    Ok((facts, inputs))
}

fn stored_digest(what: &str, text: &str) -> InputDigest {
    if text.trim().is_empty() {
        return InputDigest {
            what: what.to_owned(),
            name: "not stored (an imported campaign)".to_owned(),
            sha256: "—".to_owned(),
        };
    }
    InputDigest::of(what, "the campaign row's verbatim copy", text.as_bytes())
}

fn drift_check(e: &Journalled) -> Option<DriftCheck> {
    match e.event {
        CampaignEvent::Drift { drift_mm, max_mm } => Some(DriftCheck {
            at_ms: e.at_ms,
            drift_mm,
            max_mm,
        }),
        _ => None,
    }
}

fn fault(e: &Journalled) -> Option<FaultEntry> {
    match &e.event {
        CampaignEvent::Fault {
            device,
            kind,
            message,
            action,
        } => Some(FaultEntry {
            at_ms: e.at_ms,
            device: device.name().to_owned(),
            kind: fault_kind_name(*kind).to_owned(),
            message: message.clone(),
            action: action.clone(),
        }),
        _ => None,
    }
}

/// `what` and, for a real device, its address.
fn at(what: &str, address: &str, m: DeviceMode) -> String {
    match m {
        DeviceMode::Sim => what.to_owned(),
        DeviceMode::Real => format!("{what} at {address}"),
    }
}

/// `entries` with the identities of the journal's last `devices` event (the devices of the
/// campaign's last session).
fn with_identities(mut entries: Vec<DeviceEntry>, events: &[Journalled]) -> Vec<DeviceEntry> {
    let Some((tracker, robot, stage)) = events.iter().rev().find_map(|e| match &e.event {
        CampaignEvent::Devices {
            tracker,
            robot,
            stage,
        } => Some((tracker, robot, stage)),
        _ => None,
    }) else {
        return entries;
    };
    for entry in &mut entries {
        entry.identity = match entry.device.as_str() {
            "tracker" => tracker.clone(),
            "robot" => robot.clone(),
            "stage" => stage.clone(),
            _ => None,
        };
    }
    entries
}

/// The cell's devices as the stored configuration names them (identities: [`with_identities`]).
fn devices(cfg: Option<&CellConfig>) -> Vec<DeviceEntry> {
    let Some(c) = cfg else {
        return ["tracker", "robot", "stage"]
            .map(|d| DeviceEntry {
                device: d.to_owned(),
                configured: "unknown: no readable stored configuration".to_owned(),
                identity: None,
            })
            .to_vec();
    };
    let stage = match c.stage.kind {
        StageMode::Serial if c.stage.mode == DeviceMode::Sim => "Zaber ASCII stage".to_owned(),
        StageMode::Serial => format!("Zaber ASCII stage on {}", c.stage.serial_path),
        StageMode::Manual => "manual micrometer (technician answers)".to_owned(),
        StageMode::ManualGauge => format!("manual micrometer, gauge on {}", c.stage.gauge_path),
    };
    let entry = |device: &str, configured: String, m: DeviceMode| DeviceEntry {
        device: device.to_owned(),
        configured: match m {
            DeviceMode::Sim => format!("{configured} (simulated cell, in-process)"),
            DeviceMode::Real => configured,
        },
        identity: None,
    };
    vec![
        entry(
            "tracker",
            at("emScon TPI tracker", &c.tracker.address, c.tracker.mode),
            c.tracker.mode,
        ),
        entry(
            "robot",
            at(
                "robotlink controller",
                &c.robot_controller.address,
                c.robot_controller.mode,
            ),
            c.robot_controller.mode,
        ),
        entry("stage", stage, c.stage.mode),
    ]
}
