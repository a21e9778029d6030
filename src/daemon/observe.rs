//! What the daemon learns from a loaded campaign's journalled events: the engine's state (for
//! command replies), the devices' status (`GET /api/devices`), the metrics, the structured
//! log lines of state changes and faults, and the run's progress lines ([`Progress`], target
//! `cellcal::progress`). One observer task per loaded campaign reads the live
//! channel from before the engine starts, and replays from the journal whatever a lag lost, so
//! it sees every event once, in journal order.
//!
//! # What "connected" means
//! The daemon opens no device connection of its own: the engine's adapters connect when the
//! run prepares its devices (after `start`). So a device is `connected: null` when no campaign
//! runs (nothing is held, nothing is known), `false` while a loaded campaign has not yet
//! completed a cell step, or since the device's last connection fault (`Disconnected`,
//! `Timeout`, `Protocol`), and `true` from the next completed step on (a `setup`, `drift` or
//! `measured` event: every device answered for it). A manual stage without a gauge has no
//! connection: always `null`. `connection` ([`Connection`]) says the same for a person: it
//! tells "not connected yet" (`false` before the first completed step, `null` before any run)
//! from a connection fault and from a closed run.

use std::sync::{Arc, Mutex as StdMutex};

use serde::Serialize;
use tokio::sync::broadcast;

use super::lock;
use super::status::RunWatch;
use crate::campaign::events::fault_kind_name;
use crate::campaign::{CampaignEvent, Journalled};
use crate::cell::{DeviceKind, FaultKind};
use crate::config::{CellConfig, DeviceMode, StageMode};
use crate::metrics::Metrics;
use crate::progress::Progress;
use crate::sim::RunningSimCell;
use crate::store::ReaderPool;

/// A device's last fault, as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct FaultView {
    /// Fault kind (`Disconnected`, `BeamBroken`, `Timeout`, `EmergencyStop`, …).
    pub kind: String,
    /// The driver's message.
    pub message: String,
    /// When it was journalled (ms since the Unix epoch).
    pub at_ms: i64,
    /// What the engine did (`relock`, `reconnect`, `retry`, `pause`, …).
    pub action: String,
    /// The campaign it happened in.
    pub campaign: i64,
}

/// One device as clients see it.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct DeviceView {
    /// Protocol: `emscon` (tracker), `robotlink` (robot), `zaber` or `manual` (stage).
    pub kind: &'static str,
    /// Where it is reached: the configured address or serial path; for a simulated device the
    /// simulated cell's loopback address or pty while a campaign runs, else `null`. A manual
    /// stage without a gauge has none.
    pub address: Option<String>,
    /// Part of the simulated cell.
    pub simulated: bool,
    /// See the module doc: `null` when unknown (no campaign running), `false` before the first
    /// completed cell step or after a connection fault, `true` after a completed step.
    pub connected: Option<bool>,
    /// The last fault the engine journalled for this device (kept after the campaign ends).
    pub last_fault: Option<FaultView>,
    /// What the device said it is (model, serial, firmware) when a run last prepared it;
    /// kept after the campaign ends, `null` before any run prepared it or when it cannot say.
    pub identity: Option<String>,
    /// `connected` for a person: not connected yet, connected, a connection fault, closed
    /// after a run, or no connection to make.
    pub connection: Connection,
}

/// What a client may say of a device's connection: `connected` with its `null` and `false`
/// told apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Connection {
    /// No run of this daemon has connected it yet, or the loaded run has not yet completed a
    /// cell step (`connected` `null` before any run, `false` in a run).
    NotConnectedYet,
    /// It answered for the last completed cell step (`connected: true`).
    Connected,
    /// A connection fault (`Disconnected`, `Timeout`, `Protocol`) since the last completed
    /// step (`connected: false`).
    Fault,
    /// The last run ended and closed its connections; no campaign runs (`connected: null`).
    Closed,
    /// The device has no connection: a manual micrometer without a gauge (`connected: null`).
    NoConnection,
}

/// The cell's three devices.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct DevicesView {
    /// The laser tracker.
    pub tracker: DeviceView,
    /// The robot controller.
    pub robot: DeviceView,
    /// The 1D stage (motorised or manual micrometer).
    pub stage: DeviceView,
}

/// What a run learned of one device.
#[derive(Debug, Clone, Default)]
struct Watched {
    /// The simulated device's address during a run.
    sim_address: Option<String>,
    connected: Option<bool>,
    /// A connection fault since the last completed step of this run.
    faulted: bool,
    last_fault: Option<FaultView>,
    identity: Option<String>,
}

