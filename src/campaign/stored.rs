//! A stored campaign's identification, rebuilt from the store alone (its configuration and
//! robot file as stored when it was created, its setup result and its measurements): what
//! `cellcal identify --store` runs and what `cellcal export` writes into the CSV header, by the
//! same recipe as the campaign ([`campaign_identification`]).

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde_json::Value;

use super::engine::campaign_identification;
use crate::calibrate::{BaseSource, CalibrationResult, ModelFileError, SetupResult};
use crate::config::{parse_cell_config, ConfigError};
use crate::dataset::{write_csv, CsvSetup, Observation};
use crate::identify::IdentifyOptions;
use crate::model::{parse_robot, RobotFileError, RobotModel};
use crate::report::corrected_model_toml;
use crate::report::model_file::sha256_hex;
use crate::store::{identification_rows, Store, StoreError};

/// Why a stored campaign cannot be identified.
#[derive(Debug, thiserror::Error)]
pub enum StoredError {
    /// The store could not be read, or the campaign does not exist.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The stored configuration no longer parses.
    #[error("campaign {id}: its stored configuration: {cause}")]
    Config {
        /// Campaign id.
        id: i64,
        /// The parse error.
        cause: ConfigError,
    },
    /// The stored robot model no longer parses.
    #[error("campaign {id}: its stored robot model: {cause}")]
    Robot {
        /// Campaign id.
        id: i64,
        /// The parse error.
        cause: RobotFileError,
    },
    /// An imported campaign without a stored robot model.
    #[error("campaign {0} has no stored robot model: give one")]
    NoRobot(i64),
    /// The stored result no longer parses.
    #[error("campaign {id}: its stored result: {message}")]
    Result {
        /// Campaign id.
        id: i64,
        /// The parse error.
        message: String,
    },
    /// The stored result does not fit the stored robot model.
    #[error("campaign {id}: its corrected model: {cause}")]
    Model {
        /// Campaign id.
        id: i64,
        /// What does not fit.
        cause: ModelFileError,
    },
}

/// Everything the identification of a stored campaign takes.
#[derive(Debug, Clone)]
pub struct StoredCampaign {
    /// Campaign id.
    pub id: i64,
    /// Nominal model with the campaign's setup applied.
    pub nominal: RobotModel,
    /// The campaign's identification options.
    pub opts: IdentifyOptions,
    /// Stage travel (mm).
    pub travel_mm: f64,
    /// The measured poses (ident and verify), in plan order.
    pub rows: Vec<Observation>,
    /// The setup the identification uses, as the CSV header carries it.
    pub setup: CsvSetup,
}

impl StoredCampaign {
    /// The identify CSV of this campaign exactly as `cellcal export` writes it (and
    /// `GET /api/campaigns/{id}/measurements?format=csv` serves it): a comment naming the
    /// campaign, `source` (the store) and the identify flags it used, the setup header, the rows.
    pub fn export_csv(&self, source: &str) -> String {
        let o = &self.opts;
        let comment = format!(
            "cellcal export: campaign {} from {source}\nidentified by the campaign as: --model {}{}{}\n{}",
            self.id,
            o.obs.model.name(),
            if o.identify_base { " --identify-base" } else { "" },
            if o.identify_tool { " --identify-tool" } else { "" },
            self.setup.comment_lines()
        );
        write_csv(&self.rows, self.nominal.dof(), &comment)
    }
}

