//! The long-running campaign service behind `cellcal serve`: one cell, at most one campaign
//! loaded at a time, driven by the engine's commands and watched through its events. Front ends
//! (the REST API in [`crate::api`], later a web page) are thin clients of this.
//!
//! # Responsiveness
//! The daemon owns one store writer ([`StoreHandle`], shared with the loaded campaign's
//! engine) and a [`ReaderPool`]; every store call and the planning of a new campaign run on
//! blocking threads, never on the async runtime's workers. The slot of the loaded campaign is
//! a plain mutex held only for short, non-blocking sections: a campaign being created is
//! marked `creating` and planned outside it, so reads and commands never wait for planning.
//!
//! # State owners
//! Four: the store's two handles (writer, readers: their locks live in `store/`); the slot
//! (`Slot`: the loaded campaign, `creating`, `closing`); per loaded run one `RunWatch`
//! (`status.rs`: the engine's state, the open technician question and the outcome, one `watch`
//! channel: the end is never seen without its outcome); and the devices' `CellWatch`
//! (`observe.rs`, kept across runs). The metrics registry counts, it decides nothing.
//!
//! # Live events
//! Every event is journalled before it is published, with its journal sequence number
//! ([`Journalled`]). [`Daemon::follow`] turns the live channel plus the journal into a
//! gap-free, duplicate-free sequence: it replays from the journal what the live channel lost
//! (a lagging reader, a reconnect with a last seen sequence number).

use std::path::Path;
use std::sync::{Arc, Mutex as StdMutex};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;

use crate::campaign::cell_lock::CellLockError;
use crate::campaign::lock::{is_dead, mark_interrupted};
use crate::campaign::report::{campaign_report, ReportError};
use crate::campaign::session::{open_session_with, Resume, SessionError, EVENT_CAPACITY};
use crate::campaign::stored::{load_stored, stored_model_toml, stored_result_json, StoredError};
use crate::campaign::time::{stored_estimate, CampaignEstimate, Elapsed};
use crate::campaign::{
    journal_event, run_campaign, CampaignCommand, CampaignEvent, Control, Journalled, Outcome,
};
use crate::cell::{Answer, ChannelPrompter, PendingPrompt, PromptContext, CONFIRM_CLEAR};
use crate::config::{CampaignSection, CellConfig};
use crate::dataset::PoseSet;
use crate::metrics::Metrics;
use crate::progress::Progress;
use crate::store::{
    CampaignRow, LockHolder, ReaderPool, Store, StoreError, StoreHandle, StoredState,
};

mod observe;
mod status;
mod time;
use observe::{CellWatch, Observer};
pub use observe::{Connection, DeviceView, DevicesView, FaultView};
pub use status::RunOutcome;
use status::RunWatch;
pub use time::EstimateView;

/// Why a daemon request failed (the API maps each variant to an HTTP status).
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// A request value is invalid.
    #[error("{0}")]
    BadRequest(String),
    /// No such campaign.
    #[error("no campaign {0}")]
    NotFound(i64),
    /// The request conflicts with the cell's current use.
    #[error("{0}")]
    Conflict(String),
    /// The store failed (its message names the campaign store).
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The campaign session could not be set up.
    #[error(transparent)]
    Session(#[from] SessionError),
    /// A daemon task panicked or was cancelled.
    #[error("daemon task failed: {0}")]
    Task(String),
    /// A stored campaign cannot be rebuilt (its stored configuration, model or result).
    #[error(transparent)]
    Stored(StoredError),
}

/// Campaign settings a client may change from the configuration's `[campaign]` defaults.
#[derive(Debug, Clone, Default, PartialEq, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CampaignOverrides {
    /// Total poses.
    pub poses: Option<usize>,
    /// Identification poses (the rest verify).
    pub ident: Option<usize>,
    /// Planning seed.
    pub seed: Option<u64>,
    /// Observation model: `position`, `np`, `op` or `full`.
    pub model: Option<String>,
    /// Families of non-geometric joint terms identified with the geometry: `compliance`,
    /// `harmonics` (each at most once; `[]`: a geometric identification).
    pub nongeometric: Option<Vec<String>>,
}

impl CampaignOverrides {
    /// Apply to a configuration, with the same checks as the configuration file
    /// ([`crate::config::CampaignSection::check`]), and write the overridden keys into its text
    /// (comments and everything else kept): the campaign stores the configuration it runs with,
    /// so a resume, `identify --store` and the report read the overrides back.
    pub fn apply(&self, cfg: &mut CellConfig) -> Result<(), DaemonError> {
        self.apply_values(cfg)?;
        cfg.text = self.written_into(&cfg.text, &cfg.campaign)?;
        let back = crate::config::parse_cell_config(&cfg.text, &cfg.path)
            .map_err(|e| DaemonError::BadRequest(format!("the overridden configuration: {e}")))?;
        if back.campaign != cfg.campaign {
            return Err(DaemonError::BadRequest(
                "the overrides do not read back from the configuration text".into(),
            ));
        }
        Ok(())
    }

    /// The overridden `[campaign]` keys of `text` set to their values in `c`.
    fn written_into(&self, text: &str, c: &CampaignSection) -> Result<String, DaemonError> {
        use toml_edit::{value, Array, DocumentMut, Item};
        let mut doc: DocumentMut = text
            .parse()
            .map_err(|e| DaemonError::BadRequest(format!("the configuration text: {e}")))?;
        let count = |key: &str, n: u64| {
            i64::try_from(n)
                .map(value)
                .map_err(|_| DaemonError::BadRequest(format!("campaign.{key}: {n} is too large")))
        };
        let t = &mut doc["campaign"];
        // a key the file has keeps its place and comments
        let mut set = |key: &str, new: Item| match t.get_mut(key) {
            Some(Item::Value(v)) => {
                let decor = v.decor().clone();
                if let Item::Value(mut n) = new {
                    *n.decor_mut() = decor;
                    *v = n;
                }
            }
            _ => t[key] = new,
        };
        if self.poses.is_some() {
            set("poses", count("poses", c.poses as u64)?);
        }
        if self.ident.is_some() {
            set("ident", count("ident", c.ident as u64)?);
        }
        if self.seed.is_some() {
            set("seed", count("seed", c.seed)?);
        }
        if self.model.is_some() {
            set("model", value(c.model.name()));
        }
        if self.nongeometric.is_some() {
            let names: Array = c.nongeometric.iter().map(|f| f.name()).collect();
            set("nongeometric", value(names));
        }
        Ok(doc.to_string())
    }

    /// The overrides into `cfg`'s `[campaign]` values, checked.
    fn apply_values(&self, cfg: &mut CellConfig) -> Result<(), DaemonError> {
        let c = &mut cfg.campaign;
        if let Some(m) = &self.model {
            c.model = m
                .parse()
                .map_err(|e| DaemonError::BadRequest(format!("campaign.model: {e}")))?;
        }
        if let Some(names) = &self.nongeometric {
            c.nongeometric = names
                .iter()
                .map(|n| n.parse())
                .collect::<Result<_, _>>()
                .map_err(|e| DaemonError::BadRequest(format!("campaign.nongeometric: {e}")))?;
        }
        c.poses = self.poses.unwrap_or(c.poses);
        c.ident = self.ident.unwrap_or(c.ident);
        c.seed = self.seed.unwrap_or(c.seed);
        c.check()
            .map_err(|e| DaemonError::BadRequest(e.to_string()))
    }
}