/// The devices' status, updated by the observer.
#[derive(Debug, Default)]
pub(super) struct CellWatch {
    /// Tracker, robot, stage.
    devices: [Watched; 3],
    /// Counts the runs loaded: a late end of an older run leaves a newer one alone.
    run: u64,
}

/// The index of a device in [`CellWatch::devices`] (the operator has none).
fn device_index(device: DeviceKind) -> Option<usize> {
    match device {
        DeviceKind::Tracker => Some(0),
        DeviceKind::Robot => Some(1),
        DeviceKind::Stage => Some(2),
        DeviceKind::Operator => None,
    }
}

/// Whether a fault kind means the device's connection is gone or broken.
fn is_connection_fault(kind: FaultKind) -> bool {
    matches!(
        kind,
        FaultKind::Disconnected | FaultKind::Timeout | FaultKind::Protocol
    )
}

/// Whether the configured stage has a connection at all (a plain manual micrometer has none).
fn stage_connects(cfg: &CellConfig) -> bool {
    cfg.stage.kind != StageMode::Manual
}

impl CellWatch {
    /// A campaign was loaded on `cfg`'s cell (simulated devices at `sim`'s addresses): nothing
    /// is connected until its run completes a cell step.
    /// Returns the run's number for [`CellWatch::run_ended`].
    pub(super) fn run_loaded(&mut self, cfg: &CellConfig, sim: Option<&RunningSimCell>) -> u64 {
        let stage_sim = match cfg.stage.kind {
            StageMode::Serial => sim.and_then(|s| s.stage_path.clone()),
            StageMode::Manual => None,
            StageMode::ManualGauge => sim.and_then(|s| s.gauge_path.clone()),
        };
        let addrs = [
            sim.map(|s| s.tracker_addr.to_string()),
            sim.map(|s| s.robot_addr.to_string()),
            stage_sim,
        ];
        for (i, (d, a)) in self.devices.iter_mut().zip(addrs).enumerate() {
            d.sim_address = a;
            d.connected = (i < 2 || stage_connects(cfg)).then_some(false);
            d.faulted = false;
        }
        self.run += 1;
        self.run
    }

    /// Run `run` ended: its connections are closed, its simulated devices gone.
    pub(super) fn run_ended(&mut self, run: u64) {
        if run != self.run {
            return;
        }
        for d in &mut self.devices {
            d.sim_address = None;
            d.connected = None;
            d.faulted = false;
        }
    }

    /// A completed cell step: every device with a connection answered.
    fn step_done(&mut self) {
        for d in &mut self.devices {
            if d.connected.is_some() {
                d.connected = Some(true);
                d.faulted = false;
            }
        }
    }

    /// The run prepared every device (a completed step); each said what it is.
    fn prepared(&mut self, identities: [Option<String>; 3]) {
        self.step_done();
        for (d, id) in self.devices.iter_mut().zip(identities) {
            d.identity = id;
        }
    }

    /// A journalled fault of `kind` of `device`.
    fn fault(&mut self, device: DeviceKind, kind: FaultKind, f: FaultView) {
        let Some(d) = device_index(device).map(|i| &mut self.devices[i]) else {
            return;
        };
        if is_connection_fault(kind) && d.connected.is_some() {
            d.connected = Some(false);
            d.faulted = true;
        }
        d.last_fault = Some(f);
    }

    /// The clients' view, with the configuration's static facts.
    pub(super) fn view(&self, cfg: &CellConfig) -> DevicesView {
        let sim = |m: DeviceMode| m == DeviceMode::Sim;
        let [t, r, s] = &self.devices;
        let stage_address = match cfg.stage.kind {
            StageMode::Serial => Some(cfg.stage.serial_path.clone()),
            StageMode::Manual => None,
            StageMode::ManualGauge => Some(cfg.stage.gauge_path.clone()),
        };
        let ran = self.run > 0;
        let connection = |w: &Watched, connects: bool| match w.connected {
            _ if !connects => Connection::NoConnection,
            Some(true) => Connection::Connected,
            Some(false) if w.faulted => Connection::Fault,
            Some(false) => Connection::NotConnectedYet,
            None if ran => Connection::Closed,
            None => Connection::NotConnectedYet,
        };
        let one = |kind, w: &Watched, simulated: bool, configured: Option<String>| DeviceView {
            kind,
            address: if simulated {
                w.sim_address.clone()
            } else {
                configured
            },
            simulated,
            connected: w.connected,
            last_fault: w.last_fault.clone(),
            identity: w.identity.clone(),
            connection: connection(w, kind != "manual" || stage_connects(cfg)),
        };
        DevicesView {
            tracker: one(
                "emscon",
                t,
                sim(cfg.tracker.mode),
                Some(cfg.tracker.address.clone()),
            ),
            robot: one(
                "robotlink",
                r,
                sim(cfg.robot_controller.mode),
                Some(cfg.robot_controller.address.clone()),
            ),
            stage: one(
                match cfg.stage.kind {
                    StageMode::Serial => "zaber",
                    StageMode::Manual | StageMode::ManualGauge => "manual",
                },
                s,
                sim(cfg.stage.mode),
                stage_address,
            ),
        }
    }
}

