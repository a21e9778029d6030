//! Commands into and events out of the campaign engine, and the shared control state.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use serde::Serialize;
use tokio::sync::{broadcast, watch};
use tokio_util::sync::CancellationToken;

use crate::cell::{Answer, DeviceKind, FaultKind, PromptContext};

/// What an operator can tell the engine.
#[derive(Debug, Clone, PartialEq)]
pub enum CampaignCommand {
    /// Allow motion.
    Arm,
    /// Disallow motion: a running campaign stops the robot and the stage at once and pauses
    /// (resumable once armed again).
    Disarm,
    /// Start (or resume after a restart) the campaign; requires Arm.
    Start,
    /// Pause after the current pose.
    Pause,
    /// Resume a paused campaign.
    Resume,
    /// Resume, and if the tracker frame is found moved, re-register it (a new frame segment)
    /// instead of pausing again.
    Reregister,
    /// Stop the robot now; the campaign stays resumable.
    Abort,
    /// Answer a technician prompt.
    Answer {
        /// Prompt id.
        prompt_id: String,
        /// The answer.
        answer: Answer,
    },
}

/// Engine state.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum CampaignState {
    /// Created, not armed.
    Idle,
    /// Armed, waiting for start.
    Armed,
    /// Measuring.
    Running,
    /// Paused (by the operator or a fault).
    Paused {
        /// Why.
        reason: String,
    },
    /// Identifying the parameters.
    Identifying,
    /// Finished with a result.
    Done,
    /// Aborted by the operator (resumable).
    Aborted,
    /// Stopped by a fault that needs the operator (resumable).
    Failed {
        /// Why.
        reason: String,
    },
}

impl CampaignState {
    /// Short name stored in the campaign row.
    pub fn name(&self) -> &'static str {
        match self {
            CampaignState::Idle => "idle",
            CampaignState::Armed => "armed",
            CampaignState::Running => "running",
            CampaignState::Paused { .. } => "paused",
            CampaignState::Identifying => "identifying",
            CampaignState::Done => "done",
            CampaignState::Aborted => "aborted",
            CampaignState::Failed { .. } => "failed",
        }
    }
}

/// What the engine reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum CampaignEvent {
    /// State change.
    State {
        /// New state.
        state: CampaignState,
    },
    /// A pose was measured and committed.
    Measured {
        /// Pose index.
        pose: usize,
        /// Poses done.
        done: usize,
        /// Poses planned.
        total: usize,
        /// P1 (mm, tracker frame).
        p1_mm: [f64; 3],
        /// |P1 − predicted P1| (mm): the distance of the measured ball from where the nominal
        /// model (registered base, measured tool) puts it; null without a base registration.
        deviation_mm: Option<f64>,
        /// P1 − predicted P1 (mm, tracker frame); null without a base registration.
        deviation_xyz_mm: Option<[f64; 3]>,
    },
    /// A device fault and what the engine does about it.
    Fault {
        /// Device.
        device: &'static str,
        /// Fault kind.
        kind: String,
        /// Driver message.
        message: String,
        /// Action taken (`relock`, `reconnect`, `retry`, `pause`).
        action: String,
    },
    /// Drift check at the reference pose.
    Drift {
        /// Distance from the first reference measurement (mm).
        drift_mm: f64,
        /// Threshold (mm).
        max_mm: f64,
    },
    /// The cell setup was measured (tool frame, base registration; `SetupResult` as JSON).
    Setup {
        /// The setup result.
        result: serde_json::Value,
    },
    /// A technician question waiting for its answer (front ends answer it by `seq`).
    Prompt {
        /// Sequence number of the question (answer with it).
        seq: u64,
        /// Short id (`stage_move`, …).
        id: String,
        /// The text shown to the technician.
        text: String,
        /// Expected numeric answer (mm), if a number is asked for.
        expected_mm: Option<f64>,
        /// What the engine is doing (`step`, `pose`, `poses_total`, `position`,
        /// `robot_stopped`, `retry_reason`), flattened into the event.
        #[serde(flatten)]
        context: PromptContext,
    },
    /// What each device said it is when it was prepared (model, serial, firmware; null when it
    /// cannot say): journalled after every successful preparation, so a report names the
    /// devices a campaign was measured with.
    Devices {
        /// The tracker's identity.
        tracker: Option<String>,
        /// The robot controller's identity.
        robot: Option<String>,
        /// The stage's identity.
        stage: Option<String>,
    },
    /// The engine told every device that moves to stop (abort, disarm, a fault that ends or
    /// pauses the run): what each answered.
    Stopped {
        /// Why: `abort`, `disarm` or `fault`.
        reason: String,
        /// The robot's answer: `stopped`, or why not (`not connected`, the error).
        robot: String,
        /// The stage's answer: `stopped`, `manual` (nothing motorised), or why not.
        stage: String,
    },
    /// Free-text progress note.
    Note {
        /// Text.
        text: String,
    },
    /// The identification result (the `cellcal identify` JSON).
    Result {
        /// The JSON document.
        json: serde_json::Value,
    },
}