/// A command from a client.
#[derive(Debug, Clone, PartialEq, Deserialize, utoipa::ToSchema)]
#[serde(tag = "command", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientCommand {
    /// Allow motion.
    Arm,
    /// Disallow motion: a running campaign stops the robot and the stage at once and pauses
    /// (resumable once armed again); the engine moves nothing while disarmed.
    Disarm,
    /// Start, or resume a stored campaign (requires arm). While running: nothing to do (200).
    Start,
    /// Pause after the current pose (or setup or re-registration point). Answers at once;
    /// while the engine waits for a technician question, the question stays open and the pause
    /// takes effect after its answer (the view's `pausing` says a pause is pending). Refused
    /// before the start and while identifying.
    Pause,
    /// Resume a paused campaign (after an operator fault: retries the step), or start a stored
    /// campaign loaded to be resumed (aborted, failed, interrupted: as `cellcal run --campaign N
    /// --arm`, the tracker frame checked at the start). Requires arm; while running it withdraws
    /// a pending pause; refused before the start of a new campaign and while identifying.
    Resume,
    /// Resume (as `resume`), re-registering the tracker frame if it is found moved (a new frame
    /// segment). Refused unless paused or a stored campaign waits for its start.
    Reregister,
    /// Stop the robot now; the campaign stays resumable.
    Abort,
    /// Answer the technician question `seq`: a reading (`value_mm`), a confirmation (no
    /// value) or `abort: true`.
    Answer {
        /// Sequence number of the question (from the `prompt` event or the status).
        seq: u64,
        /// The reading (mm), when the question asks for a number.
        value_mm: Option<f64>,
        /// Abort instead of answering.
        #[serde(default)]
        abort: bool,
    },
    /// Confirm the cell clear: the answer to the open `confirm_clear` question `seq` (asked
    /// after a manual stage answer; the robot moves only after it). No other question takes
    /// it, and `answer` does not answer that one.
    ConfirmClear {
        /// Sequence number of the `confirm_clear` question.
        seq: u64,
    },
}

/// What `POST /api/cell/stop` stopped.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct CellStopView {
    /// The campaign that was loaded and running (now aborted), or null when none was.
    pub campaign: Option<i64>,
    /// Its state after the stop (`aborted`, or the final state it had reached), null without
    /// a campaign.
    pub state: Option<String>,
    /// The robot's answer to the stop: `stopped`, or why not (`not connected`, …); null when
    /// no campaign was running (the daemon holds no device connection then: nothing moves).
    pub robot: Option<String>,
    /// The stage's answer: `stopped`, `manual` (nothing motorised), or why not; null as
    /// `robot`.
    pub stage: Option<String>,
}

/// A question waiting for the technician, as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct PromptView {
    /// Answer with this sequence number.
    pub seq: u64,
    /// Short id (`stage_move`, …).
    pub id: String,
    /// The text shown to the technician.
    pub text: String,
    /// Expected numeric answer (mm), if a number is asked for.
    pub expected_mm: Option<f64>,
    /// What the engine is doing: pose n of N, P1 or P2, whether the robot stands still, why
    /// the question is asked again.
    #[serde(flatten)]
    pub context: PromptContext,
}

/// A campaign as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct CampaignView {
    /// Campaign id.
    pub id: i64,
    /// Human name.
    pub name: String,
    /// Creation time (ms since the Unix epoch).
    pub created_at_ms: i64,
    /// Last stored state (`idle`, `armed`, `running`, `paused`, `identifying`, `done`,
    /// `aborted`, `failed`, or `created` before the engine first ran), or `interrupted`: stored
    /// in a state of a run whose process is gone (nothing of it moves; resumable).
    pub state: String,
    /// Observation model.
    pub model: String,
    /// Poses measured.
    pub poses_done: usize,
    /// Poses planned.
    pub poses_total: usize,
    /// Loaded in the daemon (its engine is waiting or running).
    pub loaded: bool,
    /// Motion allowed (loaded campaigns only).
    pub armed: bool,
    /// How the last run of this daemon ended (`done`, `aborted`, `failed: …`), if it ended.
    pub last_outcome: Option<String>,
    /// A pause was asked for while running and is not taken yet: it takes effect before the
    /// next pose (or setup or re-registration point), once the open question, if any, is
    /// answered; `resume` withdraws it.
    pub pausing: bool,
    /// The question waiting for the technician, if any.
    pub prompt: Option<PromptView>,
    /// A result is stored.
    pub has_result: bool,
    /// The stored result's verdict (`ok`, `warning`, `poor`), if any.
    pub quality: Option<String>,
    /// The planned duration, stored with the campaign when it was created (the same before
    /// and after a restart); null for a campaign created without one.
    pub estimate: Option<EstimateView>,
    /// Time spent measuring so far (s): in the state `running` (setup, moves, readings,
    /// technician answers, drift checks), pauses excluded; from the journal's times, up to
    /// now while it runs.
    pub measuring_s: f64,
    /// Time spent paused so far (s), by the operator or a fault.
    pub paused_s: f64,
}

/// One measured pose as an identification row (what `cellcal export` writes as a CSV row).
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct MeasurementRow {
    /// Plan pose index.
    pub pose: usize,
    /// `ident` or `verify`.
    pub set: &'static str,
    /// Joints read back after settling (rad).
    pub q_rad: Vec<f64>,
    /// Ball at stage position P1 (mm, the campaign's first tracker frame).
    pub p1_mm: [f64; 3],
    /// Ball at stage position P2 (mm), when measured.
    pub p2_mm: Option<[f64; 3]>,
}

/// A campaign's stored plan.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct PlanView {
    /// Campaign id.
    pub campaign: i64,
    /// Poses planned.
    pub poses_total: usize,
    /// Identification poses.
    pub ident: usize,
    /// Verification poses.
    pub verify: usize,
    /// Poses with a done mark.
    pub done: usize,
    /// Every pose, in move order.
    pub poses: Vec<PlannedPoseView>,
}

/// One planned pose.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct PlannedPoseView {
    /// Pose index (the pose id in exports and `measured` events).
    pub index: usize,
    /// `ident` or `verify`.
    pub set: &'static str,
    /// Position in the move order (0 first).
    pub order: usize,
    /// Commanded joint target (rad).
    pub q_rad: Vec<f64>,
    /// Measured and committed.
    pub done: bool,
}

/// Internal tuning of a daemon (defaults for production; tests shrink them).
#[derive(Debug, Clone, PartialEq)]
pub struct DaemonOptions {
    /// Capacity of a campaign's live event channel; a follower further behind replays the gap
    /// from the journal.
    pub event_capacity: usize,
    /// Pause after each live event a follower forwards: simulates a slow client (tests of the
    /// lag replay). Zero in production.
    pub follow_pace: Duration,
}

impl Default for DaemonOptions {
    fn default() -> DaemonOptions {
        DaemonOptions {
            event_capacity: EVENT_CAPACITY,
            follow_pace: Duration::ZERO,
        }
    }
}

/// Env var overriding [`DaemonOptions::event_capacity`] (tests).
pub const EVENT_CAPACITY_ENV: &str = "CELLCAL_EVENT_CAPACITY";
/// Env var setting [`DaemonOptions::follow_pace`] in ms (tests).
pub const FOLLOW_PACE_ENV: &str = "CELLCAL_FOLLOW_PACE_MS";

impl DaemonOptions {
    /// The defaults with [`EVENT_CAPACITY_ENV`] and [`FOLLOW_PACE_ENV`] applied when set.
    pub fn from_env() -> Result<DaemonOptions, DaemonError> {
        let mut o = DaemonOptions::default();
        if let Some(n) = env_number(EVENT_CAPACITY_ENV)? {
            if n == 0 {
                return Err(DaemonError::BadRequest(format!(
                    "{EVENT_CAPACITY_ENV}: must be at least 1"
                )));
            }
            o.event_capacity = usize::try_from(n).unwrap_or(usize::MAX);
        }
        if let Some(ms) = env_number(FOLLOW_PACE_ENV)? {
            o.follow_pace = Duration::from_millis(ms);
        }
        Ok(o)
    }
}