/// Rebuild campaign `id`'s identification from `store`; `robot` replaces the stored robot model
/// when given (an imported campaign may have none). An imported campaign (no stored
/// configuration) takes the default configuration with its recorded observation model.
pub fn load_stored(
    store: &Store,
    id: i64,
    robot: Option<RobotModel>,
) -> Result<StoredCampaign, StoredError> {
    let row = store.campaign(id)?;
    let label = PathBuf::from(format!("campaign {id}.toml"));
    let mut cfg = parse_cell_config(&row.config_toml, &label)
        .map_err(|cause| StoredError::Config { id, cause })?;
    // the model the campaign ran with: a request's override (REST `model`) is recorded there,
    // not in the configuration text; an imported campaign has no configuration (an unknown
    // name keeps the configuration's, for an import the default `op`)
    if let Ok(m) = row.model.parse() {
        cfg.campaign.model = m;
    }
    let mut nominal = match robot {
        Some(r) => r,
        None if row.robot_toml.trim().is_empty() => return Err(StoredError::NoRobot(id)),
        None => parse_robot(&row.robot_toml, Path::new("robot.toml"))
            .map_err(|cause| StoredError::Robot { id, cause })?,
    };
    nominal.tool = Vector3::from(cfg.campaign.tool_mm);
    let setup = SetupResult::load(store, id)?;
    let (nominal, opts, travel_mm) = campaign_identification(&cfg, &nominal, setup.as_ref());
    // the registered base, exactly as stored: held when the base is not identified, else the
    // base of the "before"
    let base = setup.and_then(|s| s.base);
    let csv_setup = CsvSetup {
        stage_axis: Some(opts.obs.stage_axis),
        tool_mm: Some(nominal.tool),
        stage_travel_mm: Some(travel_mm),
        base_translation_mm: base.as_ref().map(|b| Vector3::from(b.translation_mm)),
        base_rotation_vector_rad: base.as_ref().map(|b| Vector3::from(b.rotation_vector_rad)),
    };
    Ok(StoredCampaign {
        id,
        nominal,
        opts,
        travel_mm,
        rows: identification_rows(store.measured(id)?),
        setup: csv_setup,
    })
}

/// Campaign `id`'s stored typed result; `None` before it has one, and for a campaign that is
/// no calibration (ISO 9283: its result is figures, not an identification).
pub fn stored_result(store: &Store, id: i64) -> Result<Option<CalibrationResult>, StoredError> {
    if store.campaign_kind(id)?.is_some() {
        return Ok(None);
    }
    Ok(store.latest_result_as(id)?)
}

/// What `GET /api/campaigns/{id}/result` answers: a calibration's `cellcal identify` JSON
/// contract rendered from its stored typed result, an ISO 9283 campaign's stored figures;
/// `None` before a result.
pub fn stored_result_json(store: &Store, id: i64) -> Result<Option<Value>, StoredError> {
    if store.campaign_kind(id)?.is_some() {
        return Ok(store.latest_result_as::<Value>(id)?);
    }
    stored_result(store, id)?
        .map(|r| serde_json::to_value(&r.report))
        .transpose()
        .map_err(|e| StoredError::Result {
            id,
            message: e.to_string(),
        })
}

/// Campaign `id`'s corrected model as robot-file TOML ([`crate::report::model_file`]) from its
/// stored typed result (its corrected model's values, base and tool) and its stored nominal
/// model (name, joint limits); `None` before it has a result, and for a campaign that is no
/// calibration (ISO 9283: its result is figures, not a model). The same store gives the same
/// bytes (`cellcal run --model-out`, `GET /api/campaigns/{id}/model`).
pub fn stored_model_toml(store: &Store, id: i64) -> Result<Option<String>, StoredError> {
    let Some(result) = stored_result(store, id)? else {
        return Ok(None);
    };
    let c = load_stored(store, id, None)?;
    let row = store.campaign(id)?;
    let base = result.corrected.base_source.unwrap_or_else(|| {
        BaseSource::of(c.opts.identify_base, c.setup.base_translation_mm.is_some())
    });
    // the digest of the result's contract: the JSON `identify --json` and `run --json` write
    let contract = result.identify_json().map_err(|e| StoredError::Result {
        id,
        message: e.to_string(),
    })?;
    let provenance = [
        format!(
            "Data: campaign {id} `{}` ({} poses), its result sha256 {}",
            row.name,
            c.rows.len(),
            sha256_hex(contract.as_bytes())
        ),
        format!(
            "Nominal model: the campaign's stored robot model (sha256 {})",
            sha256_hex(row.robot_toml.as_bytes())
        ),
    ];
    corrected_model_toml(&result, &c.nominal, &provenance, base)
        .map(Some)
        .map_err(|cause| StoredError::Model { id, cause })
}
