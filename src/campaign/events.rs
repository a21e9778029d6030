//! Commands into and events out of the campaign engine, and the shared control state.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, watch};
use tokio_util::sync::CancellationToken;

use crate::calibrate::{IdentCheck, SetupResult, StopReason};
use crate::cell::{Answer, DeviceKind, FaultKind, PromptContext};
use crate::store::{JournalEntry, JournalEvent, StoreError, StoredState};

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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// The state stored in the campaign row.
    pub fn stored(&self) -> StoredState {
        match self {
            CampaignState::Idle => StoredState::Idle,
            CampaignState::Armed => StoredState::Armed,
            CampaignState::Running => StoredState::Running,
            CampaignState::Paused { .. } => StoredState::Paused,
            CampaignState::Identifying => StoredState::Identifying,
            CampaignState::Done => StoredState::Done,
            CampaignState::Aborted => StoredState::Aborted,
            CampaignState::Failed { .. } => StoredState::Failed,
        }
    }

    /// Short name stored in the campaign row.
    pub fn name(&self) -> &'static str {
        self.stored().name()
    }

    /// Why it paused or failed (`None` for the other states).
    pub fn reason(&self) -> Option<&str> {
        match self {
            CampaignState::Paused { reason } | CampaignState::Failed { reason } => Some(reason),
            _ => None,
        }
    }
}

/// What the engine reports, as journalled and sent to clients: `{"event": kind, …fields}`.
/// Serialises and deserialises; a journal row of an unknown or older shape that does not read
/// as one of the typed variants is kept whole as [`CampaignEvent::Other`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
        /// Device (its lower-case name).
        #[serde(with = "device_name")]
        device: DeviceKind,
        /// Fault kind (its variant name, `BeamBroken`, …).
        #[serde(with = "fault_name")]
        kind: FaultKind,
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
    /// The cell setup was measured (tool frame, base registration).
    Setup {
        /// The setup result (written through a JSON value, keys sorted, as it always was).
        #[serde(serialize_with = "via_value")]
        result: Box<SetupResult>,
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
    /// The stop rule ended the identification poses (`campaign.stop_when = "predicted"`): the
    /// rest of them are skipped, never measured; the verification poses are measured in full.
    IdentStopped {
        /// Identification poses measured.
        after_poses: usize,
        /// Identification poses skipped.
        skipped: usize,
        /// Why: `min_gain` or `target`.
        reason: StopReason,
        /// The predicted mean verification error of the identification on them (mm).
        predicted_mm: f64,
        /// Every check so far, in order.
        history: Vec<IdentCheck>,
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
    /// A journal row that reads as none of the above (an older or unknown kind, a damaged
    /// text): kept whole, written back as it was read.
    #[serde(untagged)]
    Other(UnknownEvent),
}

/// A journal row of no known shape: its kind and its JSON (a text that is not JSON: that text
/// as a JSON string).
#[derive(Debug, Clone, PartialEq)]
pub struct UnknownEvent {
    /// The stored kind (the JSON's `event` field when read without its row).
    pub kind: String,
    /// The stored JSON.
    pub body: serde_json::Value,
}

impl Serialize for UnknownEvent {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.body.serialize(s)
    }
}

impl<'de> Deserialize<'de> for UnknownEvent {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let body = serde_json::Value::deserialize(d)?;
        let kind = body
            .get("event")
            .and_then(serde_json::Value::as_str)
            .unwrap_or_default()
            .to_owned();
        Ok(UnknownEvent { kind, body })
    }
}

/// Serialise through a [`serde_json::Value`] (object keys sorted): the setup result's journal
/// form since it was first journalled.
fn via_value<T: Serialize, S: serde::Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
    serde_json::to_value(v)
        .map_err(serde::ser::Error::custom)?
        .serialize(s)
}

/// [`DeviceKind`] as its lower-case name.
mod device_name {
    use super::DeviceKind;
    use serde::{Deserialize, Deserializer, Serializer};

    const ALL: [DeviceKind; 4] = [
        DeviceKind::Tracker,
        DeviceKind::Robot,
        DeviceKind::Stage,
        DeviceKind::Operator,
    ];