/// A non-negative integer from the environment variable `name`, if set.
fn env_number(name: &str) -> Result<Option<u64>, DaemonError> {
    match std::env::var(name) {
        Err(_) => Ok(None),
        Ok(v) => v.trim().parse().map(Some).map_err(|_| {
            DaemonError::BadRequest(format!("{name}: `{v}` is not a non-negative integer"))
        }),
    }
}

/// One item a follower ([`Daemon::follow`]) delivers.
#[derive(Debug, Clone, PartialEq)]
pub enum Followed {
    /// A journal entry (replayed or live), in sequence order, each once.
    Entry(Journalled),
    /// The live channel lost `count` entries; they were replayed from the journal just before.
    Replayed {
        /// Entries read back from the journal.
        count: usize,
    },
}

struct Loaded {
    id: i64,
    control: Control,
    /// The run's state, open question and outcome (ended: the engine has returned, its final
    /// state journalled).
    status: RunWatch,
    task: JoinHandle<()>,
    /// The journal's last sequence number before this run: older terminal states are history.
    run_start: i64,
    /// Loaded from the store (a stored campaign to resume), not created by this run's load.
    resumed: bool,
}

impl Loaded {
    /// Its engine has not returned (once it has, the campaign is let go and no longer loaded,
    /// though the task may still stop the simulated cell).
    fn running(&self) -> bool {
        !self.status.has_ended() && !self.task.is_finished()
    }
}

/// The cell's one campaign slot.
#[derive(Default)]
struct Slot {
    loaded: Option<Loaded>,
    /// A campaign is being planned/loaded (outside the lock).
    creating: bool,
    /// Shutting down: no new campaign is loaded.
    closing: bool,
}

/// Journal entries read per replay query.
const REPLAY_PAGE: usize = 512;

/// The live side of a follower: the channel, the run's first sequence number and its status.
struct Live {
    rx: broadcast::Receiver<Journalled>,
    run_start: i64,
    status: RunWatch,
}

/// The campaign service.
pub struct Daemon {
    cfg: CellConfig,
    opts: DaemonOptions,
    /// The only writer; the loaded campaign's engine shares it.
    writer: StoreHandle,
    readers: Arc<ReaderPool>,
    slot: StdMutex<Slot>,
    metrics: Arc<Metrics>,
    cell: Arc<StdMutex<CellWatch>>,
}

fn lock<T>(m: &StdMutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Session errors that are a conflict with the campaign's state, not a daemon failure: a done
/// campaign, a changed configuration, a campaign another process runs, a cell another process
/// commands, a stored plan that cannot be routed (`resumed`).
fn refusal(e: SessionError, resumed: bool) -> DaemonError {
    match e {
        SessionError::Done(_)
        | SessionError::ConfigChanged { .. }
        | SessionError::Cell(CellLockError::Busy { .. })
        | SessionError::Store(StoreError::Locked { .. }) => DaemonError::Conflict(e.to_string()),
        e @ SessionError::Plan(_) if resumed => DaemonError::Conflict(e.to_string()),
        // a new campaign's plan follows the client's overrides
        e @ SessionError::Plan(_) => DaemonError::BadRequest(e.to_string()),
        // an infeasible campaign is the client's request to fix, before anything starts
        SessionError::Infeasible(f) => DaemonError::BadRequest(f.to_string()),
        // so is an ISO 9283 cube the robot cannot reach under the planning checks
        e @ SessionError::Iso(_) => DaemonError::BadRequest(e.to_string()),
        e => DaemonError::Session(e),
    }
}

/// Clears the `creating` mark when a load ends, however it ends (error, panic).
struct CreatingMark<'a>(&'a StdMutex<Slot>);

impl Drop for CreatingMark<'_> {
    fn drop(&mut self) {
        lock(self.0).creating = false;
    }
}

/// How a follower's forwarding step ended.
enum Forward {
    /// Keep following.
    More,
    /// The run ended or the client went away.
    Stop,
}

impl Daemon {
    /// A daemon for the cell of `cfg`, storing campaigns in `store_path` (created and
    /// migrated if needed), with [`DaemonOptions::from_env`]. Blocking (opens the store).
    pub fn new(cfg: CellConfig, store_path: &Path) -> Result<Daemon, DaemonError> {
        Daemon::with_options(cfg, store_path, DaemonOptions::from_env()?)
    }

    /// [`Daemon::new`] with explicit options. Blocking (opens the store).
    pub fn with_options(
        cfg: CellConfig,
        store_path: &Path,
        opts: DaemonOptions,
    ) -> Result<Daemon, DaemonError> {
        let mut writer = Store::open(store_path)?;
        for (id, was) in mark_interrupted(&mut writer)? {
            tracing::warn!(
                campaign = id,
                stored = was.name(),
                "campaign interrupted: the process that ran it is gone"
            );
        }
        Ok(Daemon {
            cfg,
            opts,
            writer: StoreHandle::new(writer),
            readers: ReaderPool::open(store_path)?,
            slot: StdMutex::new(Slot::default()),
            metrics: Arc::new(Metrics::new()),
            cell: Arc::default(),
        })
    }

    /// The daemon's metrics (the API adds its request latencies and serves them).
    pub fn metrics(&self) -> &Arc<Metrics> {
        &self.metrics
    }

    /// The cell's devices: what the configuration says and what the running campaign's events
    /// told (see [`observe`]). Never blocks.
    pub fn devices(&self) -> DevicesView {
        lock(&self.cell).view(&self.cfg)
    }

    /// Run `f` on a reader on a blocking thread. Cancel-safe: it only reads.
    async fn read<T: Send + 'static>(
        &self,
        f: impl FnOnce(&Store) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, DaemonError> {
        self.readers.read(f).await.map_err(|e| match e {
            StoreError::NoCampaign(id) => DaemonError::NotFound(id),
            StoreError::Task(t) => DaemonError::Task(t),
            e => DaemonError::Store(e),
        })
    }

    /// Every stored campaign. Cancel-safe (reads only).
    pub async fn list(&self) -> Result<Vec<CampaignView>, DaemonError> {
        let stored = self
            .read(|s| {
                s.list_campaigns()?
                    .into_iter()
                    .map(|r| stored_view(s, r))
                    .collect::<Result<Vec<_>, _>>()
            })
            .await?;
        Ok(stored.into_iter().map(|v| self.view_of(v)).collect())
    }

