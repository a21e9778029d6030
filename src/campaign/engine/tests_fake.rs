//! The engine's state machine and fault policy against in-memory fake devices
//! ([`crate::sim::fake`]: the simulated world's true robot behind the device traits, with
//! fault scripts) and a real SQLite store in a temporary file: no TCP, no pty. Each test asserts
//! what is observable — the stored state and rows, the journal's events, what the fake devices
//! were commanded — and mirrors a policy of the module doc of [`super`].

use std::sync::{Arc, Mutex};

use std::time::Duration;

use nalgebra::Vector3;

use super::{
    check_travel, run_campaign, settle_error, CampaignContext, Devices, FaultPolicy, Outcome,
    DISARMED, ROBOT_RECONNECTED,
};
use crate::campaign::events::{CampaignCommand, CampaignEvent, CampaignState, Control};
use crate::campaign::session::plan_request;
use crate::cell::FaultKind;
use crate::config::{parse_cell_config, CellConfig};
use crate::dataset::PoseSet;
use crate::plan::plan_campaign;
use crate::sim::fake::{Call, FakeCell, Fault, Op};
use crate::store::{NewCampaign, PointKind, PointRecord, Store, StoreHandle};

/// config/cell.sim.toml, the configuration of the TCP/pty tests this module mirrors.
const CONFIG: &str = include_str!("../../../config/cell.sim.toml");

/// `text` with `from` replaced by `to` (`from` must be there: a renamed key fails loudly).
fn edit(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "config/cell.sim.toml has no `{from}`");
    text.replacen(from, to, 1)
}

/// config/cell.sim.toml with `poses` poses (`ident` of them to identify), no setup steps
/// unless `setup`, and the extra `edits`.
fn config(poses: usize, ident: usize, setup: bool, edits: &[(&str, &str)]) -> CellConfig {
    let mut text = edit(CONFIG, "poses = 300", &format!("poses = {poses}"));
    text = edit(&text, "ident = 100", &format!("ident = {ident}"));
    if !setup {
        text = edit(&text, "tool_frame = true", "tool_frame = false");
        text = edit(
            &text,
            "base_registration = true",
            "base_registration = false",
        );
    }
    for (from, to) in edits {
        text = edit(&text, from, to);
    }
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml");
    parse_cell_config(&text, &path).expect("config")
}

/// A temporary directory for the store file: in memory-backed `/dev/shm` where there is one
/// (the same SQLite file and code; only the disk's fsyncs, ~95 % of these tests' time on a
/// loaded disk, are gone), else the system's temporary directory.
fn scratch_dir() -> tempfile::TempDir {
    let shm = std::path::Path::new("/dev/shm");
    if shm.is_dir() {
        if let Ok(dir) = tempfile::tempdir_in(shm) {
            return dir;
        }
    }
    tempfile::tempdir().expect("tempdir")
}

/// A campaign planned and stored on a temporary SQLite file, its fake cell and its devices.
struct Bench {
    ctx: CampaignContext,
    cell: FakeCell,
    devices: Devices,
    _dir: tempfile::TempDir,
}

impl Bench {
    /// A new campaign of `cfg` on the fake cell of its `[sim]` table, with a motorised stage
    /// (a manual one when `manual`), stopping in `failed` on an operator fault.
    fn new(cfg: CellConfig, manual: bool) -> Bench {
        let dir = scratch_dir();
        let store = Store::open(&dir.path().join("c.db")).expect("store");
        Bench::on_store(cfg, manual, StoreHandle::new(store), None, dir)
    }

    /// [`Bench::new`] on an open store; `campaign` resumes a stored one.
    fn on_store(
        cfg: CellConfig,
        manual: bool,
        store: StoreHandle,
        campaign: Option<i64>,
        dir: tempfile::TempDir,
    ) -> Bench {
        let mut nominal = crate::model::tx60();
        nominal.tool = Vector3::from(cfg.campaign.tool_mm);
        let req = plan_request(&cfg);
        let plan = plan_campaign(&nominal, &req).expect("plan");
        let campaign_id = match campaign {
            Some(id) => id,
            None => {
                let planned = crate::campaign::session::planned_poses(&plan);
                let new = NewCampaign {
                    name: "fake".into(),
                    created_at_ms: 0,
                    model: cfg.campaign.model.to_string(),
                    seed: cfg.campaign.seed,
                    config_toml: cfg.text.clone(),
                    robot_toml: String::new(),
                };
                store
                    .blocking(|s| s.create_campaign(&new, &planned))
                    .expect("campaign")
            }
        };
        let cell = FakeCell::from_sim(&nominal, cfg.sim.as_ref());
        let devices = Devices {
            tracker: cell.tracker(),
            robot: cell.robot(),
            stage: cell.stage(manual),
        };
        let probe_store = store.clone();
        cell.probe_at_move(Arc::new(move || {
            probe_store
                .blocking(|s| s.done_poses(campaign_id))
                .expect("done poses")
                .len()
        }));
        Bench {
            ctx: CampaignContext {
                cfg,
                nominal,
                plan_request: req,
                plan,
                store,
                campaign_id,
                control: Control::new(4096),
                on_fault: FaultPolicy::Fail,
                iso: None,
                estimate: None,
            },
            cell,
            devices,
            _dir: dir,
        }
    }

