//! Building a campaign run from a cell configuration: start the simulated cell when devices are
//! simulated, build the device adapters, open the store, and plan a new campaign or load a
//! stored one to resume.

use std::path::Path;
use std::sync::Arc;

use nalgebra::Vector3;
use robotlink::SharedSecret;

use super::cell_lock::{lock_dir, CellKey, CellLock, CellLockError};
use super::engine::{identify_options, CampaignContext, Devices, FaultPolicy};
use super::estimate::estimate_campaign_time;
use super::events::Control;
use super::feasibility;
use super::lock::CampaignLock;
use crate::cell::stage_manual::{ManualStage, ManualStageConfig};
use crate::cell::{
    EmsconTracker, EmsconTrackerConfig, LinkRobot, LinkRobotConfig, Prompter, ZaberStageAdapter,
    ZaberStageAdapterConfig,
};
use crate::cell::{UrRobot, UrRobotConfig};
use crate::compensate::Compensator;
use crate::config::diff::changed_keys;
use crate::config::{
    parse_cell_config, CellConfig, DeviceMode, RobotProtocol, SimWorldConfig, StageMode, StopWhen,
};
use crate::dataset::PoseSet;
use crate::identify::ObsModel;
use crate::model::rotation::from_rotation_vector;
use crate::model::{load_robot, RobotModel, TermFamily};
use crate::plan::iso9283::{plan_iso, IsoPlan, IsoPlanError, IsoRequest, Targeting};
use crate::plan::motion::MotionLimits;
use crate::plan::selection::DesignSetup;
use crate::plan::{
    campaign_router, count_via_points, order_times, plan_campaign, CampaignEstimate, Plan,
    PlanEntry, PlanError, PlanRequest, Workspace,
};
use crate::sim::{start_cell_with, RunningSimCell, SimTechnician};
use crate::store::{
    CampaignKind, CampaignRow, NewCampaign, PlannedPose, Store, StoreHandle, StoredState,
    ISO9283_KIND,
};
use crate::wall_clock::now_unix_ms;

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
    /// Store (its message names the campaign store).
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    /// Planning.
    #[error("planning: {0}")]
    Plan(crate::plan::PlanError),
    /// Inconsistent request.
    #[error("{0}")]
    Invalid(String),
    /// The robot controller's shared secret (`[robot_controller] secret_file`).
    #[error(transparent)]
    RobotSecret(#[from] crate::cell::RobotSecretError),
    /// The campaign is done: nothing to measure (its result is stored).
    #[error("campaign {0} is done: nothing moves; its result is stored")]
    Done(i64),
    /// The configuration or robot model differs from the one the campaign was created with.
    #[error(
        "campaign {id} was created with another {what}; changed: {}. Resuming would mix two \
         cells in one campaign; restore the file, or accept the change with \
         --accept-changed-config",
        keys.join(", ")
    )]
    ConfigChanged {
        /// Campaign id.
        id: i64,
        /// `configuration` or `robot model`.
        what: &'static str,
        /// The dotted keys that differ.
        keys: Vec<String>,
    },
    /// The campaign cannot run as configured, or the campaign to resume is not stored.
    #[error(transparent)]
    Infeasible(#[from] super::feasibility::FeasibilityError),
    /// The ISO 9283 poses cannot be planned.
    #[error("planning: {0}")]
    Iso(IsoPlanError),
    /// Another process commands the cell (or its lock cannot be taken).
    #[error(transparent)]
    Cell(#[from] CellLockError),
}

from_cause!(crate::plan::PlanError => SessionError::Plan);
from_cause!(IsoPlanError => SessionError::Iso);

/// A stored campaign to resume.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Resume {
    /// Campaign id.
    pub id: i64,
    /// Resume although the configuration or robot model changed since the campaign was
    /// created (the changed keys are journalled).
    pub accept_changed_config: bool,
}