/// The observer of one loaded campaign.
pub(super) struct Observer {
    /// Campaign id.
    pub(super) id: i64,
    /// The journal's last sequence number before this run.
    pub(super) run_start: i64,
    pub(super) readers: Arc<ReaderPool>,
    pub(super) metrics: Arc<Metrics>,
    pub(super) cell: Arc<StdMutex<CellWatch>>,
    /// The run's status: the observer writes the engine's state into it; its end ends the
    /// observer.
    pub(super) status: RunWatch,
    /// The run's number ([`CellWatch::run_loaded`]).
    pub(super) run: u64,
    /// The run's progress lines (as `cellcal run --progress lines` prints them).
    pub(super) progress: StdMutex<Progress>,
}

impl Observer {
    /// Follow the run's events from `rx` (subscribed before the engine started) until its final
    /// state or the run's end; a lag is replayed from the journal. Then mark the run ended.
    /// Cancel-safe: it only reads and updates in-memory status.
    pub(super) async fn run(self, mut rx: broadcast::Receiver<Journalled>) {
        let mut last = self.run_start;
        loop {
            let more = tokio::select! {
                biased;
                r = rx.recv() => match r {
                    Ok(j) if j.seq <= last => true,
                    Ok(j) => {
                        last = j.seq;
                        self.note(&j)
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => self.replay(&mut last).await,
                    Err(broadcast::error::RecvError::Closed) => {
                        self.replay(&mut last).await;
                        false
                    }
                },
                _ = self.status.ended() => {
                    self.replay(&mut last).await;
                    false
                }
            };
            if !more {
                break;
            }
        }
        lock(&self.cell).run_ended(self.run);
    }

    /// Note the journal entries after `*last`; `false` once the run's final state is among them.
    /// Cancel-safe: no state changes before the only await (the journal read); the entries are then
    /// noted without an await.
    async fn replay(&self, last: &mut i64) -> bool {
        let (id, after) = (self.id, *last);
        let page = self
            .readers
            .read(move |s| s.events_after::<CampaignEvent>(id, after, usize::MAX))
            .await;
        let entries = match page {
            Ok(e) => e,
            Err(e) => {
                tracing::error!(campaign = id, error = %e, "cannot read the journal back after a lag");
                return true;
            }
        };
        for e in entries {
            *last = e.seq;
            let ends = e.event.ends_run();
            self.note(&e);
            if ends {
                return false;
            }
        }
        true
    }

    /// Take one journal entry into the state, devices, metrics and log; `false` when it ends
    /// the run.
    fn note(&self, e: &Journalled) -> bool {
        if let Some(line) = lock(&self.progress).line(e) {
            let id = self.id;
            tracing::info!(target: "cellcal::progress", campaign = id, "campaign {id} progress: {line}");
        }
        match &e.event {
            CampaignEvent::State { state } => {
                let name = state.name();
                match state.reason() {
                    None => {
                        tracing::info!(campaign = self.id, seq = e.seq, state = %name, "campaign state")
                    }
                    Some(reason) => {
                        tracing::warn!(campaign = self.id, seq = e.seq, state = %name, reason, "campaign state")
                    }
                }
                self.metrics.event(&e.event);
                self.status.set_state(state.stored());
                return !e.event.ends_run();
            }
            CampaignEvent::Fault {
                device,
                kind,
                message,
                action,
            } => {
                let (device_name, kind_name) = (device.name(), fault_kind_name(*kind));
                tracing::warn!(
                    campaign = self.id,
                    seq = e.seq,
                    device = device_name,
                    kind = kind_name,
                    action = action.as_str(),
                    detail = message.as_str(),
                    "device fault"
                );
                self.metrics.event(&e.event);
                let f = FaultView {
                    kind: kind_name.to_owned(),
                    message: message.clone(),
                    at_ms: e.at_ms,
                    action: action.clone(),
                    campaign: self.id,
                };
                lock(&self.cell).fault(*device, *kind, f);
            }
            CampaignEvent::Measured { .. } => {
                self.metrics.event(&e.event);
                lock(&self.cell).step_done();
            }
            CampaignEvent::Setup { .. } | CampaignEvent::Drift { .. } => {
                lock(&self.cell).step_done()
            }
            CampaignEvent::Devices {
                tracker,
                robot,
                stage,
            } => {
                let said = |s: &Option<String>| s.clone().filter(|s| !s.is_empty());
                lock(&self.cell).prepared([said(tracker), said(robot), said(stage)]);
            }
            _ => {}
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::parse_cell_config;

    fn cfg(stage: &str) -> CellConfig {
        let text = format!("robot = \"r.toml\"\n[stage]\nkind = \"{stage}\"\n");
        parse_cell_config(&text, std::path::Path::new("/cell.toml")).expect("config")
    }

    fn fault(kind: &str) -> FaultView {
        FaultView {
            kind: kind.into(),
            message: "m".into(),
            at_ms: 1,
            action: "reconnect".into(),
            campaign: 1,
        }
    }

    fn connected(w: &CellWatch, c: &CellConfig) -> [Option<bool>; 3] {
        let v = w.view(c);
        [v.tracker.connected, v.robot.connected, v.stage.connected]
    }

    #[test]
    fn connected_is_learned_from_the_run_and_unknown_without_one() {
        let c = cfg("serial");
        let mut w = CellWatch::default();
        assert_eq!(connected(&w, &c), [None; 3]);
        let run = w.run_loaded(&c, None);
        assert_eq!(connected(&w, &c), [Some(false); 3]);
        w.step_done();
        assert_eq!(connected(&w, &c), [Some(true); 3]);
        // a beam break is no connection fault; a timeout is
        w.fault(
            DeviceKind::Tracker,
            FaultKind::BeamBroken,
            fault("BeamBroken"),
        );
        assert_eq!(connected(&w, &c), [Some(true); 3]);
        w.fault(DeviceKind::Robot, FaultKind::Timeout, fault("Timeout"));
        assert_eq!(connected(&w, &c), [Some(true), Some(false), Some(true)]);
        assert_eq!(w.view(&c).robot.last_fault, Some(fault("Timeout")));
        w.step_done();
        assert_eq!(connected(&w, &c), [Some(true); 3]);
        // an older run's late end leaves the newer run alone
        let newer = w.run_loaded(&c, None);
        w.run_ended(run);
        assert_eq!(connected(&w, &c), [Some(false); 3]);
        w.run_ended(newer);
        assert_eq!(connected(&w, &c), [None; 3]);
        // the last faults stay
        assert_eq!(w.view(&c).tracker.last_fault, Some(fault("BeamBroken")));
    }

    fn connection(w: &CellWatch, c: &CellConfig) -> [Connection; 3] {
        let v = w.view(c);
        [v.tracker.connection, v.robot.connection, v.stage.connection]
    }

    #[test]
    fn not_connected_yet_is_told_from_a_fault_and_a_closed_run() {
        use Connection::{Closed, Connected, Fault, NoConnection, NotConnectedYet};
        let c = cfg("serial");
        let mut w = CellWatch::default();
        assert_eq!(connection(&w, &c), [NotConnectedYet; 3]);
        let run = w.run_loaded(&c, None);
        assert_eq!(connection(&w, &c), [NotConnectedYet; 3]);
        w.fault(
            DeviceKind::Robot,
            FaultKind::Disconnected,
            fault("Disconnected"),
        );
        assert_eq!(
            connection(&w, &c),
            [NotConnectedYet, Fault, NotConnectedYet]
        );
        w.step_done();
        assert_eq!(connection(&w, &c), [Connected; 3]);
        w.fault(DeviceKind::Stage, FaultKind::Timeout, fault("Timeout"));
        assert_eq!(connection(&w, &c), [Connected, Connected, Fault]);
        w.run_ended(run);
        assert_eq!(connection(&w, &c), [Closed; 3]);
        // a new run starts afresh
        w.run_loaded(&c, None);
        assert_eq!(connection(&w, &c), [NotConnectedYet; 3]);
        // a manual micrometer never connects; a gauge does
        let manual = cfg("manual");
        assert_eq!(connection(&w, &manual)[2], NoConnection);
        assert_eq!(connection(&w, &cfg("manual_gauge"))[2], NotConnectedYet);
    }

    #[test]
    fn a_manual_micrometer_has_no_connection() {
        let c = cfg("manual");
        let mut w = CellWatch::default();
        w.run_loaded(&c, None);
        w.step_done();
        let v = w.view(&c);
        assert_eq!(v.stage.kind, "manual");
        assert_eq!((v.stage.connected, v.stage.address), (None, None));
        assert_eq!(v.tracker.connected, Some(true));
        // a simulated device has no address without a run
        assert_eq!(v.tracker.kind, "emscon");
        assert!(v.tracker.simulated);
        assert_eq!(v.tracker.address, None);
    }
}