    /// The stored part of a view plus what the loaded slot knows.
    fn view_of(&self, v: StoredView) -> CampaignView {
        let slot = lock(&self.slot);
        let l = slot.loaded.as_ref().filter(|l| l.id == v.row.id);
        let prompt = l.and_then(|l| {
            l.status.read(|s| {
                s.prompt
                    .as_ref()
                    .filter(|p| p.is_open())
                    .map(|p| PromptView {
                        seq: p.seq,
                        id: p.prompt.id.clone(),
                        text: p.prompt.text.clone(),
                        expected_mm: p.prompt.expected_mm,
                        context: p.prompt.context.clone(),
                    })
            })
        });
        let here = l.is_some_and(Loaded::running);
        let live = here || v.holder.as_ref().is_some_and(|h| !is_dead(h));
        let (measuring_s, paused_s) = v.elapsed.seconds(live.then(crate::wall_clock::now_unix_ms));
        let state = match v.holder {
            Some(h) if !is_dead(&h) => v.row.state,
            // no live process runs it: a run's state is history
            _ if !here && v.row.state.is_run() => StoredState::Interrupted,
            _ => v.row.state,
        };
        CampaignView {
            id: v.row.id,
            name: v.row.name,
            created_at_ms: v.row.created_at_ms,
            state: state.name().to_owned(),
            model: v.row.model,
            poses_done: v.done,
            poses_total: v.total,
            loaded: l.is_some_and(Loaded::running),
            armed: l.is_some_and(|l| l.running() && l.control.is_armed()),
            last_outcome: l
                .and_then(|l| l.status.read(|s| s.outcome.as_ref().map(|o| o.to_string()))),
            pausing: l.is_some_and(|l| {
                l.running()
                    && *l.control.pause.borrow()
                    && l.status.read(|s| s.state) == Some(StoredState::Running)
            }),
            prompt,
            has_result: v.has_result,
            quality: v.quality,
            estimate: v.estimate.as_ref().map(EstimateView::of),
            measuring_s,
            paused_s,
        }
    }

    /// One campaign. Cancel-safe (reads only).
    pub async fn get(&self, id: i64) -> Result<CampaignView, DaemonError> {
        let v = self.read(move |s| stored_view(s, s.campaign(id)?)).await?;
        Ok(self.view_of(v))
    }

    /// Plan and store a new campaign from the configuration (plus `overrides`) and load it;
    /// nothing moves until it is armed and started. Planning runs on a blocking thread while
    /// the slot is only marked `creating`: reads and commands do not wait for it. Cancel-safe:
    /// the creation runs in its own task, so a dropped request still creates and loads the
    /// campaign (or fails) as a whole.
    pub async fn create(
        self: &Arc<Self>,
        overrides: &CampaignOverrides,
    ) -> Result<CampaignView, DaemonError> {
        let mut cfg = self.cfg.clone();
        overrides.apply(&mut cfg)?;
        let id = self.load(cfg, None).await?;
        self.get(id).await
    }

    /// Load campaign `id` unless it is loaded; a campaign still running blocks every other.
    /// Cancel-safe as [`Daemon::create`].
    async fn ensure_loaded(self: &Arc<Self>, id: i64) -> Result<(), DaemonError> {
        {
            let slot = lock(&self.slot);
            if slot
                .loaded
                .as_ref()
                .is_some_and(|l| l.running() && l.id == id)
            {
                return Ok(());
            }
        }
        self.get(id).await?;
        self.load(self.cfg.clone(), Some(id)).await?;
        Ok(())
    }

    /// Mark the slot `creating`, or say why the cell is busy.
    fn mark_creating(&self) -> Result<(), DaemonError> {
        let mut slot = lock(&self.slot);
        if slot.closing {
            return Err(DaemonError::Conflict("the daemon is stopping".into()));
        }
        if slot.creating {
            return Err(DaemonError::Conflict(
                "a campaign is being loaded on the cell; try again when it is".into(),
            ));
        }
        if let Some(l) = slot.loaded.as_ref().filter(|l| l.running()) {
            return Err(DaemonError::Conflict(format!(
                "campaign {} is loaded on the cell; abort it first",
                l.id
            )));
        }
        slot.creating = true;
        Ok(())
    }

    /// Open a session for `id` (or a new campaign) in its own task and load it. Cancel-safe:
    /// a dropped call leaves the task to finish loading.
    async fn load(self: &Arc<Self>, cfg: CellConfig, id: Option<i64>) -> Result<i64, DaemonError> {
        self.mark_creating()?;
        let me = Arc::clone(self);
        tokio::spawn(async move {
            let _mark = CreatingMark(&me.slot);
            me.open_and_install(cfg, id).await
        })
        .await
        .map_err(|e| DaemonError::Task(e.to_string()))?
    }

    /// The body of [`Daemon::load`]: session, engine task, prompt pump, then the slot. Not
    /// cancel-safe on its own (a dropped call may leave a stored campaign unloaded): it runs
    /// only inside the task [`Daemon::load`] spawns.
    async fn open_and_install(&self, cfg: CellConfig, id: Option<i64>) -> Result<i64, DaemonError> {
        let (prompter, prompts) = ChannelPrompter::new(4);
        let session = open_session_with(
            cfg,
            self.writer.clone(),
            id.map(Resume::strict),
            Arc::new(prompter),
            self.opts.event_capacity,
        )
        .await
        .map_err(|e| refusal(e, id.is_some()))?;
        let control = session.ctx.control.clone();
        let campaign_id = session.ctx.campaign_id;
        let resumed = session.resumed;
        let (run_start, (done, total)) = self
            .read(move |s| Ok((s.last_event_seq(campaign_id)?, s.pose_counts(campaign_id)?)))
            .await?;
        let status = RunWatch::new();
        self.observe_run(&session, run_start, status.clone());
        self.metrics.progress(done as u64, total as u64);
        tracing::info!(
            campaign = campaign_id,
            poses_done = done,
            poses_total = total,
            resumed = session.resumed,
            "campaign loaded"
        );
        let pump = tokio::spawn(pump_prompts(
            prompts,
            status.clone(),
            self.writer.clone(),
            campaign_id,
            control.clone(),
        ));
        let end = status.clone();
        let task = tokio::spawn(async move {
            let ctx = session.ctx;
            let mut devices = session.devices;
            let outcome = match run_campaign(&ctx, &mut devices).await {
                Ok(Outcome::Done(_) | Outcome::Iso(_)) => RunOutcome::Done,
                Ok(Outcome::Aborted) => RunOutcome::Aborted,
                Ok(Outcome::Failed(r)) => RunOutcome::Failed(r),
                Err(e) => RunOutcome::Failed(e.to_string()),
            };
            drop(devices);
            drop(ctx);
            // let go of the campaign (a store write) and the cell before announcing the end
            let held = (session.lock, session.cell);
            let _ = tokio::task::spawn_blocking(move || drop(held)).await;
            end.end(outcome);
            pump.abort();
            if let Some(sim) = session.sim {
                sim.stop().await;
            }
        });
        lock(&self.slot).loaded = Some(Loaded {
            id: campaign_id,
            control,
            status,
            task,
            run_start,
            resumed,
        });
        Ok(campaign_id)
    }

    /// Start the observer of a session's run (before its engine starts, so that it sees every
    /// event): the run's state, device status, metrics and log lines ([`observe`]).
    fn observe_run(
        &self,
        session: &crate::campaign::session::Session,
        run_start: i64,
        status: RunWatch,
    ) {
        let run = lock(&self.cell).run_loaded(&session.ctx.cfg, session.sim.as_ref());
        let observer = Observer {
            id: session.ctx.campaign_id,
            run_start,
            readers: Arc::clone(&self.readers),
            metrics: Arc::clone(&self.metrics),
            cell: Arc::clone(&self.cell),
            status,
            run,
            progress: StdMutex::new(Progress::for_campaign(&session.ctx)),
        };
        tokio::spawn(observer.run(session.ctx.control.events.subscribe()));
    }

