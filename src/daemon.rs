//! The long-running campaign service behind `cellcal serve`: one cell, at most one campaign
//! loaded at a time, driven by the engine's commands and watched through its events. Front ends
//! (the REST API in [`crate::api`], later a web page) are thin clients of this.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex as StdMutex};

use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, Mutex};
use tokio::task::JoinHandle;

use crate::campaign::session::{open_session, SessionError};
use crate::campaign::{run_campaign, CampaignCommand, CampaignEvent, Control, Outcome};
use crate::cell::{Answer, ChannelPrompter, PendingPrompt};
use crate::config::CellConfig;
use crate::store::{CampaignRow, Store, StoreError};

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
    /// The store failed.
    #[error("store: {0}")]
    Store(#[from] StoreError),
    /// The campaign session could not be set up.
    #[error("{0}")]
    Session(#[from] SessionError),
}

/// Campaign settings a client may change from the configuration's `[campaign]` defaults.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
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
}

impl CampaignOverrides {
    /// Apply to a configuration, with the same checks as the configuration file
    /// ([`crate::config::CampaignSection::check`]).
    pub fn apply(&self, cfg: &mut CellConfig) -> Result<(), DaemonError> {
        let c = &mut cfg.campaign;
        if let Some(m) = &self.model {
            c.model = m.clone();
        }
        c.poses = self.poses.unwrap_or(c.poses);
        c.ident = self.ident.unwrap_or(c.ident);
        c.seed = self.seed.unwrap_or(c.seed);
        c.check()
            .map_err(|e| DaemonError::BadRequest(e.to_string()))
    }
}

/// A command from a client.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "command", rename_all = "snake_case", deny_unknown_fields)]
pub enum ClientCommand {
    /// Allow motion.
    Arm,
    /// Disallow motion (the engine refuses to move while disarmed).
    Disarm,
    /// Start, or resume a stored campaign (requires arm).
    Start,
    /// Pause after the current pose.
    Pause,
    /// Resume a paused campaign (after an operator fault: retries the step).
    Resume,
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
}

/// A question waiting for the technician, as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PromptView {
    /// Answer with this sequence number.
    pub seq: u64,
    /// Short id (`stage_move`, …).
    pub id: String,
    /// The text shown to the technician.
    pub text: String,
    /// Expected numeric answer (mm), if a number is asked for.
    pub expected_mm: Option<f64>,
}

/// A campaign as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CampaignView {
    /// Campaign id.
    pub id: i64,
    /// Human name.
    pub name: String,
    /// Creation time (ms since the Unix epoch).
    pub created_at_ms: i64,
    /// Last stored state (`idle`, `armed`, `running`, `paused`, `identifying`, `done`,
    /// `aborted`, `failed`, or `created` before the engine first ran).
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
    /// The question waiting for the technician, if any.
    pub prompt: Option<PromptView>,
    /// A result is stored.
    pub has_result: bool,
}

struct Loaded {
    id: i64,
    control: Control,
    pending: Arc<StdMutex<Option<PendingPrompt>>>,
    outcome: Arc<StdMutex<Option<String>>>,
    task: JoinHandle<()>,
}

impl Loaded {
    fn running(&self) -> bool {
        !self.task.is_finished()
    }
}

/// The campaign service.
pub struct Daemon {
    cfg: CellConfig,
    store_path: PathBuf,
    loaded: Mutex<Option<Loaded>>,
}