impl CampaignEvent {
    /// Whether this is the state change that ends a run (`done`, `aborted`, `failed`).
    pub fn ends_run(&self) -> bool {
        matches!(
            self,
            CampaignEvent::State {
                state: CampaignState::Done | CampaignState::Aborted | CampaignState::Failed { .. }
            }
        )
    }

    /// The event's tag (`state`, `measured`, `fault`, `drift`, `setup`, `prompt`, `devices`,
    /// `stopped`, `note`, `result`).
    pub fn kind(&self) -> &'static str {
        match self {
            CampaignEvent::State { .. } => "state",
            CampaignEvent::Measured { .. } => "measured",
            CampaignEvent::Fault { .. } => "fault",
            CampaignEvent::Drift { .. } => "drift",
            CampaignEvent::Setup { .. } => "setup",
            CampaignEvent::Prompt { .. } => "prompt",
            CampaignEvent::Devices { .. } => "devices",
            CampaignEvent::Stopped { .. } => "stopped",
            CampaignEvent::Note { .. } => "note",
            CampaignEvent::Result { .. } => "result",
        }
    }

    /// A fault event.
    pub fn fault(device: DeviceKind, kind: FaultKind, message: &str, action: &str) -> Self {
        CampaignEvent::Fault {
            device: device.name(),
            kind: format!("{kind:?}"),
            message: message.to_owned(),
            action: action.to_owned(),
        }
    }
}

/// A live event as its campaign's journal stored it: every event on [`Control::events`] is
/// journalled first, so a client that missed some can read them back by sequence number.
#[derive(Debug, Clone, PartialEq)]
pub struct Journalled {
    /// The journal's sequence number (the store's row id): increasing in emission order.
    pub seq: i64,
    /// When it was journalled (ms since the Unix epoch).
    pub at_ms: i64,
    /// The event.
    pub event: CampaignEvent,
}

/// Shared control state between the command listener and the engine.
#[derive(Debug, Clone)]
pub struct Control {
    /// Motion allowed: the engine waits on it, so a disarm ends any device wait at once.
    pub armed: watch::Sender<bool>,
    /// Abort requested (cancels every wait).
    pub abort: CancellationToken,
    /// Pause requested.
    pub pause: watch::Sender<bool>,
    /// Start requested.
    pub start: watch::Sender<bool>,
    /// Re-register a moved tracker frame at the next frame check (taken by that check).
    pub reregister: Arc<AtomicBool>,
    /// Event stream: journalled events in journal order (a lagging receiver can replay the
    /// gap from the store).
    pub events: broadcast::Sender<Journalled>,
}

impl Control {
    /// New control state with an event channel of `capacity`.
    pub fn new(capacity: usize) -> Control {
        Control {
            armed: watch::channel(false).0,
            abort: CancellationToken::new(),
            pause: watch::channel(false).0,
            start: watch::channel(false).0,
            reregister: Arc::new(AtomicBool::new(false)),
            events: broadcast::channel(capacity).0,
        }
    }

    /// Apply a command (answers are routed by the caller to the prompter).
    pub fn apply(&self, cmd: &CampaignCommand) {
        match cmd {
            CampaignCommand::Arm => {
                self.armed.send_replace(true);
            }
            CampaignCommand::Disarm => {
                self.armed.send_replace(false);
            }
            CampaignCommand::Start => {
                self.start.send_replace(true);
            }
            CampaignCommand::Pause => {
                self.pause.send_replace(true);
            }
            CampaignCommand::Resume => {
                self.pause.send_replace(false);
            }
            CampaignCommand::Reregister => {
                self.reregister.store(true, Ordering::SeqCst);
                self.pause.send_replace(false);
            }
            CampaignCommand::Abort => self.abort.cancel(),
            CampaignCommand::Answer { .. } => {}
        }
    }

    /// Whether a re-registration was asked for; clears the request.
    pub fn take_reregister(&self) -> bool {
        self.reregister.swap(false, Ordering::SeqCst)
    }

    /// Whether motion is allowed.
    pub fn is_armed(&self) -> bool {
        *self.armed.borrow()
    }

    /// Publish an event the journal has stored (no receivers is fine); only the journalling
    /// code calls this, under the store lock, so receivers see journal order.
    pub(crate) fn publish(&self, e: Journalled) {
        let _ = self.events.send(e);
    }
}