    pub(super) fn serialize<S: Serializer>(d: &DeviceKind, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(d.name())
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<DeviceKind, D::Error> {
        let name = String::deserialize(d)?;
        ALL.into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown device `{name}`")))
    }
}

/// A fault kind's journalled name, its variant name (`BeamBroken`, …): the `kind` of a `fault`
/// event, a metric label, the devices view's `last_fault.kind`.
pub fn fault_kind_name(kind: FaultKind) -> &'static str {
    fault_name::name(kind)
}

/// [`FaultKind`] as its variant name (`BeamBroken`, …).
mod fault_name {
    use super::FaultKind;
    use serde::{Deserialize, Deserializer, Serializer};

    const ALL: [FaultKind; 9] = [
        FaultKind::BeamBroken,
        FaultKind::Timeout,
        FaultKind::Disconnected,
        FaultKind::Rejected,
        FaultKind::EmergencyStop,
        FaultKind::NotReady,
        FaultKind::Protocol,
        FaultKind::Aborted,
        FaultKind::Device,
    ];

    /// The name journalled and counted (`BeamBroken`, …).
    pub(super) fn name(k: FaultKind) -> &'static str {
        match k {
            FaultKind::BeamBroken => "BeamBroken",
            FaultKind::Timeout => "Timeout",
            FaultKind::Disconnected => "Disconnected",
            FaultKind::Rejected => "Rejected",
            FaultKind::EmergencyStop => "EmergencyStop",
            FaultKind::NotReady => "NotReady",
            FaultKind::Protocol => "Protocol",
            FaultKind::Aborted => "Aborted",
            FaultKind::Device => "Device",
        }
    }

    pub(super) fn serialize<S: Serializer>(k: &FaultKind, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(name(*k))
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<FaultKind, D::Error> {
        let text = String::deserialize(d)?;
        ALL.into_iter()
            .find(|k| name(*k) == text)
            .ok_or_else(|| serde::de::Error::custom(format!("unknown fault kind `{text}`")))
    }

    #[cfg(test)]
    #[test]
    fn names_are_the_debug_names() {
        for k in ALL {
            assert_eq!(name(k), format!("{k:?}"));
        }
    }
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
    /// `stopped`, `ident_stopped`, `note`, `result`; an unknown row's stored kind).
    pub fn kind(&self) -> &str {
        match self {
            CampaignEvent::State { .. } => "state",
            CampaignEvent::Measured { .. } => "measured",
            CampaignEvent::Fault { .. } => "fault",
            CampaignEvent::Drift { .. } => "drift",
            CampaignEvent::Setup { .. } => "setup",
            CampaignEvent::Prompt { .. } => "prompt",
            CampaignEvent::Devices { .. } => "devices",
            CampaignEvent::Stopped { .. } => "stopped",
            CampaignEvent::IdentStopped { .. } => "ident_stopped",
            CampaignEvent::Note { .. } => "note",
            CampaignEvent::Result { .. } => "result",
            CampaignEvent::Other(u) => &u.kind,
        }
    }

    /// A fault event.
    pub fn fault(device: DeviceKind, kind: FaultKind, message: &str, action: &str) -> Self {
        CampaignEvent::Fault {
            device,
            kind,
            message: message.to_owned(),
            action: action.to_owned(),
        }
    }
}

impl JournalEvent for CampaignEvent {
    fn kind(&self) -> &str {
        CampaignEvent::kind(self)
    }

    fn to_text(&self) -> Result<String, StoreError> {
        serde_json::to_string(self).map_err(|e| StoreError::Invalid(format!("event: {e}")))
    }

    /// The typed event when the text reads as the kind its row names, else
    /// [`CampaignEvent::Other`] with the row's kind and JSON (a text that is not JSON as a
    /// JSON string).
    fn from_stored(kind: String, text: String) -> CampaignEvent {
        match serde_json::from_str::<CampaignEvent>(&text) {
            Ok(e) if !matches!(e, CampaignEvent::Other(_)) && e.kind() == kind => e,
            _ => CampaignEvent::Other(UnknownEvent {
                body: serde_json::from_str(&text).unwrap_or(serde_json::Value::String(text)),
                kind,
            }),
        }
    }
}

/// A live event as its campaign's journal stored it: every event on [`Control::events`] is
/// journalled first, so a client that missed some can read them back by sequence number
/// (`seq`: the store's row id, increasing in emission order).
pub type Journalled = JournalEntry<CampaignEvent>;

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