    /// The joint target of the `k`-th pose in move order (from 1).
    fn pose_q(&self, k: usize) -> Vec<f64> {
        self.ctx.plan.poses[k - 1].q_rad.clone()
    }

    /// Arm, start and run to the end; `steer` sees every event with the control (the operator)
    /// and the fake cell. Returns the outcome and every event of the run, in journal order.
    async fn run(
        &mut self,
        mut steer: impl FnMut(&CampaignEvent, &Control, &FakeCell) + Send + 'static,
    ) -> (Outcome, Vec<CampaignEvent>) {
        let mut all = self.ctx.control.events.subscribe();
        let mut rx = self.ctx.control.events.subscribe();
        let (control, cell) = (self.ctx.control.clone(), self.cell.clone());
        let steering = tokio::spawn(async move {
            while let Ok(j) = rx.recv().await {
                steer(&j.event, &control, &cell);
            }
        });
        self.ctx.control.apply(&CampaignCommand::Arm);
        self.ctx.control.apply(&CampaignCommand::Start);
        let outcome = tokio::time::timeout(
            Duration::from_secs(60),
            run_campaign(&self.ctx, &mut self.devices),
        )
        .await
        .expect("the run ends")
        .expect("the run stores its final state");
        steering.abort();
        let mut events = Vec::new();
        while let Ok(j) = all.try_recv() {
            events.push(j.event);
        }
        let id = self.ctx.campaign_id;
        let journalled = self
            .with_store(|s| s.events::<CampaignEvent>(id))
            .expect("events");
        assert!(
            journalled.len() >= events.len(),
            "every live event is journalled"
        );
        (outcome, events)
    }

    fn with_store<R>(&self, f: impl FnOnce(&mut Store) -> R) -> R {
        self.ctx.store.blocking(f)
    }

    fn done(&self) -> Vec<usize> {
        let id = self.ctx.campaign_id;
        self.with_store(|s| s.done_poses(id)).expect("done")
    }

    fn stored_state(&self) -> String {
        let id = self.ctx.campaign_id;
        self.with_store(|s| s.campaign(id))
            .expect("row")
            .state
            .name()
            .to_string()
    }

    fn discarded(&self) -> usize {
        let id = self.ctx.campaign_id;
        self.with_store(|s| s.point_count(id, PointKind::Discarded))
            .expect("points")
    }

    /// The MOVEJ targets sent, in order.
    fn moves(&self) -> Vec<Vec<f64>> {
        self.cell
            .calls()
            .into_iter()
            .filter_map(|c| match c {
                Call::MoveJ { q, .. } => Some(q),
                _ => None,
            })
            .collect()
    }

    /// How many MOVEJs went to the `k`-th pose.
    fn moves_to(&self, k: usize) -> usize {
        let q = self.pose_q(k);
        self.moves().iter().filter(|m| **m == q).count()
    }

    /// Every pose of the plan committed exactly once.
    fn assert_complete(&self) {
        let mut done = self.done();
        let n = done.len();
        done.sort_unstable();
        done.dedup();
        assert_eq!(done.len(), n, "a pose committed twice");
        assert_eq!(n, self.ctx.plan.poses.len(), "every pose committed");
    }
}

/// The state names of `events`, in order.
fn states(events: &[CampaignEvent]) -> Vec<&'static str> {
    events
        .iter()
        .filter_map(|e| match e {
            CampaignEvent::State { state } => Some(state.name()),
            _ => None,
        })
        .collect()
}

/// The pause reasons of `events`, in order.
fn pauses(events: &[CampaignEvent]) -> Vec<String> {
    events
        .iter()
        .filter_map(|e| match e {
            CampaignEvent::State {
                state: CampaignState::Paused { reason },
            } => Some(reason.clone()),
            _ => None,
        })
        .collect()
}

/// (device, kind, action) of every fault event, in order.
fn faults(events: &[CampaignEvent]) -> Vec<(String, String, String)> {
    events
        .iter()
        .filter_map(|e| match e {
            CampaignEvent::Fault {
                device,
                kind,
                action,
                ..
            } => Some((
                device.name().to_string(),
                crate::campaign::events::fault_kind_name(*kind).to_string(),
                action.clone(),
            )),
            _ => None,
        })
        .collect()
}

fn fault(device: &str, kind: &str, action: &str) -> (String, String, String) {
    (device.into(), kind.into(), action.into())
}

/// The `stopped` events: (reason, robot, stage).
fn stops(events: &[CampaignEvent]) -> Vec<(String, String, String)> {
    events
        .iter()
        .filter_map(|e| match e {
            CampaignEvent::Stopped {
                reason,
                robot,
                stage,
            } => Some((reason.clone(), robot.clone(), stage.clone())),
            _ => None,
        })
        .collect()
}

/// The operator resumes at every pause.
fn resume_every_pause(e: &CampaignEvent, c: &Control, _: &FakeCell) {
    if matches!(
        e,
        CampaignEvent::State {
            state: CampaignState::Paused { .. }
        }
    ) {
        c.apply(&CampaignCommand::Resume);
    }
}