fn lock<T>(m: &StdMutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Daemon {
    /// A daemon for the cell of `cfg`, storing campaigns in `store_path` (created if missing).
    pub fn new(cfg: CellConfig, store_path: &Path) -> Result<Daemon, DaemonError> {
        Store::open(store_path)?;
        Ok(Daemon {
            cfg,
            store_path: store_path.to_owned(),
            loaded: Mutex::new(None),
        })
    }

    fn store(&self) -> Result<Store, DaemonError> {
        Ok(Store::open(&self.store_path)?)
    }

    /// Every stored campaign.
    pub async fn list(&self) -> Result<Vec<CampaignView>, DaemonError> {
        let rows = self.store()?.list_campaigns()?;
        let mut out = Vec::with_capacity(rows.len());
        for r in rows {
            out.push(self.view_of(r).await?);
        }
        Ok(out)
    }

    async fn view_of(&self, row: CampaignRow) -> Result<CampaignView, DaemonError> {
        let s = self.store()?;
        let id = row.id;
        let done = s.done_poses(id)?.len();
        let total = s.plan(id)?.len();
        let has_result = s.latest_result(id)?.is_some();
        let loaded = self.loaded.lock().await;
        let l = loaded.as_ref().filter(|l| l.id == id);
        let prompt = l.and_then(|l| {
            lock(&l.pending).as_ref().map(|p| PromptView {
                seq: p.seq,
                id: p.prompt.id.clone(),
                text: p.prompt.text.clone(),
                expected_mm: p.prompt.expected_mm,
            })
        });
        Ok(CampaignView {
            id,
            name: row.name,
            created_at_ms: row.created_at_ms,
            state: row.state,
            model: row.model,
            poses_done: done,
            poses_total: total,
            loaded: l.is_some_and(Loaded::running),
            armed: l.is_some_and(|l| l.running() && l.control.is_armed()),
            last_outcome: l.and_then(|l| lock(&l.outcome).clone()),
            prompt,
            has_result,
        })
    }

    /// One campaign.
    pub async fn get(&self, id: i64) -> Result<CampaignView, DaemonError> {
        let row = match self.store()?.campaign(id) {
            Err(StoreError::NoCampaign(_)) => return Err(DaemonError::NotFound(id)),
            r => r?,
        };
        self.view_of(row).await
    }

    /// Plan and store a new campaign from the configuration (plus `overrides`) and load it;
    /// nothing moves until it is armed and started.
    pub async fn create(&self, overrides: &CampaignOverrides) -> Result<CampaignView, DaemonError> {
        let mut cfg = self.cfg.clone();
        overrides.apply(&mut cfg)?;
        let id = self.load(cfg, None).await?;
        self.get(id).await
    }

    /// Load campaign `id` unless it is loaded; a campaign still running blocks every other.
    async fn ensure_loaded(&self, id: i64) -> Result<(), DaemonError> {
        {
            let loaded = self.loaded.lock().await;
            if let Some(l) = loaded.as_ref().filter(|l| l.running()) {
                if l.id == id {
                    return Ok(());
                }
            }
        }
        self.get(id).await?;
        self.load(self.cfg.clone(), Some(id)).await?;
        Ok(())
    }

    async fn load(&self, cfg: CellConfig, id: Option<i64>) -> Result<i64, DaemonError> {
        let mut loaded = self.loaded.lock().await;
        if let Some(l) = loaded.as_ref().filter(|l| l.running()) {
            return Err(DaemonError::Conflict(format!(
                "campaign {} is loaded on the cell; abort it first",
                l.id
            )));
        }
        let (prompter, mut prompts) = ChannelPrompter::new(4);
        // an infeasible campaign is the client's request to fix (400), before anything starts
        let session = open_session(cfg, &self.store_path, id, Arc::new(prompter))
            .await
            .map_err(|e| match e {
                SessionError::Infeasible(f) => DaemonError::BadRequest(f.to_string()),
                e => DaemonError::Session(e),
            })?;
        let control = session.ctx.control.clone();
        let campaign_id = session.ctx.campaign_id;
        let pending: Arc<StdMutex<Option<PendingPrompt>>> = Arc::default();
        let outcome: Arc<StdMutex<Option<String>>> = Arc::default();
        // questions for the technician: kept for `answer`, announced as events
        let (slot, events) = (Arc::clone(&pending), control.clone());
        let pump = tokio::spawn(async move {
            while let Some(p) = prompts.recv().await {
                events.emit(CampaignEvent::Prompt {
                    seq: p.seq,
                    id: p.prompt.id.clone(),
                    text: p.prompt.text.clone(),
                    expected_mm: p.prompt.expected_mm,
                });
                *lock(&slot) = Some(p);
            }
        });
        let ended = Arc::clone(&outcome);
        let task = tokio::spawn(async move {
            let ctx = session.ctx;
            let mut devices = session.devices;
            let text = match run_campaign(&ctx, &mut devices).await {
                Ok(Outcome::Done(_)) => "done".to_owned(),
                Ok(Outcome::Aborted) => "aborted".to_owned(),
                Ok(Outcome::Failed(r)) => format!("failed: {r}"),
                Err(e) => format!("failed: {e}"),
            };
            *lock(&ended) = Some(text);
            drop(devices);
            drop(ctx);
            pump.abort();
            if let Some(sim) = session.sim {
                sim.stop().await;
            }
        });
        *loaded = Some(Loaded {
            id: campaign_id,
            control,
            pending,
            outcome,
            task,
        });
        Ok(campaign_id)
    }

    /// Apply a client command to campaign `id` (loading a stored campaign to resume it).
    pub async fn command(&self, id: i64, cmd: ClientCommand) -> Result<CampaignView, DaemonError> {
        if !matches!(cmd, ClientCommand::Abort | ClientCommand::Disarm) {
            self.ensure_loaded(id).await?;
        }
        {
            let loaded = self.loaded.lock().await;
            let Some(l) = loaded.as_ref().filter(|l| l.id == id && l.running()) else {
                // abort or disarm of a campaign that is not running: nothing moves anyway
                drop(loaded);
                return self.get(id).await;
            };
            match cmd {
                ClientCommand::Answer {
                    seq,
                    value_mm,
                    abort,
                } => {
                    let mut slot = lock(&l.pending);
                    match slot.take() {
                        Some(p) if p.seq == seq => {
                            let answer = match (abort, value_mm) {
                                (true, _) => Answer::Abort,
                                (false, Some(v)) if v.is_finite() => Answer::Number(v),
                                (false, Some(v)) => {
                                    *slot = Some(p);
                                    return Err(DaemonError::BadRequest(format!(
                                        "value_mm: {v} is not a finite number"
                                    )));
                                }
                                (false, None) => Answer::Confirmed,
                            };
                            p.answer(answer);
                        }
                        other => {
                            let waiting = other.as_ref().map(|p| p.seq);
                            *slot = other;
                            return Err(DaemonError::Conflict(match waiting {
                                Some(w) => format!("question {seq} is not open; {w} is"),
                                None => format!("question {seq} is not open; none is"),
                            }));
                        }
                    }
                }
                ClientCommand::Arm => l.control.apply(&CampaignCommand::Arm),
                ClientCommand::Disarm => l.control.apply(&CampaignCommand::Disarm),
                ClientCommand::Start => l.control.apply(&CampaignCommand::Start),
                ClientCommand::Pause => l.control.apply(&CampaignCommand::Pause),
                ClientCommand::Resume => l.control.apply(&CampaignCommand::Resume),
                ClientCommand::Abort => l.control.apply(&CampaignCommand::Abort),
            }
        }
        self.get(id).await
    }

    /// Live events of campaign `id` (loaded campaigns only).
    pub async fn subscribe(
        &self,
        id: i64,
    ) -> Result<broadcast::Receiver<CampaignEvent>, DaemonError> {
        self.get(id).await?;
        let loaded = self.loaded.lock().await;
        match loaded.as_ref().filter(|l| l.id == id && l.running()) {
            Some(l) => Ok(l.control.events.subscribe()),
            None => Err(DaemonError::Conflict(format!(
                "campaign {id} is not loaded; its journal is at /api/campaigns/{id}/events"
            ))),
        }
    }

    /// The campaign's event journal (oldest first), each entry `{at_ms, event}`.
    pub async fn journal(&self, id: i64) -> Result<Vec<serde_json::Value>, DaemonError> {
        self.get(id).await?;
        Ok(self
            .store()?
            .events(id)?
            .into_iter()
            .map(|e| {
                let event = serde_json::from_str(&e.message)
                    .unwrap_or(serde_json::Value::String(e.message));
                serde_json::json!({ "at_ms": e.at_ms, "kind": e.kind, "event": event })
            })
            .collect())
    }

    /// The campaign's latest result (the `cellcal identify` JSON), if any.
    pub async fn result(&self, id: i64) -> Result<Option<serde_json::Value>, DaemonError> {
        self.get(id).await?;
        Ok(self
            .store()?
            .latest_result(id)?
            .and_then(|t| serde_json::from_str(&t).ok()))
    }

    /// Abort the loaded campaign (if running) and wait for its engine to stop the robot.
    pub async fn shutdown(&self) {
        let l = self.loaded.lock().await.take();
        if let Some(l) = l {
            l.control.apply(&CampaignCommand::Abort);
            let _ = l.task.await;
        }
    }
}
