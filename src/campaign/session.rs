//! Building a campaign run from a cell configuration: start the simulated cell when devices are
//! simulated, build the device adapters, open the store, and plan a new campaign or load a
//! stored one to resume.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{SystemTime, UNIX_EPOCH};

use nalgebra::Vector3;

use super::engine::{CampaignContext, Devices, FaultPolicy};
use super::events::Control;
use crate::cell::stage_manual::{ManualStage, ManualStageConfig};
use crate::cell::{
    EmsconTracker, EmsconTrackerConfig, LinkRobot, LinkRobotConfig, Prompter, ZaberStageAdapter,
    ZaberStageAdapterConfig,
};
use crate::config::{CellConfig, DeviceMode, StageMode};
use crate::dataset::PoseSet;
use crate::model::{load_robot, RobotModel};
use crate::plan::{
    count_via_points, plan_campaign, Plan, PlanEntry, PlanError, PlanRequest, Router, Workspace,
};
use crate::sim::{start_cell, RunningSimCell, SimTechnician, SimWorldConfig};
use crate::store::{NewCampaign, PlannedPose, Store};

/// Why a session could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// Robot model file.
    #[error(transparent)]
    Robot(#[from] crate::model::RobotFileError),
    /// The `[sim]` table.
    #[error("{path}: [sim]: {message}")]
    Sim {
        /// Config file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// Store.
    #[error("store: {0}")]
    Store(#[from] crate::store::StoreError),
    /// Planning.
    #[error("planning: {0}")]
    Plan(#[from] crate::plan::PlanError),
    /// Inconsistent request.
    #[error("{0}")]
    Invalid(String),
}

/// A ready campaign: context, devices and (when simulated) the running simulated cell.
pub struct Session {
    /// Engine context.
    pub ctx: CampaignContext,
    /// Device adapters.
    pub devices: Devices,
    /// The simulated cell, when any device is simulated.
    pub sim: Option<RunningSimCell>,
    /// Whether the campaign was resumed from the store.
    pub resumed: bool,
}

/// Planning request from the configuration.
pub fn plan_request(cfg: &CellConfig) -> PlanRequest {
    let c = &cfg.campaign;
    PlanRequest {
        workspace: Workspace {
            center_mm: Vector3::from(c.box_center_mm),
            size_mm: Vector3::from(c.box_size_mm),
            wrist_min_rad: c.wrist_min_deg.to_radians(),
            floor_z_mm: c.floor_z_mm,
            path_margin_mm: c.path_margin_mm,
        },
        poses: c.poses,
        ident: c.ident,
        seed: c.seed,
        tracker_mm: Vector3::from(cfg.tracker.position_mm),
        line_of_sight_max_rad: c.line_of_sight_max_deg.to_radians(),
        tool_mm: Vector3::from(c.tool_mm),
        drift_every: c.drift_every,
    }
}

fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// Set up a campaign session. `campaign` resumes a stored campaign; otherwise a new one is
/// planned and stored (the split is fixed before the first measurement).
pub async fn open_session(
    cfg: CellConfig,
    store_path: &Path,
    campaign: Option<i64>,
    prompter: Arc<dyn Prompter>,
) -> Result<Session, SessionError> {
    let mut nominal: RobotModel = load_robot(&cfg.robot)?;
    nominal.tool = Vector3::from(cfg.campaign.tool_mm);
    let robot_text = std::fs::read_to_string(&cfg.robot).unwrap_or_default();
    // simulated devices
    let sim = if cfg.any_simulated() {
        let table = cfg.sim.clone().unwrap_or_default();
        let mut sc: SimWorldConfig =
            table
                .try_into()
                .map_err(|e: toml::de::Error| SessionError::Sim {
                    path: cfg.path.display().to_string(),
                    message: e.to_string().trim_end().replace('\n', " "),
                })?;
        if !matches!(sc.errors.as_str(), "paper" | "random" | "none" | "") {
            let dir = cfg.path.parent().unwrap_or(Path::new("."));
            sc.errors = dir.join(&sc.errors).to_string_lossy().into_owned();
        }
        if cfg.stage.kind != StageMode::Serial {
            sc.stage_mode = crate::sim::config::StageMode::Manual;
        }
        let cell = start_cell(nominal.bare(), sc, std::future::pending())
            .await
            .map_err(|e| SessionError::Sim {
                path: cfg.path.display().to_string(),
                message: e.to_string(),
            })?;
        Some(cell)
    } else {
        None
    };
    let mut tcfg = match (&sim, cfg.tracker.mode) {
        (Some(s), DeviceMode::Sim) => s.tracker_config(),
        _ => EmsconTrackerConfig {
            address: cfg.tracker.address.clone(),
            reflector_id: cfg.tracker.reflector_id,
            ..EmsconTrackerConfig::default()
        },
    };
    tcfg.meas_time_ms = cfg.tracker.measure_ms as i32;
    let rcfg = match (&sim, cfg.robot_controller.mode) {
        (Some(s), DeviceMode::Sim) => s.robot_config(),
        _ => LinkRobotConfig {
            address: cfg.robot_controller.address.clone(),
            ..LinkRobotConfig::default()
        },
    };
    let stage: Box<dyn crate::cell::Stage> = match cfg.stage.kind {
        StageMode::Serial => {
            let scfg = match (&sim, cfg.stage.mode) {
                (Some(s), DeviceMode::Sim) => s.stage_config().ok_or_else(|| {
                    SessionError::Invalid("the simulated cell has no serial stage".into())
                })?,
                _ => ZaberStageAdapterConfig {
                    port: cfg.stage.serial_path.clone(),
                    microsteps_per_mm: cfg.stage.microsteps_per_mm,
                    ..ZaberStageAdapterConfig::default()
                },
            };
            Box::new(ZaberStageAdapter::new(ZaberStageAdapterConfig {
                tolerance_mm: cfg.stage.tolerance_mm,
                ..scfg
            }))
        }
        StageMode::Manual | StageMode::ManualGauge => Box::new(ManualStage::new(
            match (&sim, cfg.stage.mode) {
                // the simulated micrometer follows the technician's answers
                (Some(s), DeviceMode::Sim) => {
                    Arc::new(SimTechnician::new(Arc::clone(&prompter), s.world.clone()))
                }
                _ => Arc::clone(&prompter),
            },
            ManualStageConfig {
                tolerance_mm: cfg.stage.tolerance_mm,
                ..ManualStageConfig::default()
            },
        )),
    };
    let devices = Devices {
        tracker: Box::new(EmsconTracker::new(tcfg)),
        robot: Box::new(LinkRobot::new(rcfg)),
        stage,
    };
    // store and plan
    let mut store = Store::open(store_path)?;
    let req = plan_request(&cfg);
    let fresh = plan_campaign(&nominal, &req)?;
    let mut model_of_resumed = None;
    let (campaign_id, plan, resumed) = match campaign {
        Some(id) => {
            let row = store.campaign(id)?;
            let stored = store.plan(id)?;
            let poses: Vec<PlanEntry> = stored
                .into_iter()
                .map(|p| PlanEntry {
                    index: p.index,
                    set: p.set,
                    q_rad: p.q_rad,
                })
                .collect();
            let mut router = Router::new(
                &nominal,
                &req.workspace,
                &req.tool_mm,
                &fresh.drift_reference,
            )
            .map_err(PlanError::from)?;
            let via_points =
                count_via_points(&mut router, req.drift_every, &poses).map_err(PlanError::from)?;
            // identify with the model the campaign was created with
            model_of_resumed = Some(row.model);
            (
                id,
                Plan {
                    poses,
                    drift_reference: fresh.drift_reference.clone(),
                    via_points,
                },
                true,
            )
        }
        None => {
            let planned: Vec<PlannedPose> = fresh
                .poses
                .iter()
                .enumerate()
                .map(|(order, e)| PlannedPose {
                    index: e.index,
                    set: e.set,
                    order,
                    q_rad: e.q_rad.clone(),
                })
                .collect();
            let id = store.create_campaign(
                &NewCampaign {
                    name: format!("{} {}", nominal.name, cfg.campaign.model),
                    created_at_ms: now_ms(),
                    model: cfg.campaign.model.clone(),
                    seed: cfg.campaign.seed,
                    config_toml: cfg.text.clone(),
                    robot_toml: robot_text,
                },
                &planned,
            )?;
            (id, fresh, false)
        }
    };
    if plan
        .poses
        .iter()
        .filter(|p| p.set == PoseSet::Ident)
        .count()
        == 0
    {
        return Err(SessionError::Invalid(format!(
            "campaign {campaign_id} has no identification poses"
        )));
    }
    let mut cfg = cfg;
    if let Some(model) = model_of_resumed {
        cfg.campaign.model = model;
    }
    Ok(Session {
        ctx: CampaignContext {
            cfg,
            nominal,
            plan_request: req,
            plan,
            store: Arc::new(Mutex::new(store)),
            campaign_id,
            control: Control::new(1024),
            on_fault: FaultPolicy::default(),
        },
        devices,
        sim,
        resumed,
    })
}