    /// Apply a client command to campaign `id` and answer with the campaign once the engine
    /// has taken it: the reply's `state` is the state the command leads to (`arm` → `armed`,
    /// `start` → `running`, `abort` → `aborted`, …), waiting at most [`COMMAND_SETTLE`] (a
    /// pause takes effect after the current pose: a slow pose, or an open technician question
    /// at once, answers `running` with `pausing`). A command that cannot act in the
    /// campaign's state is a conflict that says why ([`command_effect`]), never a reply that
    /// does nothing.
    /// Only `arm`, `start` and `resume` (an operator's) load a stored campaign that is not
    /// loaded; any other command on it changes nothing ([`Daemon::not_loaded`]). Cancel-safe: a
    /// command is applied at once (a load runs in its own task); a dropped call only stops the
    /// waiting.
    pub async fn command(
        self: &Arc<Self>,
        id: i64,
        cmd: ClientCommand,
    ) -> Result<CampaignView, DaemonError> {
        let loaded = self.running_id();
        if loaded != Some(id) {
            match cmd {
                ClientCommand::Arm | ClientCommand::Start | ClientCommand::Resume => {
                    self.ensure_loaded(id).await?
                }
                _ => return self.not_loaded(id, &cmd, loaded).await,
            }
        }
        if let Some(wait) = self.apply_to_loaded(id, cmd)? {
            wait.settle(COMMAND_SETTLE).await;
        }
        self.get(id).await
    }

    /// The id of the campaign whose engine runs in this daemon, if any.
    fn running_id(&self) -> Option<i64> {
        let slot = lock(&self.slot);
        slot.loaded.as_ref().filter(|l| l.running()).map(|l| l.id)
    }

    /// The answer to `cmd` on campaign `id`, which is not loaded (`loaded` is): nothing is
    /// loaded or changed. An abort or disarm answers the campaign's true state when nothing of
    /// it can move; a conflict names the loaded campaign, or the live process that runs `id`.
    /// Cancel-safe (reads only).
    async fn not_loaded(
        &self,
        id: i64,
        cmd: &ClientCommand,
        loaded: Option<i64>,
    ) -> Result<CampaignView, DaemonError> {
        let v = self.read(move |s| stored_view(s, s.campaign(id)?)).await?;
        let holder = v.holder.clone().filter(|h| !is_dead(h));
        let view = self.view_of(v);
        let stops = matches!(cmd, ClientCommand::Abort | ClientCommand::Disarm);
        let what = match cmd {
            ClientCommand::Abort => "abort",
            ClientCommand::Disarm => "disarm",
            ClientCommand::Pause => "pause",
            ClientCommand::Reregister => "reregister",
            ClientCommand::Answer { .. } => "answer",
            ClientCommand::ConfirmClear { .. } => "confirm_clear",
            ClientCommand::Arm | ClientCommand::Start | ClientCommand::Resume => "load",
        };
        let state = &view.state;
        Err(DaemonError::Conflict(match (loaded, holder) {
            (Some(other), _) => format!(
                "campaign {id} is not loaded ({state}): nothing of it moves; campaign {other} is \
                 the loaded one — send {what} to campaign {other}"
            ),
            (None, Some(h)) if h.pid == std::process::id() => format!(
                "campaign {id} is being loaded by this daemon (nothing of it moves before an \
                 arm and a start); send {what} again once it is loaded"
            ),
            (None, Some(h)) => format!(
                "campaign {id} is run by another process, {h}, not by this daemon: stop it there"
            ),
            (None, None) if stops => return Ok(view),
            (None, None) if matches!(cmd, ClientCommand::Reregister) => format!(
                "campaign {id} is not loaded ({state}): an operator loads it with arm; then \
                 reregister resumes it, re-registering a tracker frame found moved"
            ),
            (None, None) => format!(
                "campaign {id} is not loaded ({state}): nothing to {what}; only an operator \
                 loads a stored campaign (arm, start or resume)"
            ),
        }))
    }

    /// Apply `cmd` to campaign `id` if it is the running one, returning how to wait for the
    /// engine to take it; abort or disarm of a campaign that is not running is a no-op
    /// (nothing moves anyway). Every other command either acts or is refused with the reason
    /// ([`command_effect`]): a reply of 200 means the campaign is, or is going to, the state
    /// the command asks for.
    fn apply_to_loaded(
        &self,
        id: i64,
        cmd: ClientCommand,
    ) -> Result<Option<StateWait>, DaemonError> {
        let slot = lock(&self.slot);
        let Some(l) = slot.loaded.as_ref().filter(|l| l.id == id && l.running()) else {
            return Ok(None);
        };
        let wait = |settled: fn(StoredState) -> bool, or_asking: bool| {
            Some(StateWait {
                status: l.status.clone(),
                settled,
                or_asking,
            })
        };
        let state = l.status.read(|s| s.state);
        let effect = command_effect(id, &cmd, state, l.control.is_armed(), l.resumed)?;
        match effect {
            Effect::Holds => return Ok(None),
            Effect::Start { reregister } => {
                if reregister {
                    l.control.apply(&CampaignCommand::Reregister);
                }
                l.control.apply(&CampaignCommand::Start);
                return Ok(wait(started, false));
            }
            Effect::Apply => {}
        }
        Ok(match cmd {
            ClientCommand::Answer {
                seq,
                value_mm,
                abort,
            } => {
                l.status.update(|status| {
                    let slot = &mut status.prompt;
                    let r = match slot.take().filter(PendingPrompt::is_open) {
                        Some(p) if p.seq == seq => {
                            let answer = match (abort, value_mm) {
                                (true, _) => Answer::Abort,
                                (false, _) if p.prompt.id == CONFIRM_CLEAR => {
                                    *slot = Some(p);
                                    return (
                                        Err(DaemonError::Conflict(format!(
                                            "question {seq} asks to confirm the cell clear: send \
                                         {{\"command\": \"confirm_clear\", \"seq\": {seq}}}"
                                        ))),
                                        false,
                                    );
                                }
                                (false, Some(v)) if v.is_finite() => Answer::Number(v),
                                (false, Some(v)) => {
                                    *slot = Some(p);
                                    return (
                                        Err(DaemonError::BadRequest(format!(
                                            "value_mm: {v} is not a finite number"
                                        ))),
                                        false,
                                    );
                                }
                                (false, None) => Answer::Confirmed,
                            };
                            p.answer(answer);
                            Ok(())
                        }
                        other => {
                            let waiting = other.as_ref().map(|p| p.seq);
                            *slot = other;
                            Err(DaemonError::Conflict(match waiting {
                                Some(w) => format!("question {seq} is not open; {w} is"),
                                None => format!("question {seq} is not open; none is"),
                            }))
                        }
                    };
                    (r, true)
                })?;
                None
            }
            ClientCommand::ConfirmClear { seq } => {
                l.status.update(|status| {
                    let slot = &mut status.prompt;
                    let r = match slot.take().filter(PendingPrompt::is_open) {
                        Some(p) if p.seq == seq && p.prompt.id == CONFIRM_CLEAR => {
                            p.answer(Answer::Clear);
                            Ok(())
                        }
                        other => {
                            let open = other.as_ref().map(|p| (p.seq, p.prompt.id.clone()));
                            *slot = other;
                            Err(DaemonError::Conflict(match open {
                                Some((w, id)) if id == CONFIRM_CLEAR => {
                                    format!("question {seq} is not open; {w} is")
                                }
                                Some((w, _)) => format!(
                                    "no `{CONFIRM_CLEAR}` question {seq} is open (question {w} is \
                                 answered with `answer`)"
                                ),
                                None => format!("question {seq} is not open; none is"),
                            }))
                        }
                    };
                    (r, true)
                })?;
                None
            }
            ClientCommand::Arm => {
                l.control.apply(&CampaignCommand::Arm);
                wait(|s| s != StoredState::Idle, false)
            }
            ClientCommand::Disarm => {
                l.control.apply(&CampaignCommand::Disarm);
                // a running campaign pauses on a disarm
                wait(
                    |s| !matches!(s, StoredState::Armed | StoredState::Running),
                    false,
                )
            }
            ClientCommand::Start => {
                l.control.apply(&CampaignCommand::Start);
                wait(started, false)
            }
            ClientCommand::Pause => {
                l.control.apply(&CampaignCommand::Pause);
                // an open question is answered before the pause takes effect: say so at once
                wait(|s| s != StoredState::Running, true)
            }
            ClientCommand::Resume => {
                // while running: withdraws a pause asked for and not yet taken
                l.control.apply(&CampaignCommand::Resume);
                wait(|s| s != StoredState::Paused, false)
            }
            ClientCommand::Reregister => {
                l.control.apply(&CampaignCommand::Reregister);
                wait(|s| s != StoredState::Paused, false)
            }
            ClientCommand::Abort => {
                l.control.apply(&CampaignCommand::Abort);
                // until the run has ended and let go of the campaign and the cell: the reply's
                // `loaded: false` is true, and a next command loads it again
                wait(|_| false, false)
            }
        })
    }