impl Resume {
    /// Resume `id` only with the configuration and robot model it was created with.
    pub fn strict(id: i64) -> Resume {
        Resume {
            id,
            accept_changed_config: false,
        }
    }
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
    /// This process is the campaign's one runner while this is held.
    pub lock: CampaignLock,
    /// This process is the cell's one commander while this is held (`None`: an in-memory
    /// store with a simulated robot, a cell no other process can reach).
    pub cell: Option<CellLock>,
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
        ident_block: None,
        speed_pct: cfg.robot_controller.speed_pct,
        move_speed_rad_s: move_speed_rad_s(cfg),
        settle_s: settle_s(cfg),
        stage_offset_mm: stage_offset_mm(cfg),
        selection: c.selection,
        design: design_setup(cfg),
    }
}

/// What optimal selection designs a campaign's identification for: its observation model and
/// stage as the identification uses them, its base and tool choice, the AT960's noise.
fn design_setup(cfg: &CellConfig) -> DesignSetup {
    let opts = super::engine::identify_options(cfg);
    DesignSetup {
        obs: opts.obs,
        stage_travel_mm: cfg.stage.travel_mm,
        identify_base: opts.identify_base,
        identify_tool: opts.identify_tool,
        ..DesignSetup::default()
    }
}

/// [`plan_request`] of a campaign of `nominal`: with `campaign.stop_when = "predicted"` (a
/// calibration campaign) the identification poses come first, in the stop rule's blocks
/// ([`super::engine::stop_block`]), so each check follows a whole block.
pub fn campaign_plan_request(cfg: &CellConfig, nominal: &RobotModel) -> PlanRequest {
    let mut req = plan_request(cfg);
    if cfg.campaign.stop_when == StopWhen::Predicted && cfg.iso9283.is_none() {
        req.ident_block = Some(super::engine::stop_block(cfg, nominal));
    }
    req
}

/// Settle time after a move the plan's order assumes (s): the simulated robot's when the robot
/// is simulated, else [`REAL_SETTLE_S`].
fn settle_s(cfg: &CellConfig) -> f64 {
    match (&cfg.robot_controller.mode, &cfg.sim) {
        (DeviceMode::Sim, Some(sim)) => sim.settle_s(),
        (DeviceMode::Sim, None) => SimWorldConfig::default().settle_s(),
        _ => REAL_SETTLE_S,
    }
}

/// The constant joint speed the plan's order assumes (rad/s): a simulated robot's given
/// `[sim] move_speed_deg_s` on a realistic cell (`[sim] realistic = true`), else `None`: the
/// robot file's limits (a fast test cell's speeds are not meant to be a robot's: its campaigns
/// keep the order of the robot file, as README's pinned one and the tests' short campaigns).
fn move_speed_rad_s(cfg: &CellConfig) -> Option<f64> {
    match (cfg.robot_controller.mode, &cfg.sim) {
        (DeviceMode::Sim, Some(sim)) if sim.realistic => sim
            .move_speed_deg_s
            .map(|v| v.to_radians() / sim.time_scale),
        _ => None,
    }
}

/// Settle time of a real robot after a move that the plan's order assumes (s).
pub const REAL_SETTLE_S: f64 = 1.5;

/// Where the stage puts the ball at P2 relative to P1, flange frame (mm): the stage axis the
/// identification uses × the travel; zero when no pose measures P2 (an ISO 9283 campaign with
/// `measure_axis = false`).
pub fn stage_offset_mm(cfg: &CellConfig) -> Vector3<f64> {
    if cfg.iso9283.as_ref().is_some_and(|i| !i.measure_axis) {
        return Vector3::zeros();
    }
    identify_options(cfg).obs.stage_axis * cfg.stage.travel_mm
}

/// Capacity of a session's live event channel (a receiver further behind lags).
pub const EVENT_CAPACITY: usize = 1024;