fn nobody(_: &CampaignEvent, _: &Control, _: &FakeCell) {}

/// The index in `calls` of the `n`-th (from 1) call matching `is`.
fn nth_call(calls: &[Call], n: usize, is: impl Fn(&Call) -> bool) -> usize {
    calls
        .iter()
        .enumerate()
        .filter(|(_, c)| is(c))
        .nth(n - 1)
        .map(|(i, _)| i)
        .expect("that call was made")
}

const POSES: usize = 30;
const IDENT: usize = 20;

#[tokio::test]
async fn a_clean_run_commits_every_pose_once_before_the_robot_moves_on() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(states(&events), ["armed", "running", "identifying", "done"]);
    assert_eq!(b.stored_state(), "done");
    b.assert_complete();
    assert!(faults(&events).is_empty(), "{:?}", faults(&events));
    let id = b.ctx.campaign_id;
    assert!(b
        .with_store(|s| s.latest_result(id))
        .expect("result")
        .is_some());
    let calls = b.cell.calls();
    // the devices are prepared (robot first: power on) before anything moves
    assert_eq!(
        calls[..3],
        [
            Call::RobotPrepare(100.0),
            Call::TrackerPrepare,
            Call::StagePrepare
        ]
    );
    // commit before move: every MOVEJ sees each pose started before it committed
    let targets: Vec<Vec<f64>> = (1..=POSES).map(|k| b.pose_q(k)).collect();
    let mut started = 0;
    for c in &calls {
        if let Call::MoveJ { q, probe } = c {
            assert_eq!(
                *probe, started,
                "a MOVEJ before the previous pose was committed"
            );
            started += usize::from(targets.contains(q));
        }
    }
    assert_eq!(started, POSES);
    // two points a pose, the frame reference and the final drift check; nothing stopped
    assert_eq!(b.cell.count(Op::Measure), 2 * POSES as u64 + 2);
    assert!(!calls.contains(&Call::RobotStop));
    let measured: Vec<usize> = events
        .iter()
        .filter_map(|e| match e {
            CampaignEvent::Measured { done, .. } => Some(*done),
            _ => None,
        })
        .collect();
    assert_eq!(measured, (1..=POSES).collect::<Vec<_>>());
}

#[tokio::test]
async fn a_beam_break_relocks_and_measures_the_point_again() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    // measure 1 is the frame reference, 2 and 3 pose 1's P1 and P2
    b.cell
        .on(Op::Measure, 3, 1, Fault::Fail(FaultKind::BeamBroken));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(faults(&events), [fault("tracker", "BeamBroken", "relock")]);
    let calls = b.cell.calls();
    let broken = nth_call(&calls, 3, |c| matches!(c, Call::Measure(_)));
    assert_eq!(calls[broken], Call::Measure(None));
    // no base registered: nothing predicts the ball, the tracker searches
    assert_eq!(calls[broken + 1], Call::Relock(None));
    assert!(matches!(calls[broken + 2], Call::Measure(Some(_))));
    assert_eq!(b.cell.count(Op::Measure), 2 * POSES as u64 + 3);
    assert_eq!(b.discarded(), 0, "nothing of a broken beam is kept");
    b.assert_complete();
}

#[tokio::test]
async fn a_relock_looks_first_where_the_registered_base_puts_the_ball() {
    let mut b = Bench::new(config(POSES, IDENT, true, &[]), false);
    // break the beam at the 5th pose's P1, well after the setup
    let q5 = b.pose_q(5);
    let fired = Arc::new(Mutex::new(false));
    let once = Arc::clone(&fired);
    let breaks = b.cell.clone();
    b.cell.on_target(
        Op::MoveJ,
        &q5,
        1,
        Fault::Then(Arc::new(move || {
            *once.lock().expect("flag") = true;
            let n = breaks.count(Op::Measure);
            breaks.on(Op::Measure, n + 1, 1, Fault::Fail(FaultKind::BeamBroken));
        })),
    );
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert!(*fired.lock().expect("flag"));
    assert_eq!(faults(&events), [fault("tracker", "BeamBroken", "relock")]);
    let calls = b.cell.calls();
    let i = calls
        .iter()
        .position(|c| matches!(c, Call::Relock(_)))
        .expect("a relock");
    let (Call::Relock(Some(predicted)), Call::Measure(Some(found))) = (&calls[i], &calls[i + 1])
    else {
        panic!("{:?}", &calls[i..i + 2]);
    };
    assert!(
        (predicted - found).norm() < 2.0,
        "predicted {predicted:?}, the ball is at {found:?}"
    );
}