    /// Follow campaign `id`'s events: journal entries with a sequence number above `after`,
    /// then live ones as they happen, each exactly once and in order, replaying from the journal
    /// whatever the live channel lost. `after = None` means "from now" for a running campaign
    /// and "the whole journal" otherwise. The channel closes after the run's final state (or,
    /// for a campaign not running, after the replay). Cancel-safe: dropping the receiver ends
    /// the follower task.
    pub async fn follow(
        self: &Arc<Self>,
        id: i64,
        after: Option<i64>,
    ) -> Result<mpsc::Receiver<Followed>, DaemonError> {
        let newest = self.read(move |s| s.last_event_seq(id)).await?;
        let live = {
            let slot = lock(&self.slot);
            slot.loaded
                .as_ref()
                .filter(|l| l.id == id && l.running())
                .map(|l| Live {
                    rx: l.control.events.subscribe(),
                    run_start: l.run_start,
                    status: l.status.clone(),
                })
        };
        let last = match (after, &live) {
            (Some(a), _) => a.max(0),
            (None, Some(_)) => newest,
            (None, None) => 0,
        };
        let (tx, rx) = mpsc::channel(64);
        tokio::spawn(Arc::clone(self).forward(id, last, live, tx));
        Ok(rx)
    }

    /// The follower task of [`Daemon::follow`]. Cancel-safe: it only reads and sends.
    async fn forward(
        self: Arc<Self>,
        id: i64,
        mut last: i64,
        live: Option<Live>,
        tx: mpsc::Sender<Followed>,
    ) {
        let run_start = live.as_ref().map(|l| l.run_start);
        let replayed = self.replay(id, &mut last, run_start, &tx).await;
        let (Some(mut live), Ok((_, Forward::More))) = (live, replayed) else {
            return;
        };
        loop {
            let step = tokio::select! {
                biased;
                r = live.rx.recv() => self.forward_live(id, r, &mut last, &live, &tx).await,
                _ = live.status.ended() => {
                    // the final state is journalled: deliver what is left, then end
                    let _ = self.replay(id, &mut last, None, &tx).await;
                    Forward::Stop
                }
                _ = tx.closed() => Forward::Stop,
            };
            if matches!(step, Forward::Stop) {
                return;
            }
        }
    }

    /// One receive of the live channel: forward a new entry, replay after a lag, stop at the
    /// run's end. Cancel-safe: a dropped call loses at most entries the journal replays.
    async fn forward_live(
        &self,
        id: i64,
        r: Result<Journalled, broadcast::error::RecvError>,
        last: &mut i64,
        live: &Live,
        tx: &mpsc::Sender<Followed>,
    ) -> Forward {
        match r {
            Ok(j) if j.seq <= *last => Forward::More,
            Ok(j) => {
                *last = j.seq;
                let ends = j.event.ends_run();
                if tx.send(Followed::Entry(j)).await.is_err() || ends {
                    return Forward::Stop;
                }
                if !self.opts.follow_pace.is_zero() {
                    tokio::time::sleep(self.opts.follow_pace).await;
                }
                Forward::More
            }
            Err(broadcast::error::RecvError::Lagged(_)) => {
                match self.replay(id, last, Some(live.run_start), tx).await {
                    Ok((count, step)) => {
                        if tx.send(Followed::Replayed { count }).await.is_err() {
                            return Forward::Stop;
                        }
                        step
                    }
                    Err(_) => Forward::Stop,
                }
            }
            Err(broadcast::error::RecvError::Closed) => {
                let _ = self.replay(id, last, None, tx).await;
                Forward::Stop
            }
        }
    }

    /// Send the journal entries after `*last` (page by page, read off the runtime) and advance
    /// `*last`; returns how many were sent and whether to go on. With `run_start`, the final
    /// state of the run started after it stops the replay. Cancel-safe: `*last` only
    /// advances past entries already sent.
    async fn replay(
        &self,
        id: i64,
        last: &mut i64,
        run_start: Option<i64>,
        tx: &mpsc::Sender<Followed>,
    ) -> Result<(usize, Forward), DaemonError> {
        let mut count = 0;
        loop {
            let after = *last;
            let page = self
                .read(move |s| s.events_after::<CampaignEvent>(id, after, REPLAY_PAGE))
                .await?;
            let full = page.len() == REPLAY_PAGE;
            for e in page {
                *last = e.seq;
                count += 1;
                let ends = run_start.is_some_and(|r| e.seq > r) && e.event.ends_run();
                if tx.send(Followed::Entry(e)).await.is_err() || ends {
                    return Ok((count, Forward::Stop));
                }
            }
            if !full {
                return Ok((count, Forward::More));
            }
        }
    }

    /// The campaign's event journal (oldest first), each entry `{seq, at_ms, kind, event}`.
    /// Cancel-safe (reads only).
    pub async fn journal(&self, id: i64) -> Result<Vec<serde_json::Value>, DaemonError> {
        let entries = self.read(move |s| s.events::<CampaignEvent>(id)).await?;
        entries
            .into_iter()
            .map(|e| {
                // through a JSON value, as the journal has always been served (keys sorted)
                let event = serde_json::to_value(&e.event)
                    .map_err(|x| DaemonError::Task(format!("event {}: {x}", e.seq)))?;
                Ok(serde_json::json!({
                    "seq": e.seq,
                    "at_ms": e.at_ms,
                    "kind": e.event.kind(),
                    "event": event,
                }))
            })
            .collect()
    }

    /// The campaign's corrected model as robot-file TOML
    /// ([`crate::campaign::stored::stored_model_toml`]), `None` before a result. Cancel-safe
    /// (reads only).
    pub async fn model(&self, id: i64) -> Result<Option<String>, DaemonError> {
        self.read(move |s| Ok(stored_model_toml(s, id)))
            .await?
            .map_err(|e| match e {
                StoredError::Store(StoreError::NoCampaign(id)) => DaemonError::NotFound(id),
                e => DaemonError::Stored(e),
            })
    }

    /// The campaign's measured poses as identification rows (segment 0's tracker frame, plan
    /// order). Cancel-safe (reads only).
    pub async fn measurements(&self, id: i64) -> Result<Vec<MeasurementRow>, DaemonError> {
        let poses = self.read(move |s| s.measured(id)).await?;
        Ok(poses
            .into_iter()
            .map(|m| MeasurementRow {
                pose: m.index,
                set: m.set.as_str(),
                q_rad: m.joints_rad,
                p1_mm: m.p1.position_mm.into(),
                p2_mm: m.p2.map(|p| p.position_mm.into()),
            })
            .collect())
    }