/// Set up a campaign session on the store at `path` (opened, migrated, as the session's only
/// writer). `campaign` resumes a stored campaign (refused when it is done, or when its
/// configuration or robot model changed unless accepted); otherwise a new one is planned and
/// stored (the split is fixed before the first measurement). Before anything is planned or
/// stored this process takes the cell ([`CellLock`]: refused while another process commands
/// it); it then holds the cell and the campaign ([`CampaignLock`]) until the session is
/// dropped; only then are the
/// simulated devices (if any) started and the adapters built. Not cancel-safe: a dropped call may
/// leave a stored campaign that no session runs (and a simulated cell to be dropped).
pub async fn open_session(
    cfg: CellConfig,
    store_path: &Path,
    campaign: Option<Resume>,
    prompter: Arc<dyn Prompter>,
) -> Result<Session, SessionError> {
    let (path, checked) = (store_path.to_owned(), cfg.clone());
    // infeasible or unknown: refused before the store file is even created
    let store = tokio::task::spawn_blocking(move || {
        let mut nominal = load_robot(&checked.robot)?;
        nominal.tool = Vector3::from(checked.campaign.tool_mm);
        feasibility::check_session(&checked, &nominal, &path, campaign.map(|r| r.id))?;
        Ok::<_, SessionError>(Store::open(&path)?)
    })
    .await
    .map_err(|e| SessionError::Invalid(format!("store task failed: {e}")))??;
    open_session_with(
        cfg,
        StoreHandle::new(store),
        campaign,
        prompter,
        EVENT_CAPACITY,
    )
    .await
}

/// [`open_session`] on an open store (the caller's writer, shared with the engine) with a live
/// event channel of `capacity`. Planning and every store call run on blocking threads, never
/// on the async runtime's workers. Not cancel-safe (see [`open_session`]).
pub async fn open_session_with(
    cfg: CellConfig,
    store: StoreHandle,
    campaign: Option<Resume>,
    prompter: Arc<dyn Prompter>,
    capacity: usize,
) -> Result<Session, SessionError> {
    let mut nominal: RobotModel = load_robot(&cfg.robot)?;
    nominal.tool = Vector3::from(cfg.campaign.tool_mm);
    // before a campaign is stored: no session without the controller's secret
    let robot_secret = crate::cell::controller_secret(&cfg.robot_controller)?;
    let robot_text = std::fs::read_to_string(&cfg.robot).unwrap_or_default();
    let req = campaign_plan_request(&cfg, &nominal);
    let prepared = {
        let (store, nominal, req, cfg) = (store.clone(), nominal.clone(), req.clone(), cfg.clone());
        tokio::task::spawn_blocking(move || {
            let cell = take_cell(&store, &cfg, campaign.map(|r| r.id))?;
            let mut prepared = plan_and_store(&store, &nominal, &req, &cfg, campaign, robot_text)?;
            if let Some((mut cell, previous)) = cell {
                cell.set_campaign(prepared.campaign_id)?;
                if let Some(h) = previous {
                    let text = format!(
                        "took over the cell ({}) from {h}, which died holding it",
                        h.cell
                    );
                    store.blocking(|s| note(s, prepared.campaign_id, text))?;
                }
                prepared.cell = Some(cell);
            }
            Ok::<_, SessionError>(prepared)
        })
        .await
        .map_err(|e| SessionError::Invalid(format!("planning task failed: {e}")))??
    };
    let Prepared {
        campaign_id,
        plan,
        iso,
        own_of_resumed,
        lock,
        cell,
        plan_request: req,
        estimate: stored,
    } = prepared;
    let sim = simulated_cell(&cfg, &nominal, robot_secret.clone()).await?;
    let devices = cell_devices(&cfg, &nominal, sim.as_ref(), robot_secret, prompter)?;
    let resumed = own_of_resumed.is_some();
    let mut cfg = cfg;
    if let Some(v) = cfg.iso9283.as_ref().and_then(|i| i.speed_pct) {
        // the ISO campaign's speed, for every move of the campaign
        cfg.robot_controller.speed_pct = v;
    }
    if let Some((model, terms)) = own_of_resumed {
        // identify as the campaign was created to: its model and its terms
        cfg.campaign.model = model;
        cfg.campaign.nongeometric = terms;
    }
    // a campaign created now: the estimate stored with it (computed once); else afresh
    let estimate = match stored {
        Some(e) => Some(e),
        None => {
            let (cfg, nominal, req, plan) =
                (cfg.clone(), nominal.clone(), req.clone(), plan.clone());
            tokio::task::spawn_blocking(move || {
                super::estimate::estimate_campaign_time(&cfg, &nominal, &req, &plan)
            })
            .await
            .ok()
        }
    };
    Ok(Session {
        ctx: CampaignContext {
            cfg,
            nominal,
            plan_request: req,
            plan,
            store,
            campaign_id,
            control: Control::new(capacity),
            on_fault: FaultPolicy::default(),
            iso,
            estimate,
        },
        devices,
        sim,
        resumed,
        lock,
        cell,
    })
}