#[tokio::test]
async fn beam_breaks_beyond_max_attempts_fail_a_headless_run_and_stop_every_device() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    // measure 4 is pose 2's P1: it never comes back (max_attempts = 5)
    b.cell
        .on(Op::Measure, 4, 5, Fault::Fail(FaultKind::BeamBroken));
    let (outcome, events) = b.run(nobody).await;
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(
        reason.contains("no acceptable point after 5 attempts"),
        "{reason}"
    );
    assert_eq!(faults(&events).len(), 5);
    assert_eq!(b.cell.count(Op::Relock), 5);
    assert_eq!(b.stored_state(), "failed");
    assert_eq!(b.done().len(), 1, "pose 1 kept, pose 2 not committed");
    assert_eq!(
        stops(&events),
        [("fault".into(), "stopped".into(), "stopped".into())]
    );
    let calls = b.cell.calls();
    let last_move = calls
        .iter()
        .rposition(|c| matches!(c, Call::MoveJ { .. }))
        .expect("moves");
    let stop = calls
        .iter()
        .position(|c| *c == Call::RobotStop)
        .expect("robot stopped");
    assert!(stop > last_move, "nothing moved after the stop");
    assert!(calls.contains(&Call::StageStop));
    assert_eq!(b.moves_to(3), 0, "the run ended at pose 2");
}

#[tokio::test]
async fn under_the_pause_policy_an_operator_fault_pauses_and_resume_re_prepares_and_completes() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.ctx.on_fault = FaultPolicy::Pause;
    b.cell
        .on(Op::Measure, 4, 5, Fault::Fail(FaultKind::BeamBroken));
    let (outcome, events) = b.run(resume_every_pause).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let p = pauses(&events);
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(p[0].contains("no acceptable point"), "{p:?}");
    // the devices are stopped before the pause (nothing moves while the operator looks)
    assert_eq!(
        stops(&events),
        [("fault".into(), "stopped".into(), "stopped".into())]
    );
    assert_eq!(
        b.cell.count(Op::RobotPrepare),
        2,
        "prepared again on resume"
    );
    assert_eq!(b.moves_to(2), 2, "pose 2 measured again from its move");
    b.assert_complete();
}

#[tokio::test]
async fn a_tracker_disconnect_or_timeout_reconnects_and_a_not_ready_waits() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.cell
        .on(Op::Measure, 3, 1, Fault::Fail(FaultKind::Disconnected))
        .on(Op::Measure, 7, 1, Fault::Fail(FaultKind::Timeout))
        .on(Op::Measure, 11, 1, Fault::Fail(FaultKind::NotReady));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(
        faults(&events),
        [
            fault("tracker", "Disconnected", "reconnect"),
            fault("tracker", "Timeout", "reconnect"),
            fault("tracker", "NotReady", "wait"),
        ]
    );
    assert_eq!(b.cell.count(Op::TrackerReconnect), 2);
    assert_eq!(b.cell.count(Op::Relock), 0);
    assert_eq!(b.cell.count(Op::Measure), 2 * POSES as u64 + 5);
    b.assert_complete();
}

#[tokio::test]
async fn a_point_above_the_quality_gate_is_kept_discarded_and_measured_again() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.cell.on(Op::Measure, 3, 1, Fault::Noisy(0.2));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(faults(&events), [fault("tracker", "Device", "retry")]);
    assert_eq!(b.discarded(), 1);
    b.assert_complete();
}

#[tokio::test]
async fn a_tracker_refusal_is_an_operator_fault_at_once() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.cell
        .on(Op::Measure, 3, 1, Fault::Fail(FaultKind::Rejected));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Failed(_)), "{outcome:?}");
    assert_eq!(faults(&events), [fault("tracker", "Rejected", "pause")]);
    assert_eq!(b.cell.count(Op::Measure), 3, "not measured again");
    assert_eq!(b.discarded(), 1, "pose 1's P1 kept as discarded");
    assert!(b.done().is_empty());
}

#[tokio::test]
async fn a_move_whose_wait_times_out_stops_the_robot_and_is_repeated() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let q5 = b.pose_q(5);
    b.cell
        .on_target(Op::WaitSettled, &q5, 1, Fault::Fail(FaultKind::Timeout));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(faults(&events), [fault("robot", "Timeout", "stop, retry")]);
    let calls = b.cell.calls();
    let first = calls
        .iter()
        .position(|c| matches!(c, Call::MoveJ { q, .. } if *q == q5))
        .expect("moved to pose 5");
    assert_eq!(
        calls[first + 1..first + 3],
        [Call::WaitSettled, Call::RobotStop]
    );
    assert_eq!(b.moves_to(5), 2, "the move repeated once");
    assert_eq!(b.cell.count(Op::RobotReconnect), 0);
    b.assert_complete();
}

#[tokio::test]
async fn a_robot_reconnect_never_powers_the_arm_on_and_pauses_until_resumed() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.ctx.on_fault = FaultPolicy::Pause;
    let q4 = b.pose_q(4);
    b.cell
        .on_target(Op::MoveJ, &q4, 1, Fault::Fail(FaultKind::Disconnected));
    let (outcome, events) = b.run(resume_every_pause).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(
        faults(&events),
        [fault("robot", "Disconnected", "reconnect")]
    );
    assert_eq!(pauses(&events), [ROBOT_RECONNECTED]);
    // power was switched on by the two preparations only, the reconnect moved nothing
    let calls = b.cell.calls();
    let reconnect = calls
        .iter()
        .position(|c| *c == Call::RobotReconnect)
        .expect("reconnected");
    let prepared = nth_call(&calls, 2, |c| matches!(c, Call::RobotPrepare(_)));
    assert!(prepared > reconnect);
    assert!(!calls[reconnect..prepared]
        .iter()
        .any(|c| matches!(c, Call::MoveJ { .. })));
    let power_ons = crate::sim::lock_world(&b.cell.world()).power_on_requests();
    assert_eq!(power_ons, 2);
    b.assert_complete();
}