    /// The campaign's measurements as the identify CSV that `cellcal export` writes (setup
    /// header included; the store named as this daemon was given it). A campaign that cannot
    /// be rebuilt (an imported one without its robot model) is a conflict. Cancel-safe.
    pub async fn measurements_csv(&self, id: i64) -> Result<String, DaemonError> {
        let source = self.readers.path().display().to_string();
        let csv = self
            .read(move |s| match load_stored(s, id, None) {
                Ok(c) => Ok(Ok(c.export_csv(&source))),
                Err(StoredError::Store(e)) => Err(e),
                Err(e) => Ok(Err(e.to_string())),
            })
            .await?;
        csv.map_err(DaemonError::Conflict)
    }

    /// The campaign's stored plan: every pose in move order, its set, joints and done mark.
    /// Cancel-safe (reads only).
    pub async fn plan(&self, id: i64) -> Result<PlanView, DaemonError> {
        let (plan, done) = self
            .read(move |s| Ok((s.plan(id)?, s.done_poses(id)?)))
            .await?;
        let done: std::collections::HashSet<usize> = done.into_iter().collect();
        let count = |set: PoseSet| plan.iter().filter(|p| p.set == set).count();
        Ok(PlanView {
            campaign: id,
            poses_total: plan.len(),
            ident: count(PoseSet::Ident),
            verify: count(PoseSet::Verify),
            done: done.len(),
            poses: plan
                .iter()
                .map(|p| PlannedPoseView {
                    index: p.index,
                    set: p.set.as_str(),
                    order: p.order,
                    q_rad: p.q_rad.clone(),
                    done: done.contains(&p.index),
                })
                .collect(),
        })
    }

    /// The campaign's latest result (the `cellcal identify` JSON rendered from the stored typed
    /// result; an ISO campaign's figures), if any. Cancel-safe.
    pub async fn result(&self, id: i64) -> Result<Option<serde_json::Value>, DaemonError> {
        self.read(move |s| Ok(stored_result_json(s, id)))
            .await?
            .map_err(|e| match e {
                StoredError::Store(StoreError::NoCampaign(id)) => DaemonError::NotFound(id),
                e => DaemonError::Stored(e),
            })
    }

    /// The calibration report of a campaign (one self-contained HTML page), `None` while it has
    /// no result; a conflict for an ISO 9283 campaign (no identification to report). Built on a blocking thread from a store reader (the campaign's identification
    /// is rebuilt for the per-pose plots). Cancel-safe (reads only).
    pub async fn report_html(&self, id: i64) -> Result<Option<String>, DaemonError> {
        let name = self
            .readers
            .path()
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let at = crate::wall_clock::now_unix_ms();
        let page = self
            .read(move |s| match campaign_report(s, id, &name, at) {
                Ok(input) => Ok(Ok(input.map(|i| crate::report::html::render(&i)))),
                Err(ReportError::Store(e)) => Err(e),
                Err(e @ ReportError::NotCalibration(_)) => Ok(Err(e)),
            })
            .await?;
        page.map_err(|e| DaemonError::Conflict(e.to_string()))
    }

    /// Stop the cell: abort the loaded campaign, if one is running, and wait (at most
    /// [`COMMAND_SETTLE`]) until its engine has told the robot and the stage to stop; answers
    /// with what each said. Without a running campaign the daemon holds no device connection
    /// and nothing moves. Cancel-safe: the abort is applied before the only wait.
    pub async fn cell_stop(&self) -> Result<CellStopView, DaemonError> {
        let running = {
            let slot = lock(&self.slot);
            slot.loaded.as_ref().filter(|l| l.running()).map(|l| {
                let events = l.control.events.subscribe();
                l.control.apply(&CampaignCommand::Abort);
                (l.id, events, l.status.clone())
            })
        };
        let Some((id, mut events, status)) = running else {
            return Ok(CellStopView {
                campaign: None,
                state: None,
                robot: None,
                stage: None,
            });
        };
        let mut said = (None, None);
        let _ = tokio::time::timeout(COMMAND_SETTLE, async {
            loop {
                tokio::select! {
                    biased;
                    e = events.recv() => match e.map(|j| j.event) {
                        Ok(CampaignEvent::Stopped { robot, stage, .. }) => {
                            said = (Some(robot), Some(stage));
                        }
                        Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => {}
                        Err(broadcast::error::RecvError::Closed) => break,
                    },
                    _ = status.ended() => break,
                }
            }
        })
        .await;
        let state = self.get(id).await.ok().map(|v| v.state);
        Ok(CellStopView {
            campaign: Some(id),
            state,
            robot: said.0,
            stage: said.1,
        })
    }

    /// Refuse new campaigns, wait for one being loaded, abort the loaded campaign (if running)
    /// and wait for its engine to stop the robot. Not cancel-safe: a dropped call may leave the
    /// campaign aborting on its own.
    pub async fn shutdown(&self) {
        lock(&self.slot).closing = true;
        while lock(&self.slot).creating {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let l = lock(&self.slot).loaded.take();
        if let Some(l) = l {
            l.control.apply(&CampaignCommand::Abort);
            let _ = l.task.await;
        }
    }
}

/// Longest wait of a command's reply for the engine to take the command.
pub const COMMAND_SETTLE: Duration = Duration::from_secs(5);

/// Waiting for the engine to take a command.
struct StateWait {
    status: RunWatch,
    /// The engine states in which the command has been taken.
    settled: fn(StoredState) -> bool,
    /// Also stop waiting while a technician question is open (a pause waits for its answer).
    or_asking: bool,
}

impl StateWait {
    /// Until the engine's state is one `settled` accepts, the run ends, (with `or_asking`) a
    /// question waits for the technician, or `limit` passes. Cancel-safe (it only waits).
    async fn settle(self, limit: Duration) {
        let _ =
            tokio::time::timeout(limit, self.status.settled(self.settled, self.or_asking)).await;
    }
}

/// What a command does to a loaded run in its current state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Effect {
    /// Apply it to the engine.
    Apply,
    /// Start the run waiting for its start (a `resume` or `reregister` of a campaign loaded
    /// from the store is its start, as `cellcal run --campaign N --arm [--reregister]`: the
    /// engine's frame check at the start re-registers a moved tracker only when asked).
    Start {
        /// Re-register a tracker frame found moved at the start's frame check.
        reregister: bool,
    },
    /// The state the command asks for already holds (arm while armed, pause while paused,
    /// start or resume while running): nothing to do, and the reply says so truthfully.
    Holds,
}