/// Take the cell for this process ([`CellKey::of`] the configuration and the store's file),
/// before anything is planned or stored. Blocking.
fn take_cell(
    store: &StoreHandle,
    cfg: &CellConfig,
    campaign: Option<i64>,
) -> Result<Option<(CellLock, Option<super::cell_lock::CellHolder>)>, SessionError> {
    let path = store.blocking(|s| s.path().map(Path::to_owned));
    let Some(key) = CellKey::of(cfg, path.as_deref()) else {
        return Ok(None);
    };
    let store_path = path.unwrap_or_else(|| ":memory:".into());
    Ok(Some(CellLock::acquire(
        &lock_dir(cfg),
        &key,
        &store_path,
        campaign,
    )?))
}

/// A campaign ready to run: new or resumed, held by this process.
struct Prepared {
    campaign_id: i64,
    plan: Plan,
    /// The ISO 9283 plan of an ISO campaign.
    iso: Option<IsoPlan>,
    /// The observation model and the terms a resumed campaign was created with.
    own_of_resumed: Option<(ObsModel, Vec<TermFamily>)>,
    lock: CampaignLock,
    /// The cell, once [`open_session_with`] has recorded the campaign in it.
    cell: Option<CellLock>,
    /// The planning request of the campaign (a resumed one's own seed and pose counts).
    plan_request: PlanRequest,
    /// The estimate stored with a campaign created now (`None`: resumed, or not estimated).
    estimate: Option<CampaignEstimate>,
}

/// Check a campaign to resume (or plan and store a new one), then take it for this process
/// and journal what the operator should know (a lock taken over, accepted changes).
/// Blocking: planning may take seconds.
fn plan_and_store(
    store: &StoreHandle,
    nominal: &RobotModel,
    req: &PlanRequest,
    cfg: &CellConfig,
    campaign: Option<Resume>,
    robot_text: String,
) -> Result<Prepared, SessionError> {
    let resumed = store.blocking(|s| {
        match campaign {
            None => feasibility::check_new(cfg, nominal)?,
            Some(r) => feasibility::check_resumed(cfg, nominal, s, r.id)?,
        }
        campaign
            .map(|r| {
                let config = (cfg.text.as_str(), cfg.campaign.nongeometric.as_slice());
                stored_campaign(s, r, config, &robot_text)
            })
            .transpose()
    })?;
    // a resumed calibration's hub is planned from its own request (its seed and pose counts,
    // which a creation's overrides may have set), as when it was created
    let own_req = match &resumed {
        Some(s) if s.iso.is_none() => own_request(req, s),
        _ => req.clone(),
    };
    let fresh = plan_campaign(nominal, &own_req)?;
    let (campaign_id, plan, iso, own_of_resumed, accepted_changes, estimate) = match resumed {
        Some(s) if s.iso.is_some() || cfg.iso9283.is_some() => {
            let iso =
                match (s.iso, cfg.iso9283.is_some()) {
                    (Some(iso), true) => iso,
                    _ => {
                        return Err(SessionError::Invalid(format!(
                        "campaign {} is {} campaign: resume it with a configuration {} [iso9283]",
                        s.id,
                        if cfg.iso9283.is_some() { "a calibration" } else { "an ISO 9283" },
                        if cfg.iso9283.is_some() { "without" } else { "with its" },
                    )))
                    }
                };
            let plan = iso_engine_plan(nominal, req, &iso)?;
            (
                s.id,
                plan,
                Some(iso),
                Some((s.model, s.nongeometric)),
                s.accepted_changes,
                None,
            )
        }
        None if cfg.iso9283.is_some() => {
            let iso = plan_new_iso(cfg, nominal, req, &fresh.drift_reference)?;
            let plan = iso_engine_plan(nominal, req, &iso)?;
            let (id, _) = store.blocking(|s| {
                store_new_campaign(s, cfg, (nominal, req), robot_text, &plan, Some(&iso))
            })?;
            (id, plan, Some(iso), None, Vec::new(), None)
        }
        Some(s) => {
            // a stored plan whose moves cannot all be routed is refused before anything moves
            let mut router =
                campaign_router(nominal, req, &fresh.drift_reference).map_err(PlanError::from)?;
            let via_points = count_via_points(&mut router, req.drift_every, &s.poses)
                .map_err(PlanError::from)?;
            let (sampling_order_s, planned_order_s) =
                order_times(nominal, req, &mut router, &s.poses);
            let plan = Plan {
                poses: s.poses,
                drift_reference: fresh.drift_reference,
                via_points,
                approach: Default::default(),
                sampling_order_s,
                planned_order_s,
            };
            (
                s.id,
                plan,
                None,
                Some((s.model, s.nongeometric)),
                s.accepted_changes,
                None,
            )
        }
        None => {
            let (id, estimate) = store.blocking(|s| {
                store_new_campaign(s, cfg, (nominal, req), robot_text, &fresh, None)
            })?;
            (id, fresh, None, None, Vec::new(), estimate)
        }
    };
    if !plan.poses.iter().any(|p| p.set == PoseSet::Ident) {
        return Err(SessionError::Invalid(format!(
            "campaign {campaign_id} has no identification poses"
        )));
    }
    let (lock, took_over) = CampaignLock::acquire(store, campaign_id)?;
    store.blocking(|s| {
        if let Some(h) = took_over {
            let text = format!("took over the campaign from {h}, which no longer runs");
            note(s, campaign_id, text)?;
        }
        for (what, keys) in accepted_changes {
            let text = format!(
                "resumed with a changed {what} (accepted): {}",
                keys.join(", ")
            );
            note(s, campaign_id, text)?;
        }
        Ok::<_, SessionError>(())
    })?;
    Ok(Prepared {
        campaign_id,
        plan,
        iso,
        own_of_resumed,
        lock,
        cell: None,
        plan_request: own_req,
        estimate,
    })
}