#[tokio::test]
async fn an_emergency_stop_pauses_and_only_a_released_stop_lets_the_run_go_on() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.ctx.on_fault = FaultPolicy::Pause;
    let q6 = b.pose_q(6);
    b.cell.on_target(Op::MoveJ, &q6, 1, Fault::EStop);
    let mut paused = 0;
    let (outcome, events) = b
        .run(move |e, c, cell| {
            if let CampaignEvent::State {
                state: CampaignState::Paused { .. },
            } = e
            {
                paused += 1;
                // the first resume finds the E-stop still latched; then it is released
                if paused == 2 {
                    cell.release_estop();
                }
                c.apply(&CampaignCommand::Resume);
            }
        })
        .await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let f = faults(&events);
    assert_eq!(f[0], fault("robot", "EmergencyStop", "pause"));
    assert_eq!(f[1], fault("robot", "EmergencyStop", "pause"), "{f:?}");
    let p = pauses(&events);
    assert_eq!(p.len(), 2, "{p:?}");
    assert!(p[1].contains("robot could not be prepared"), "{p:?}");
    let calls = b.cell.calls();
    let estop = calls
        .iter()
        .position(|c| matches!(c, Call::MoveJ { q, .. } if *q == q6))
        .expect("the move");
    assert_eq!(
        calls[estop + 1],
        Call::RobotStop,
        "the robot is told to stop"
    );
    assert_eq!(b.cell.count(Op::RobotPrepare), 3);
    b.assert_complete();
}

#[tokio::test]
async fn joints_settled_off_target_repeat_the_move_then_fail_without_a_commit() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let q6 = b.pose_q(6);
    let off = Fault::SettleOff {
        joint: 2,
        rad: 0.2_f64.to_radians(),
    };
    b.cell.on_target(Op::WaitSettled, &q6, 3, off);
    let (outcome, events) = b.run(nobody).await;
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(reason.contains("joint 3 settled 0.2000 deg"), "{reason}");
    assert!(reason.contains("after 3 attempts"), "{reason}");
    assert_eq!(
        faults(&events),
        vec![fault("robot", "Device", "repeat move"); 3]
    );
    assert_eq!(b.moves_to(6), 3);
    assert_eq!(b.done().len(), 5, "no pose committed off target");
}

/// The stage is not sent back to P1 after P2: each pose starts where the last one ended, so
/// a run moves the stage once per pose (the frame reference's P1 aside), back and forth, and
/// every stored P1 is still the reading at P1.
#[tokio::test]
async fn each_pose_moves_the_stage_once_starting_where_the_last_pose_ended() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let (outcome, _) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let (s1, travel) = (b.ctx.cfg.stage.p1_mm, b.ctx.cfg.stage.travel_mm);
    let moves: Vec<f64> = b
        .cell
        .calls()
        .iter()
        .filter_map(|c| match c {
            Call::StageMove(mm) => Some(*mm),
            _ => None,
        })
        .collect();
    let expected: Vec<f64> = (0..=POSES)
        .map(|k| if k % 2 == 0 { s1 } else { s1 + travel })
        .collect();
    assert_eq!(
        moves, expected,
        "frame reference at P1, then one move per pose"
    );
    let id = b.ctx.campaign_id;
    let poses = b.with_store(|s| s.measured_poses(id)).expect("poses");
    assert_eq!(poses.len(), POSES);
    for (_, m) in poses {
        let p2 = m.p2.expect("P2");
        assert!((m.p1.stage_mm - s1).abs() < 1e-9, "pose {}", m.index);
        assert!((p2.stage_mm - s1 - travel).abs() < 1e-9, "pose {}", m.index);
    }
}

#[tokio::test]
async fn a_stage_move_that_fails_once_pauses_keeps_p1_discarded_and_measures_the_pose_again() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.ctx.on_fault = FaultPolicy::Pause;
    // stage move 1 is the frame reference's P1; pose k moves the stage once, at move k + 1
    // (odd k: read at P1, then to P2; even k: read at P2, then to P1)
    b.cell
        .on(Op::StageMove, 4, 1, Fault::Fail(FaultKind::Device));
    let (outcome, events) = b.run(resume_every_pause).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(faults(&events), [fault("stage", "Device", "pause")]);
    assert_eq!(pauses(&events).len(), 1);
    assert_eq!(
        stops(&events),
        [("fault".into(), "stopped".into(), "stopped".into())]
    );
    assert_eq!(b.discarded(), 1, "pose 3's P1 is kept as discarded");
    assert_eq!(b.moves_to(3), 2);
    b.assert_complete();
}