/// What `cmd` does to loaded campaign `id` whose engine is in `state` (`None`: not yet
/// written), armed or not, `resumed` from the store or created by this daemon; `Err` says why
/// the command cannot act now and what to send instead. Answers and stops always reach the
/// engine (their own checks follow).
fn command_effect(
    id: i64,
    cmd: &ClientCommand,
    state: Option<StoredState>,
    armed: bool,
    resumed: bool,
) -> Result<Effect, DaemonError> {
    use StoredState::{Armed, Identifying, Idle, Paused, Running};
    let what = command_name(cmd);
    let refuse = |why: String| Err(DaemonError::Conflict(why));
    let waiting = matches!(state, None | Some(Idle | Armed));
    let now = state.map_or("loading", StoredState::name);
    match cmd {
        ClientCommand::Arm
        | ClientCommand::Disarm
        | ClientCommand::Abort
        | ClientCommand::Answer { .. }
        | ClientCommand::ConfirmClear { .. } => Ok(Effect::Apply),
        ClientCommand::Start if !armed => refuse(format!(
            "campaign {id} is not armed: arm it first (a start before arm is refused, not \
             remembered)"
        )),
        ClientCommand::Resume | ClientCommand::Reregister if !armed => refuse(format!(
            "campaign {id} is not armed: arm it, then {what} (nothing is powered or moved while \
             disarmed)"
        )),
        ClientCommand::Start if waiting => Ok(Effect::Apply),
        ClientCommand::Resume | ClientCommand::Reregister if waiting && resumed => {
            Ok(Effect::Start {
                reregister: matches!(cmd, ClientCommand::Reregister),
            })
        }
        ClientCommand::Resume | ClientCommand::Reregister | ClientCommand::Pause if waiting => {
            refuse(format!(
                "campaign {id} has not started ({now}): nothing to {what}; send start (a {what} \
                 before the start is refused, not remembered)"
            ))
        }
        ClientCommand::Start | ClientCommand::Resume if state == Some(Running) => {
            Ok(if matches!(cmd, ClientCommand::Resume) {
                // withdraws a pause asked for and not yet taken
                Effect::Apply
            } else {
                Effect::Holds
            })
        }
        ClientCommand::Pause if state == Some(Running) => Ok(Effect::Apply),
        ClientCommand::Pause if state == Some(Paused) => Ok(Effect::Holds),
        ClientCommand::Resume | ClientCommand::Reregister if state == Some(Paused) => {
            Ok(Effect::Apply)
        }
        ClientCommand::Start if state == Some(Paused) => refuse(format!(
            "campaign {id} is paused: send resume (start begins a campaign that waits for its \
             start)"
        )),
        ClientCommand::Reregister if state == Some(Running) => refuse(format!(
            "campaign {id} is not paused: reregister resumes a paused campaign (it is not \
             remembered for a later pause)"
        )),
        _ if state == Some(Identifying) => refuse(format!(
            "campaign {id} has measured every pose and is identifying: nothing to {what}"
        )),
        _ => refuse(format!(
            "campaign {id} is {now}: its run is ending; send {what} again once it has ended"
        )),
    }
}

/// The command's name in messages (`arm`, `confirm_clear`, …).
fn command_name(cmd: &ClientCommand) -> &'static str {
    match cmd {
        ClientCommand::Arm => "arm",
        ClientCommand::Disarm => "disarm",
        ClientCommand::Start => "start",
        ClientCommand::Pause => "pause",
        ClientCommand::Resume => "resume",
        ClientCommand::Reregister => "reregister",
        ClientCommand::Abort => "abort",
        ClientCommand::Answer { .. } => "answer",
        ClientCommand::ConfirmClear { .. } => "confirm_clear",
    }
}

/// The engine has left its wait for the start (the state a start leads to).
fn started(s: StoredState) -> bool {
    !matches!(s, StoredState::Idle | StoredState::Armed)
}

/// What a view needs from the store.
struct StoredView {
    row: CampaignRow,
    /// The process holding the campaign (its lock row), if any.
    holder: Option<LockHolder>,
    done: usize,
    total: usize,
    has_result: bool,
    quality: Option<String>,
    estimate: Option<CampaignEstimate>,
    /// Measuring and paused time from the journal.
    elapsed: Elapsed,
}

/// Read the stored part of a campaign's view (counts, the verdict, the estimate and the
/// journal's state times; no plan or result bodies).
fn stored_view(s: &Store, row: CampaignRow) -> Result<StoredView, StoreError> {
    let (done, total) = s.pose_counts(row.id)?;
    let has_result = s.has_result(row.id)?;
    let quality = s.result_quality(row.id)?;
    let holder = s.campaign_holder(row.id)?;
    let estimate = stored_estimate(s, row.id)?;
    let elapsed = Elapsed::stored(s, row.id)?;
    Ok(StoredView {
        row,
        holder,
        done,
        total,
        has_result,
        quality,
        estimate,
        elapsed,
    })
}

/// Keep each technician question for `answer`, then journal and announce it as a `prompt`
/// event (in that order, so a client that sees the event can answer it at once).
/// Runs as the session's own task. Cancel-safe: the question is kept before the only await, and
/// [`journal_event`] finishes on its blocking thread even if this task is dropped.
async fn pump_prompts(
    mut prompts: mpsc::Receiver<PendingPrompt>,
    status: RunWatch,
    store: StoreHandle,
    id: i64,
    control: Control,
) {
    while let Some(p) = prompts.recv().await {
        let event = CampaignEvent::Prompt {
            seq: p.seq,
            id: p.prompt.id.clone(),
            text: p.prompt.text.clone(),
            expected_mm: p.prompt.expected_mm,
            context: p.prompt.context.clone(),
        };
        status.update(|s| {
            s.prompt = Some(p);
            ((), true)
        });
        // a store that cannot journal also stops the engine, which reports it
        let _ = journal_event(&store, id, &control, event).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_cell_config;
    use crate::model::TermFamily;

    const FILE: &str = "# the cell\n[campaign]\n# the paper's campaign\nposes = 300 # all of them\n\n[stage]\ntravel_mm = 10.0\n";

    fn apply(body: &str) -> Result<CellConfig, String> {
        let mut cfg = parse_cell_config(FILE, std::path::Path::new("cell.toml")).unwrap();
        let o: CampaignOverrides = serde_json::from_str(body).map_err(|e| e.to_string())?;
        o.apply(&mut cfg).map(|()| cfg).map_err(|e| e.to_string())
    }

    #[test]
    fn a_campaigns_terms_can_be_chosen_per_request_and_bad_ones_are_named() {
        let c = apply(r#"{"nongeometric": ["harmonics", "compliance"]}"#).unwrap();
        assert_eq!(
            c.campaign.nongeometric,
            [TermFamily::Harmonics, TermFamily::Compliance]
        );
        assert!(apply("{}").unwrap().campaign.nongeometric.is_empty());
        assert!(apply(r#"{"nongeometric": []}"#)
            .unwrap()
            .campaign
            .nongeometric
            .is_empty());
        let e = apply(r#"{"nongeometric": ["gravity"]}"#).unwrap_err();
        assert!(
            e.contains("campaign.nongeometric: `gravity` is not one of compliance, harmonics"),
            "{e}"
        );
        let e = apply(r#"{"nongeometric": ["harmonics", "harmonics"]}"#).unwrap_err();
        assert!(e.contains("campaign.nongeometric"), "{e}");
        assert!(apply(r#"{"nongeometric": "harmonics"}"#).is_err(), "a list");
    }

    #[test]
    fn the_overrides_are_written_into_the_stored_text_and_read_back_from_it() {
        let body = r#"{"poses": 120, "ident": 40, "seed": 7, "model": "position",
                       "nongeometric": ["harmonics"]}"#;
        let c = apply(body).unwrap();
        let back = parse_cell_config(&c.text, std::path::Path::new("stored")).unwrap();
        assert_eq!(back.campaign, c.campaign);
        assert_eq!(
            (back.campaign.poses, back.campaign.ident, back.campaign.seed),
            (120, 40, 7)
        );
        assert_eq!(back.campaign.model, crate::identify::ObsModel::Position);
        assert_eq!(back.campaign.nongeometric, [TermFamily::Harmonics]);
        // the rest of the file as it was, comments included
        for kept in [
            "# the cell",
            "# the paper's campaign",
            "# all of them",
            "travel_mm = 10.0",
        ] {
            assert!(c.text.contains(kept), "{kept}: {}", c.text);
        }
        // no override: the text is the file's, byte for byte
        assert_eq!(apply("{}").unwrap().text, FILE);
        assert!(apply(r#"{"seed": 18446744073709551615}"#)
            .unwrap_err()
            .contains("campaign.seed"));
    }
}