/// The planning request a stored calibration was created with: the configuration's cell and
/// workspace, the campaign's own seed, pose count and identification count.
fn own_request(req: &PlanRequest, s: &StoredCampaign) -> PlanRequest {
    PlanRequest {
        seed: s.seed,
        poses: s.poses.len(),
        ident: s.poses.iter().filter(|p| p.set == PoseSet::Ident).count(),
        ..req.clone()
    }
}

/// A stored campaign that may be resumed.
struct StoredCampaign {
    id: i64,
    model: ObsModel,
    /// The non-geometric terms it identifies (its stored configuration's).
    nongeometric: Vec<TermFamily>,
    /// The planning seed it was created with.
    seed: u64,
    poses: Vec<PlanEntry>,
    /// The stored ISO 9283 plan of an ISO campaign.
    iso: Option<IsoPlan>,
    accepted_changes: Vec<(&'static str, Vec<String>)>,
}

/// Load campaign `r.id` to resume it, refusing a done campaign and (unless accepted) changed
/// files.
fn stored_campaign(
    store: &Store,
    r: Resume,
    (config_text, current_terms): (&str, &[TermFamily]),
    robot_text: &str,
) -> Result<StoredCampaign, SessionError> {
    let row = store.campaign(r.id)?;
    if row.state == StoredState::Done {
        return Err(SessionError::Done(r.id));
    }
    let changes = config_changes(&row, config_text, robot_text);
    if let (Some((what, keys)), false) = (changes.first(), r.accept_changed_config) {
        return Err(SessionError::ConfigChanged {
            id: r.id,
            what,
            keys: keys.clone(),
        });
    }
    let poses = store
        .plan(r.id)?
        .into_iter()
        .map(|p| PlanEntry {
            index: p.index,
            set: p.set,
            q_rad: p.q_rad,
        })
        .collect();
    let iso = match store.campaign_kind(r.id)? {
        Some(k) if k.kind == ISO9283_KIND => {
            Some(serde_json::from_str(&k.plan_json).map_err(|e| {
                SessionError::Invalid(format!("campaign {}: its stored ISO plan: {e}", r.id))
            })?)
        }
        _ => None,
    };
    // an imported campaign has no stored configuration: the current one's terms
    let nongeometric = parse_cell_config(&row.config_toml, Path::new("stored configuration"))
        .ok()
        .filter(|_| !row.config_toml.trim().is_empty())
        .map(|c| c.campaign.nongeometric);
    Ok(StoredCampaign {
        id: r.id,
        model: row.model.parse().map_err(|e| {
            SessionError::Invalid(format!("campaign {}: its stored model: {e}", r.id))
        })?,
        nongeometric: nongeometric.unwrap_or_else(|| current_terms.to_vec()),
        seed: row.seed,
        poses,
        iso,
        accepted_changes: changes,
    })
}

/// The ISO request of `[iso9283]` (the cube defaults to the campaign box's centre and smallest
/// edge).
fn iso_request(cfg: &CellConfig) -> Option<IsoRequest> {
    let i = cfg.iso9283.as_ref()?;
    let c = &cfg.campaign;
    Some(IsoRequest {
        cube_center_mm: Vector3::from(i.cube_center_mm.unwrap_or(c.box_center_mm)),
        cube_edge_mm: i
            .cube_edge_mm
            .unwrap_or_else(|| c.box_size_mm.iter().copied().fold(f64::INFINITY, f64::min)),
        diagonal_fraction: i.diagonal_fraction,
        approach_dir: i.approach_vector()?,
        approach_mm: i.approach_mm,
        rotation: i
            .orientation_deg
            .map(|r| from_rotation_vector(&Vector3::from(r).map(f64::to_radians))),
        cycles: i.cycles,
    })
}

/// Plan a new ISO campaign around `hub`: nominal joints, or compensated by the configured
/// corrected model.
fn plan_new_iso(
    cfg: &CellConfig,
    nominal: &RobotModel,
    req: &PlanRequest,
    hub: &[f64],
) -> Result<IsoPlan, SessionError> {
    let iso = iso_request(cfg)
        .ok_or_else(|| SessionError::Invalid("[iso9283]: no approach direction".into()))?;
    match cfg
        .iso9283
        .as_ref()
        .and_then(|i| i.compensated_model.as_ref())
    {
        None => Ok(plan_iso(nominal, req, &iso, hub, &Targeting::Nominal)?),
        Some(path) => {
            let identified = load_robot(path)?;
            let c = Compensator::new(nominal, &identified).map_err(|e| {
                SessionError::Invalid(format!("iso9283.compensated_model {}: {e}", path.display()))
            })?;
            Ok(plan_iso(
                nominal,
                req,
                &iso,
                hub,
                &Targeting::Compensated(&c),
            )?)
        }
    }
}

/// The engine's plan of an ISO campaign (every move routed, or refused before anything moves).
fn iso_engine_plan(
    nominal: &RobotModel,
    req: &PlanRequest,
    iso: &IsoPlan,
) -> Result<Plan, SessionError> {
    let mut router = campaign_router(nominal, req, &iso.hub_q_rad).map_err(PlanError::from)?;
    let via_points = iso
        .via_points(&mut router, req.drift_every)
        .map_err(PlanError::from)?;
    Ok(iso.to_plan(via_points))
}

/// Store a freshly planned campaign (plan, split, the verbatim files and, for an ISO campaign,
/// its ISO plan); returns its id.
/// The plan's poses as the store keeps them, in move order.
pub(crate) fn planned_poses(plan: &Plan) -> Vec<PlannedPose> {
    plan.poses
        .iter()
        .enumerate()
        .map(|(order, e)| PlannedPose {
            index: e.index,
            set: e.set,
            order,
            q_rad: e.q_rad.clone(),
        })
        .collect()
}

fn store_new_campaign(
    store: &mut Store,
    cfg: &CellConfig,
    (nominal, req): (&RobotModel, &PlanRequest),
    robot_text: String,
    plan: &Plan,
    iso: Option<&IsoPlan>,
) -> Result<(i64, Option<CampaignEstimate>), SessionError> {
    let planned = planned_poses(plan);
    let new = NewCampaign {
        name: match iso {
            None => format!("{} {}", nominal.name, cfg.campaign.model),
            Some(_) => format!("{} {ISO9283_KIND}", nominal.name),
        },
        created_at_ms: now_unix_ms(),
        model: cfg.campaign.model.name().to_owned(),
        seed: cfg.campaign.seed,
        config_toml: cfg.text.clone(),
        robot_toml: robot_text,
    };
    Ok(match iso {
        // the estimate is stored with the campaign: shown the same until it is done
        None => {
            let estimate = estimate_campaign_time(cfg, nominal, req, plan);
            match super::time::estimate_json(&estimate) {
                Some(json) => (
                    store.create_campaign_estimated(&new, &planned, None, &json)?,
                    Some(estimate),
                ),
                None => (store.create_campaign(&new, &planned)?, None),
            }
        }
        Some(iso) => {
            let kind = CampaignKind {
                kind: ISO9283_KIND.to_owned(),
                plan_json: serde_json::to_string(iso)
                    .map_err(|e| SessionError::Invalid(e.to_string()))?,
            };
            (store.create_campaign_of_kind(&new, &planned, &kind)?, None)
        }
    })
}

/// Start the simulated cell when any device is simulated (`[sim]`, parsed and checked with the
/// configuration). Not cancel-safe: a drop once the cell started leaves its servers running
/// until the runtime ends.
async fn simulated_cell(
    cfg: &CellConfig,
    nominal: &RobotModel,
    robot_secret: SharedSecret,
) -> Result<Option<RunningSimCell>, SessionError> {
    let Some(world) = cfg.sim.clone().filter(|_| cfg.any_simulated()) else {
        return Ok(None);
    };
    let cell = start_cell_with(nominal.bare(), world, robot_secret, std::future::pending())
        .await
        .map_err(|e| SessionError::Sim {
            path: cfg.path.display().to_string(),
            message: e.to_string(),
        })?;
    Ok(Some(cell))
}

/// The device adapters: to the simulated cell's devices where simulated, else to the
/// configured addresses; either way with every device setting of the configuration (the
/// simulated cell only supplies the defaults a section leaves unset).
fn cell_devices(
    cfg: &CellConfig,
    nominal: &RobotModel,
    sim: Option<&RunningSimCell>,
    robot_secret: SharedSecret,
    prompter: Arc<dyn Prompter>,
) -> Result<Devices, SessionError> {
    let tracker = match (sim, cfg.tracker.mode) {
        (Some(s), DeviceMode::Sim) => s.tracker_config(),
        _ => EmsconTrackerConfig {
            address: cfg.tracker.address.clone(),
            ..EmsconTrackerConfig::default()
        },
    };
    let robot: Box<dyn crate::cell::Robot> = match cfg.robot_controller.protocol {
        RobotProtocol::Robotlink => {
            let robot = match (sim, cfg.robot_controller.mode) {
                (Some(s), DeviceMode::Sim) => s.robot_config(),
                _ => LinkRobotConfig {
                    address: cfg.robot_controller.address.clone(),
                    secret: Some(robot_secret),
                    ..LinkRobotConfig::default()
                },
            };
            Box::new(LinkRobot::new(robot.with_section(&cfg.robot_controller)))
        }
        RobotProtocol::Ur => {
            let limits = MotionLimits::of(nominal, 100.0);
            let mut ur = UrRobotConfig::from_section(&cfg.robot_controller, limits);
            if let (Some(s), DeviceMode::Sim) = (sim, cfg.robot_controller.mode) {
                s.ur_robot_config(&cfg.robot_controller, &mut ur)
                    .map_err(|e| SessionError::Invalid(e.to_string()))?;
            }
            Box::new(UrRobot::new(ur))
        }
    };
    Ok(Devices {
        tracker: Box::new(EmsconTracker::new(tracker.with_section(&cfg.tracker))),
        robot,
        stage: stage_device(cfg, sim, prompter)?,
    })
}

/// The stage adapter: a Zaber stage, or a micrometer the technician sets (followed by the
/// simulated world when simulated).
fn stage_device(
    cfg: &CellConfig,
    sim: Option<&RunningSimCell>,
    prompter: Arc<dyn Prompter>,
) -> Result<Box<dyn crate::cell::Stage>, SessionError> {
    Ok(match cfg.stage.kind {
        StageMode::Serial => {
            let device = match (sim, cfg.stage.mode) {
                (Some(s), DeviceMode::Sim) => s.stage_config().ok_or_else(|| {
                    SessionError::Invalid("the simulated cell has no serial stage".into())
                })?,
                _ => ZaberStageAdapterConfig {
                    port: cfg.stage.serial_path.clone(),
                    ..ZaberStageAdapterConfig::default()
                },
            };
            Box::new(ZaberStageAdapter::new(device.with_section(&cfg.stage)))
        }
        StageMode::Manual | StageMode::ManualGauge => {
            let manual = ManualStageConfig {
                tolerance_mm: cfg.stage.tolerance_mm,
                max_tries: cfg.stage.max_tries,
                confirm_clear: cfg.stage.confirm_clear(),
            };
            match (sim, cfg.stage.mode) {
                // the simulated micrometer follows the technician's answers (typed readings:
                // the simulated cell has no gauge that follows a confirmation)
                (Some(s), DeviceMode::Sim) => Box::new(ManualStage::new(
                    Arc::new(SimTechnician::new(prompter, s.world.clone())),
                    manual,
                )),
                _ if cfg.stage.kind == StageMode::ManualGauge => {
                    let gauge = ManualStage::with_gauge_port(
                        prompter,
                        &cfg.stage.gauge_path,
                        zaber::GaugeConfig::default(),
                        manual,
                    )
                    .map_err(|e| {
                        SessionError::Invalid(format!(
                            "{}: stage.gauge_path: {} (stage.kind = \"manual_gauge\" reads the \
                             micrometer there)",
                            cfg.path.display(),
                            e.message
                        ))
                    })?;
                    Box::new(gauge)
                }
                _ => Box::new(ManualStage::new(prompter, manual)),
            }
        }
    })
}

/// The `[campaign]` keys a campaign keeps as it was created (a request may override them):
/// a resume plans and identifies with its own, whatever the configuration says now.
const CAMPAIGN_OWN: [&str; 5] = [
    "campaign.poses",
    "campaign.ident",
    "campaign.seed",
    "campaign.model",
    "campaign.nongeometric",
];

/// The configuration keys and robot-model keys that differ from the campaign's stored files
/// (the simulated world's `[sim]` table is not the cell's configuration and is skipped, nor is
/// `robot_controller.secret_file`: who may drive the robot, not what is measured, nor the
/// campaign's own keys, [`CAMPAIGN_OWN`]).
fn config_changes(
    row: &CampaignRow,
    config_text: &str,
    robot_text: &str,
) -> Vec<(&'static str, Vec<String>)> {
    [
        (
            "configuration",
            changed_keys(&row.config_toml, config_text, &["sim", "lock_dir"])
                .into_iter()
                .filter(|k| {
                    k != "robot_controller.secret_file" && !CAMPAIGN_OWN.contains(&k.as_str())
                })
                .collect(),
        ),
        (
            "robot model",
            changed_keys(&row.robot_toml, robot_text, &[]),
        ),
    ]
    .into_iter()
    .filter(|(_, keys)| !keys.is_empty())
    .collect()
}

/// Journal a note in the store (before the engine runs).
fn note(store: &mut Store, id: i64, text: String) -> Result<(), SessionError> {
    Ok(super::lock::journal_note(store, id, text)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_cell_config;

    /// A campaign created now carries the estimate stored with it to the session (computed
    /// once, not again for the session).
    #[test]
    fn a_new_campaign_hands_the_estimate_it_stored_to_the_session() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml");
        let text = std::fs::read_to_string(&path)
            .expect("config")
            .replacen("poses = 300", "poses = 40", 1)
            .replacen("ident = 100", "ident = 20", 1);
        let cfg = parse_cell_config(&text, &path).expect("config parses");
        let mut nominal = load_robot(&cfg.robot).expect("robot");
        nominal.tool = Vector3::from(cfg.campaign.tool_mm);
        let dir = tempfile::tempdir().expect("tempdir");
        let store = StoreHandle::new(Store::open(&dir.path().join("c.db")).expect("store"));
        let req = campaign_plan_request(&cfg, &nominal);
        let p = plan_and_store(&store, &nominal, &req, &cfg, None, String::new()).expect("stored");
        let id = p.campaign_id;
        let stored = store
            .blocking(|s| super::super::time::stored_estimate(s, id))
            .expect("read");
        assert!(p.estimate.is_some(), "a new campaign is estimated");
        assert_eq!(p.estimate, stored);
    }
}