#[tokio::test]
async fn a_stage_slip_fails_the_travel_check_and_the_pose_is_measured_again() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    // pose 3's move to P2 (stage move 4) slips 0.5 mm (the stage reads back its target)
    b.cell.on(Op::StageMove, 4, 1, Fault::Slip(0.5));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(faults(&events), [fault("stage", "Device", "measure again")]);
    let message = events.iter().find_map(|e| match e {
        CampaignEvent::Fault { message, .. } => Some(message.clone()),
        _ => None,
    });
    assert!(message.expect("fault").contains("|P2 − P1|"));
    assert_eq!(
        b.discarded(),
        2,
        "both points of the bad pair kept as discarded"
    );
    assert_eq!(b.moves_to(3), 2);
    b.assert_complete();
    let travel = b.ctx.cfg.stage.travel_mm;
    let id = b.ctx.campaign_id;
    for (_, m) in b.with_store(|s| s.measured_poses(id)).expect("poses") {
        let p2 = m.p2.expect("P2");
        let d = Vector3::new(
            p2.x_mm - m.p1.x_mm,
            p2.y_mm - m.p1.y_mm,
            p2.z_mm - m.p1.z_mm,
        );
        assert!(
            (d.norm() - travel).abs() < 0.1,
            "pose {}: {}",
            m.index,
            d.norm()
        );
    }
}

#[tokio::test]
async fn a_tracker_frame_jump_after_pose_7_fails_the_next_drift_check() {
    let cfg = config(
        POSES,
        IDENT,
        false,
        &[("drift_every = 50", "drift_every = 5")],
    );
    let mut b = Bench::new(cfg, false);
    let q8 = b.pose_q(8);
    let jump = Fault::FrameJump(Vector3::new(0.5, 0.0, 0.0));
    b.cell.on_target(Op::MoveJ, &q8, 1, jump);
    let (outcome, events) = b.run(nobody).await;
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    // the drift itself (0.5 mm, within the noise) is checked below
    assert!(
        reason.starts_with("drift 0.") && reason.contains("exceeds 0.1 mm"),
        "{reason}"
    );
    let drifts: Vec<f64> = events
        .iter()
        .filter_map(|e| match e {
            CampaignEvent::Drift { drift_mm, .. } => Some(*drift_mm),
            _ => None,
        })
        .collect();
    assert_eq!(
        drifts.len(),
        3,
        "reference, after pose 5, after pose 10: {drifts:?}"
    );
    // after pose 5: joint jitter and tracker noise only, below drift_max_mm (0.1 mm)
    assert!(
        drifts[1] < 0.1 && (drifts[2] - 0.5).abs() < 0.05,
        "{drifts:?}"
    );
    assert_eq!(b.done().len(), 10);
    assert_eq!(b.moves_to(11), 0, "nothing measured after the failed check");
}

#[tokio::test]
async fn abort_mid_move_stops_robot_and_stage_and_a_resume_measures_only_the_rest() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let q4 = b.pose_q(4);
    let control = b.ctx.control.clone();
    let abort = Arc::new(move || control.apply(&CampaignCommand::Abort));
    b.cell
        .on_target(Op::WaitSettled, &q4, 1, Fault::ThenHang(abort));
    let (outcome, events) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    assert_eq!(b.stored_state(), "aborted");
    assert_eq!(
        stops(&events),
        [("abort".into(), "stopped".into(), "stopped".into())]
    );
    let calls = b.cell.calls();
    let tail = &calls[nth_call(&calls, b.moves().len(), |c| matches!(c, Call::MoveJ { .. }))..];
    assert_eq!(
        tail[1..],
        [Call::WaitSettled, Call::RobotStop, Call::StageStop]
    );
    assert_eq!(b.done().len(), 3);

    // a second session on the same store resumes at pose 4
    let Bench { ctx, _dir: dir, .. } = b;
    let mut r = Bench::on_store(ctx.cfg, false, ctx.store, Some(ctx.campaign_id), dir);
    let (outcome, events) = r.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert!(events.iter().any(|e| matches!(
        e,
        CampaignEvent::Note { text } if text == &format!("resuming: 3 of {POSES} poses already measured")
    )));
    for k in 1..=3 {
        assert_eq!(r.moves_to(k), 0, "pose {k} measured again");
    }
    r.assert_complete();
}

#[tokio::test]
async fn disarm_stops_everything_and_pauses_whatever_the_policy_until_armed_and_resumed() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    assert_eq!(b.ctx.on_fault, FaultPolicy::Fail);
    // measure 5 is pose 2's P2: the operator disarms while it is under way
    let control = b.ctx.control.clone();
    let disarm = Arc::new(move || control.apply(&CampaignCommand::Disarm));
    b.cell.on(Op::Measure, 5, 1, Fault::ThenHang(disarm));
    let mut asked = 0;
    let (outcome, events) = b
        .run(move |e, c, _| {
            if let CampaignEvent::State {
                state: CampaignState::Paused { .. },
            } = e
            {
                asked += 1;
                // a resume while disarmed is refused; armed, it goes on
                if asked == 2 {
                    c.apply(&CampaignCommand::Arm);
                }
                c.apply(&CampaignCommand::Resume);
            }
        })
        .await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(pauses(&events), [DISARMED, "not armed: arm, then resume"]);
    assert_eq!(
        stops(&events),
        [("disarm".into(), "stopped".into(), "stopped".into())]
    );
    assert_eq!(b.discarded(), 1, "pose 2's P1 kept as discarded");
    let calls = b.cell.calls();
    let disarmed = nth_call(&calls, 5, |c| matches!(c, Call::Measure(_)));
    let prepared = nth_call(&calls, 2, |c| matches!(c, Call::RobotPrepare(_)));
    assert!(
        !calls[disarmed..prepared]
            .iter()
            .any(|c| matches!(c, Call::MoveJ { .. } | Call::StageMove(_))),
        "something moved while disarmed"
    );
    b.assert_complete();
}

#[tokio::test]
async fn nothing_is_prepared_or_moved_unless_armed_and_a_start_while_disarmed_is_forgotten() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let mut rx = b.ctx.control.events.subscribe();
    let control = b.ctx.control.clone();
    let operator = tokio::spawn(async move {
        let mut seen = Vec::new();
        while let Ok(j) = rx.recv().await {
            if let CampaignEvent::State { state } = j.event {
                seen.push(state.name());
                match state {
                    CampaignState::Idle => {
                        // start while disarmed: forgotten once the engine saw it
                        control.apply(&CampaignCommand::Start);
                        let forgotten = async {
                            while *control.start.borrow() {
                                tokio::time::sleep(Duration::from_millis(1)).await;
                            }
                        };
                        if tokio::time::timeout(Duration::from_secs(2), forgotten)
                            .await
                            .is_err()
                        {
                            return seen;
                        }
                        control.apply(&CampaignCommand::Arm);
                    }
                    CampaignState::Armed => control.apply(&CampaignCommand::Abort),
                    _ => {}
                }
            }
            if seen.last() == Some(&"aborted") {
                return seen;
            }
        }
        seen
    });
    let run = run_campaign(&b.ctx, &mut b.devices);
    let outcome = tokio::time::timeout(Duration::from_secs(10), run)
        .await
        .expect("the run ends")
        .expect("runs");
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    let seen = tokio::time::timeout(Duration::from_secs(10), operator)
        .await
        .expect("the operator saw the run end")
        .expect("operator");
    assert_eq!(seen, ["idle", "armed", "aborted"]);
    assert_eq!(b.cell.calls(), [Call::RobotStop, Call::StageStop]);
    assert_eq!(
        crate::sim::lock_world(&b.cell.world()).power_on_requests(),
        0
    );
}

#[tokio::test]
async fn a_target_outside_the_limits_fails_the_run_unsent_whatever_the_policy() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    b.ctx.on_fault = FaultPolicy::Pause;
    b.ctx.plan.poses[3].q_rad[0] = 4.0;
    let bad = b.pose_q(4);
    let (outcome, events) = b.run(resume_every_pause).await;
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(
        reason.contains("fails the joint-limit/workspace check: not sent"),
        "{reason}"
    );
    assert!(pauses(&events).is_empty());
    assert!(!b.moves().contains(&bad));
    assert_eq!(b.done().len(), 3);
}

#[tokio::test]
async fn after_a_manual_stage_move_the_robot_moves_only_once_the_cell_is_confirmed_clear() {
    let mut b = Bench::new(config(10, 8, false, &[]), true);
    let (outcome, _) = b.run(nobody).await;
    assert!(
        matches!(outcome, Outcome::Done(_) | Outcome::Failed(_)),
        "{outcome:?}"
    );
    let calls = b.cell.calls();
    let mut hand_at_stage = false;
    let mut confirmed = 0;
    for c in &calls {
        match c {
            Call::StageMove(_) => hand_at_stage = true,
            Call::ConfirmClear => {
                hand_at_stage = false;
                confirmed += 1;
            }
            Call::MoveJ { .. } => {
                assert!(!hand_at_stage, "the robot moved with a hand at the stage")
            }
            _ => {}
        }
    }
    // the frame reference and every pose but the last are followed by a move
    assert_eq!(confirmed, 10 + 1);
    assert_eq!(b.done().len(), 10);
}

#[tokio::test]
async fn an_operator_pause_waits_for_the_pose_to_be_committed_and_resume_goes_on() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    let control = b.ctx.control.clone();
    let pause = Arc::new(move || control.apply(&CampaignCommand::Pause));
    // measure 7 is pose 3's P2
    b.cell.on(Op::Measure, 7, 1, Fault::Then(pause));
    let (outcome, events) = b.run(resume_every_pause).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    assert_eq!(pauses(&events), ["paused by the operator"]);
    let at = |pred: &dyn Fn(&CampaignEvent) -> bool| events.iter().position(pred).expect("event");
    let paused = at(&|e| {
        matches!(
            e,
            CampaignEvent::State {
                state: CampaignState::Paused { .. }
            }
        )
    });
    let third = at(&|e| matches!(e, CampaignEvent::Measured { done: 3, .. }));
    let fourth = at(&|e| matches!(e, CampaignEvent::Measured { done: 4, .. }));
    assert!(third < paused && paused < fourth);
    assert_eq!(
        b.cell.count(Op::RobotPrepare),
        1,
        "an operator pause prepares nothing again"
    );
    assert!(
        stops(&events).is_empty(),
        "an operator pause between poses stops nothing"
    );
    b.assert_complete();
}

#[tokio::test]
async fn a_failed_identification_ends_failed_with_the_reason_as_the_last_event() {
    let mut b = Bench::new(config(POSES, IDENT, false, &[]), false);
    // the 1D stage gives no full orientation: the stored data cannot serve this model
    b.ctx.cfg.campaign.model = "full".parse().expect("a model name");
    let (outcome, events) = b.run(nobody).await;
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(reason.contains("identification"), "{reason}");
    assert!(
        matches!(
            events.last(),
            Some(CampaignEvent::State {
                state: CampaignState::Failed { .. }
            })
        ),
        "{:?}",
        events.last()
    );
    assert_eq!(b.stored_state(), "failed");
    b.assert_complete();
}

fn point(xyz: [f64; 3], stage_mm: f64, std_total_mm: f64) -> PointRecord {
    PointRecord {
        stage_mm,
        std_total_mm,
        ..PointRecord::position_only(xyz[0], xyz[1], xyz[2], 0)
    }
}

#[test]
fn settle_error_names_the_joint_farthest_off_and_refuses_nan_and_a_wrong_count() {
    let tol = 0.05_f64.to_radians();
    let t = [0.1, 0.2, 0.3];
    assert_eq!(settle_error(&t, &t, tol), None);
    assert_eq!(settle_error(&t, &[0.1, 0.2, 0.3 + 0.9 * tol], tol), None);
    let off = [0.1 + 2.0 * tol, 0.2, 0.3 - 3.0 * tol];
    let why = settle_error(&t, &off, tol).expect("off");
    assert!(why.starts_with("joint 3 settled 0.1500 deg"), "{why}");
    let why = settle_error(&t, &[0.1, f64::NAN, 0.3], tol).expect("nan");
    assert!(why.starts_with("joint 2"), "{why}");
    let why = settle_error(&t, &[0.1, 0.2], tol).expect("count");
    assert!(why.contains("2 joints for a 3-joint target"), "{why}");
}

#[test]
fn the_travel_check_allows_the_tolerance_plus_three_sigma_and_refuses_nan() {
    let p1 = point([0.0; 3], 0.0, 0.01);
    // 10 mm of stage travel; allowed = 0.02 + 3·0.01·√2 ≈ 0.0624 mm
    assert!(check_travel(&p1, &point([0.0, 10.06, 0.0], 10.0, 0.01), 0.02, 0.05).is_ok());
    let why =
        check_travel(&p1, &point([0.0, 10.07, 0.0], 10.0, 0.01), 0.02, 0.05).expect_err("too far");
    assert!(why.contains("off by 0.0700 mm"), "{why}");
    // a point without σ counts at the quality gate
    assert!(check_travel(&p1, &point([0.0, 10.1, 0.0], 10.0, f64::NAN), 0.02, 0.05).is_ok());
    assert!(check_travel(&p1, &point([f64::NAN, 10.0, 0.0], 10.0, 0.01), 0.02, 0.05).is_err());
}

/// With `verify_readings = "p1"` a verification pose is read at P1 only: no P2 is stored and
/// the stage does not move for it (the identification poses keep both readings, one stage
/// move each), and the plan's estimate counts those readings.
#[tokio::test]
async fn with_verify_readings_p1_a_verification_pose_is_read_at_p1_only_without_a_stage_move() {
    let p1_only = (
        "drift_every = 50",
        "drift_every = 50\nverify_readings = \"p1\"",
    );
    let mut b = Bench::new(config(POSES, IDENT, false, &[p1_only]), false);
    let (outcome, _) = b.run(nobody).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let s1 = b.ctx.cfg.stage.p1_mm;
    let stage_moves = (b.cell.calls().iter())
        .filter(|c| matches!(c, Call::StageMove(_)))
        .count();
    // the frame reference's P1, then one move per identification pose and one back to P1
    // for a verification pose only where an identification pose left the stage at P2
    let (mut at_p1, mut expected) = (true, 1);
    for p in &b.ctx.plan.poses {
        if p.set == PoseSet::Ident || !at_p1 {
            expected += 1;
            at_p1 = !at_p1 || p.set == PoseSet::Verify;
        }
    }
    assert!(expected < 1 + POSES, "nothing saved: {expected} moves");
    assert_eq!(stage_moves, expected);
    let id = b.ctx.campaign_id;
    let poses = b.with_store(|s| s.measured_poses(id)).expect("poses");
    assert_eq!(poses.len(), POSES);
    let set_of = |i: usize| b.ctx.plan.poses.iter().find(|p| p.index == i).unwrap().set;
    for (_, m) in &poses {
        match set_of(m.index) {
            PoseSet::Ident => assert!(m.p2.is_some(), "ident pose {}", m.index),
            PoseSet::Verify => {
                assert!(m.p2.is_none(), "verify pose {}", m.index);
                assert!((m.p1.stage_mm - s1).abs() < 1e-9, "pose {}", m.index);
            }
        }
    }
    let walk = crate::plan::timing::campaign_walk(
        &b.ctx.plan,
        0,
        Vec::new(),
        None,
        (s1, b.ctx.cfg.stage.travel_mm, b.ctx.cfg.stage.tolerance_mm),
        b.ctx.cfg.axis_readings(),
    );
    assert_eq!(walk.readings, 2 * IDENT + (POSES - IDENT));
}
