//! Safety and integrity of campaigns: signals stop `run` and leave the campaign `aborted`, one
//! runner per campaign, done campaigns never move again, resumes refuse a changed cell
//! (configuration, or a tracker moved between sessions), bad points are measured again, and a
//! robot reconnect never powers the arm on behind the operator's back.

use std::path::Path;
use std::process::{Child, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use cellcal::campaign::session::{open_session, Resume};
use cellcal::campaign::{run_campaign, CampaignCommand, CampaignEvent, CampaignState, Outcome};
use cellcal::cell::ScriptedPrompter;
use cellcal::config::parse_cell_config;
use cellcal::store::{PointKind, Store};

use super::campaign::{
    check_complete, config_text, journal_states, run_steered, sim_session, write_config,
};

/// config/cell.sim.toml (accelerated) with `poses` poses, `ident` of them identification poses,
/// and no setup steps (the subject of these tests is the measurement loop).
fn no_setup_config(poses: usize, ident: usize) -> String {
    config_text("", "", "")
        .replace("poses = 300", &format!("poses = {poses}"))
        .replace("ident = 100", &format!("ident = {ident}"))
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false")
}

/// The messages of campaign `id`'s journal, oldest first.
fn journal_messages(store: &Path, id: i64) -> Vec<String> {
    Store::open(store)
        .expect("store")
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .map(|e| serde_json::to_string(&e.event).expect("JSON"))
        .collect()
}

use super::common::cellcal_process as cellcal;

/// A 120-pose campaign at the simulator's default (not accelerated) speed: ~80 ms a pose.
fn slow_config(dir: &Path) -> std::path::PathBuf {
    let text = config_text("", "", "")
        .replace(
            "move_speed_deg_s = 200000.0\nstage_speed_mm_s = 100000.0\n",
            "",
        )
        .replace("poses = 300", "poses = 120")
        .replace("ident = 100", "ident = 40");
    write_config(dir, &text)
}

fn spawn_run(cfg: &Path, store: &Path, extra: &[&str]) -> Child {
    cellcal()
        .args(["run", "--quiet", "--on-fault", "fail", "--config"])
        .arg(cfg)
        .arg("--store")
        .arg(store)
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn cellcal run")
}

fn state_of(store: &Path, id: i64) -> String {
    Store::open(store)
        .and_then(|s| s.campaign(id))
        .map(|r| r.state.name().to_owned())
        .unwrap_or_default()
}

/// Wait until campaign `id` has at least `poses` poses measured.
fn wait_poses(store: &Path, id: i64, poses: usize) {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let done = Store::open(store)
            .and_then(|s| s.done_poses(id))
            .map(|d| d.len())
            .unwrap_or(0);
        if done >= poses {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "{poses} poses not measured in time"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn signal(child: &Child, sig: nix::sys::signal::Signal) {
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), sig).expect("signal");
}

fn finish(child: Child) -> (Option<i32>, String) {
    let out = child.wait_with_output().expect("wait");
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn sigterm_and_sighup_abort_run_and_leave_the_campaign_resumable() {
    use nix::sys::signal::Signal;
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = slow_config(dir.path());
    let store = dir.path().join("c.db");
    let mut done_before = 0;
    for (round, (sig, code)) in [(Signal::SIGTERM, 143), (Signal::SIGHUP, 129)]
        .into_iter()
        .enumerate()
    {
        let resume = ["--arm", "--campaign", "1"];
        let child = spawn_run(
            &cfg,
            &store,
            if round == 0 {
                &resume[..1]
            } else {
                &resume[..]
            },
        );
        wait_poses(&store, 1, done_before + 3);
        assert_eq!(state_of(&store, 1), "running");
        signal(&child, sig);
        let (status, err) = finish(child);
        assert_eq!(status, Some(code), "{sig:?}: {err}");
        assert!(
            err.contains(&format!("aborted by {}", sig.as_str())),
            "{err}"
        );
        assert_eq!(
            state_of(&store, 1),
            "aborted",
            "{sig:?} leaves no `running` behind"
        );
        let s = Store::open(&store).expect("store");
        assert_eq!(
            s.campaign_holder(1).expect("holder"),
            None,
            "the lock is released"
        );
        let done = s.done_poses(1).expect("done").len();
        assert!(done > done_before, "{sig:?}: resumed and measured on");
        done_before = done;
    }
}

#[test]
fn two_runners_on_one_campaign_the_second_is_refused_naming_the_first() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = slow_config(dir.path());
    let store = dir.path().join("c.db");
    // plan and store (nothing moves without --arm)
    let (code, err) = finish(spawn_run(&cfg, &store, &[]));
    assert_eq!(code, Some(0), "{err}");
    let first = spawn_run(&cfg, &store, &["--arm", "--campaign", "1"]);
    wait_poses(&store, 1, 2);
    let (code, err) = finish(spawn_run(&cfg, &store, &["--arm", "--campaign", "1"]));
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains(&format!("pid {}", first.id())) && err.contains("commanded by"),
        "{err}"
    );
    signal(&first, nix::sys::signal::Signal::SIGTERM);
    let (code, err) = finish(first);
    assert_eq!(code, Some(143), "{err}");
    // a lock left by a process that died without letting go is taken over and journalled
    let dead = cellcal::store::LockHolder {
        pid: u32::MAX - 7,
        ..cellcal::campaign::lock::this_process()
    };
    Store::open(&store)
        .expect("store")
        .lock_campaign(1, &dead, |_| false)
        .expect("a stale lock");
    let (code, err) = finish(spawn_run(&cfg, &store, &["--campaign", "1"]));
    assert_eq!(code, Some(0), "{err}");
    let notes = journal_messages(&store, 1);
    assert!(
        notes
            .iter()
            .any(|n| n.contains("took over the campaign from pid 4294967288")),
        "{notes:?}"
    );
}

#[test]
fn a_done_campaign_moves_nothing_and_prints_its_stored_result() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20");
    let cfg = write_config(dir.path(), &text);
    let store = dir.path().join("c.db");
    let (code, err) = finish(spawn_run(&cfg, &store, &["--arm"]));
    // done: exit 0, or 3 when the result's verdict is poor (the same for the stored result)
    let stored = Store::open(&store).expect("store").latest_result(1);
    let poor = stored
        .expect("result")
        .expect("stored")
        .contains(r#""quality": "poor""#);
    let done_exit = Some(if poor { 3 } else { 0 });
    assert_eq!(code, done_exit, "{err}");
    let snapshot = |s: &Store| {
        (
            s.events::<CampaignEvent>(1).expect("events").len(),
            s.done_poses(1).expect("done"),
            s.latest_result(1).expect("result"),
        )
    };
    let before = snapshot(&Store::open(&store).expect("store"));
    let json = dir.path().join("again.json");
    let out = cellcal()
        .args(["run", "--quiet", "--arm", "--campaign", "1", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store)
        .arg("--json")
        .arg(&json)
        .output()
        .expect("run");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), done_exit, "{err}");
    assert!(err.contains("campaign 1 is done: nothing moves"), "{err}");
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("verify"),
        "the stored summary"
    );
    assert_eq!(
        snapshot(&Store::open(&store).expect("store")),
        before,
        "nothing ran"
    );
    // the stored typed result's contract, as `identify --json` writes it
    let stored = cellcal::campaign::stored::stored_result(&Store::open(&store).expect("store"), 1)
        .expect("read")
        .expect("stored result");
    assert_eq!(
        std::fs::read_to_string(&json).expect("json"),
        stored.identify_json().expect("contract")
    );
}

#[test]
fn resuming_with_a_changed_configuration_is_refused_naming_the_keys() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = config_text("", "", "");
    let cfg = write_config(dir.path(), &text);
    let store = dir.path().join("c.db");
    assert_eq!(finish(spawn_run(&cfg, &store, &[])).0, Some(0));
    // the robot file and two keys change; the simulated world (`[sim]`) is not the cell's config
    std::fs::write(
        &cfg,
        text.replace("max_attempts = 5", "max_attempts = 6")
            .replace("drift_max_mm = 0.1", "drift_max_mm = 0.5")
            .replace("seed = 4802", "seed = 4803"),
    )
    .expect("edit");
    let (code, err) = finish(spawn_run(&cfg, &store, &["--campaign", "1"]));
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("campaign.drift_max_mm") && err.contains("tracker.max_attempts"),
        "{err}"
    );
    assert!(err.contains("--accept-changed-config"), "{err}");
    let (code, err) = finish(spawn_run(
        &cfg,
        &store,
        &["--campaign", "1", "--accept-changed-config"],
    ));
    assert_eq!(code, Some(0), "{err}");
    let journal = journal_messages(&store, 1);
    assert!(
        journal
            .iter()
            .any(|m| m.contains("changed configuration (accepted)")),
        "{journal:?}"
    );
}

/// config/cell.sim.toml (accelerated, 40 poses) with the robot moved by `shift_mm` in the
/// tracker frame and turned by `turn_deg` about the tracker's vertical.
fn frame_config(shift_mm: [f64; 3], turn_deg: f64) -> String {
    let [x, y, z] = shift_mm;
    config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20")
        .replace(
            "base_translation_mm = [2434.177, -693.336, -209.929]",
            &format!(
                "base_translation_mm = [{}, {}, {}]",
                2434.177 + x,
                -693.336 + y,
                -209.929 + z
            ),
        )
        .replace(
            "base_rotation_vector_deg = [0.3, -0.2, 155.0]",
            &format!(
                "base_rotation_vector_deg = [0.3, -0.2, {}]",
                155.0 + turn_deg
            ),
        )
}

/// Session 1 of a two-session campaign in `dir/c.db`: measure 10 poses of `text`, then abort;
/// returns the campaign id and the configuration path.
async fn measure_ten_then_abort(dir: &Path, text: &str) -> (i64, std::path::PathBuf) {
    let store = dir.join("c.db");
    let cfg_path = write_config(dir, text);
    let cfg = parse_cell_config(text, &cfg_path).expect("config");
    let s1 = open_session(cfg, &store, None, Arc::new(ScriptedPrompter::exact()))
        .await
        .expect("session");
    let (ctx, mut devices) = (s1.ctx, s1.devices);
    let mut rx = ctx.control.events.subscribe();
    let control = ctx.control.clone();
    tokio::spawn(async move {
        while let Ok(e) = rx.recv().await {
            if matches!(e.event, CampaignEvent::Measured { done: 10, .. }) {
                control.apply(&CampaignCommand::Abort);
            }
        }
    });
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("runs");
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    let id = ctx.campaign_id;
    drop((ctx, devices, s1.lock));
    s1.sim.expect("sim").stop().await;
    (id, cfg_path)
}

/// Abort the campaign at its first pause; the task returns the pause's reason.
fn abort_at_first_pause(
    control: &cellcal::campaign::Control,
) -> tokio::task::JoinHandle<Option<String>> {
    let mut rx = control.events.subscribe();
    let control = control.clone();
    tokio::spawn(async move {
        while let Ok(e) = rx.recv().await {
            if let CampaignEvent::State {
                state: CampaignState::Paused { reason },
            } = e.event
            {
                control.apply(&CampaignCommand::Abort);
                return Some(reason);
            }
        }
        None
    })
}

/// Session 2: resume campaign `id` of `store` with the configuration `text` (at `cfg_path`).
async fn resume_session(
    text: &str,
    cfg_path: &Path,
    store: &Path,
    id: i64,
) -> cellcal::campaign::session::Session {
    let cfg = parse_cell_config(text, cfg_path).expect("config");
    open_session(
        cfg,
        store,
        Some(Resume::strict(id)),
        Arc::new(ScriptedPrompter::exact()),
    )
    .await
    .expect("resume")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tracker_moved_1_mm_between_sessions_pauses_the_resumed_campaign() {
    let dir = tempfile::tempdir().expect("tempdir");
    let base = |x: f64| frame_config([x, 0.0, 0.0], 0.0);
    let store = dir.path().join("c.db");
    // session 1: measure 10 poses, then abort
    let (id, cfg_path) = measure_ten_then_abort(dir.path(), &base(0.0)).await;

    // session 2: the tracker stands 1 mm elsewhere
    let s2 = resume_session(&base(1.0), &cfg_path, &store, id).await;
    let (ctx, mut devices) = (s2.ctx, s2.devices);
    let watcher = abort_at_first_pause(&ctx.control);
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("runs");
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    let reason = watcher.await.expect("watcher").expect("the resume paused");
    let moved: f64 = reason
        .split("moved by ")
        .nth(1)
        .and_then(|r| r.split(" mm").next())
        .and_then(|v| v.parse().ok())
        .expect("the distance in the reason");
    assert!((moved - 1.0).abs() < 0.05, "{reason}");
    assert!(reason.contains("since pose 10"), "{reason}");
    let s = Store::open(&store).expect("store");
    assert_eq!(
        s.done_poses(id).expect("done").len(),
        10,
        "nothing measured in the moved frame"
    );
    assert_eq!(s.frame_refs(id).expect("refs").len(), 1);
    s2.sim.expect("sim").stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stage_slip_is_caught_by_the_travel_check_and_the_pose_measured_again() {
    let text = no_setup_config(40, 20).replace("slip = 0 ", "slip = 2 ");
    let (outcome, store, id) = run_steered(&text, |_, _, _| {}).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    check_complete(&store, id, 40);
    let s = Store::open(&store).expect("store");
    let faults: Vec<String> = s
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .map(|e| {
            (
                e.event.kind().to_owned(),
                serde_json::to_string(&e.event).expect("JSON"),
            )
        })
        .filter(|(kind, message)| kind == "fault" && message.contains("measure again"))
        .map(|(_, message)| message)
        .collect();
    assert_eq!(faults.len(), 2, "{faults:?}");
    assert!(faults[0].contains("|P2 − P1|"), "{faults:?}");
    let discarded = s.point_count(id, PointKind::Discarded).expect("points");
    assert_eq!(
        discarded, 4,
        "both points of each bad pair kept as discarded"
    );
    // every committed pose agrees with the stage travel
    for (_, m) in s.measured_poses(id).expect("poses") {
        let p2 = m.p2.expect("P2");
        let d = ((p2.x_mm - m.p1.x_mm).powi(2)
            + (p2.y_mm - m.p1.y_mm).powi(2)
            + (p2.z_mm - m.p1.z_mm).powi(2))
        .sqrt();
        assert!((d - 10.0).abs() < 0.1, "pose {}: |P2 − P1| = {d}", m.index);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn joints_settled_off_target_repeat_the_move_then_pause() {
    let text = no_setup_config(40, 20);
    let mut offset_set = false;
    let (outcome, store, id) = run_steered(&text, move |e, cell, control| {
        match e {
            // after the 5th pose the controller reports joint 3 0.2° off its target
            CampaignEvent::Measured { done: 5, .. } if !offset_set => {
                offset_set = true;
                cell.robot_faults.lock().expect("faults").joint_offset_deg[2] = 0.2;
            }
            CampaignEvent::State {
                state: CampaignState::Paused { reason },
            } => {
                assert!(reason.contains("joint 3 settled 0.2000 deg"), "{reason}");
                control.apply(&CampaignCommand::Abort);
            }
            _ => {}
        }
    })
    .await;
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    let s = Store::open(&store).expect("store");
    assert_eq!(
        s.done_poses(id).expect("done").len(),
        5,
        "no pose committed off target"
    );
    let repeats = s
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .filter(|e| {
            serde_json::to_string(&e.event)
                .expect("JSON")
                .contains("repeat move")
        })
        .count();
    assert_eq!(repeats, 3, "max_attempts moves, each refused");
    assert!(journal_states(&store, id)
        .iter()
        .any(|s| s["state"] == "paused"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_robot_reconnect_pauses_and_never_powers_the_arm_on() {
    let text = no_setup_config(40, 20);
    let mut power_ons = None;
    let (outcome, store, id) = run_steered(&text, move |e, cell, control| match e {
        CampaignEvent::Measured { done: 3, .. } if power_ons.is_none() => {
            power_ons = Some(cellcal::sim::lock_world(&cell.world).power_on_requests());
            // the controller accepts the next move, then the link drops
            cell.robot_faults
                .lock()
                .expect("faults")
                .disconnect_during_move = 1;
        }
        CampaignEvent::State {
            state: CampaignState::Paused { reason },
        } => {
            assert!(reason.contains("robot controller reconnected"), "{reason}");
            assert_eq!(
                Some(cellcal::sim::lock_world(&cell.world).power_on_requests()),
                power_ons,
                "the reconnect switched the arm on with nobody asked"
            );
            control.apply(&CampaignCommand::Abort);
        }
        _ => {}
    })
    .await;
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    assert!(journal_states(&store, id)
        .iter()
        .any(|s| s["state"] == "paused"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failed_identification_ends_in_failed_with_the_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = no_setup_config(30, 20);
    let store = dir.path().join("c.db");
    let session = sim_session(dir.path(), &text).await;
    let (mut ctx, mut devices) = (session.ctx, session.devices);
    // the stored data can then not serve the model: the 1D stage gives no full orientation
    ctx.cfg.campaign.model = cellcal::identify::ObsModel::Full;
    let mut rx = ctx.control.events.subscribe();
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("runs");
    let Outcome::Failed(reason) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(reason.contains("identification"), "{reason}");
    // the last live event is the terminal state (a stream ends on it)
    let mut last = None;
    while let Ok(j) = rx.try_recv() {
        last = Some(j.event);
    }
    assert!(
        matches!(
            last,
            Some(CampaignEvent::State {
                state: CampaignState::Failed { .. }
            })
        ),
        "{last:?}"
    );
    assert_eq!(
        journal_states(&store, ctx.campaign_id)
            .last()
            .expect("states")["state"],
        "failed"
    );
    assert_eq!(
        Store::open(&store)
            .expect("store")
            .campaign(ctx.campaign_id)
            .expect("row")
            .state,
        "failed",
        "no state left claiming `identifying`"
    );
    session.sim.expect("sim").stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abort_mid_move_stops_the_simulated_arm_within_200_ms() {
    // slow joints (10 deg/s): the first move takes seconds
    let text = config_text("", "", "")
        .replace("move_speed_deg_s = 200000.0\n", "move_speed_deg_s = 10.0\n")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20")
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false");
    let dir = tempfile::tempdir().expect("tempdir");
    let session = sim_session(dir.path(), &text).await;
    let (ctx, mut devices) = (session.ctx, session.devices);
    let sim = session.sim.expect("sim");
    let (world, control) = (sim.world.clone(), ctx.control.clone());
    let watcher = tokio::spawn(async move {
        // wait until the arm has been moving for 300 ms, then abort and time the stop
        let deadline = Instant::now() + Duration::from_secs(30);
        while !cellcal::sim::lock_world(&world).is_moving() {
            assert!(Instant::now() < deadline, "the arm never moved");
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(
            cellcal::sim::lock_world(&world).is_moving(),
            "the move is long enough"
        );
        let aborted = Instant::now();
        control.apply(&CampaignCommand::Abort);
        while cellcal::sim::lock_world(&world).is_moving() {
            assert!(
                aborted.elapsed() < Duration::from_secs(10),
                "the arm never stopped"
            );
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        aborted.elapsed()
    });
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("runs");
    let latency = watcher.await.expect("watcher");
    eprintln!("abort → arm stopped: {latency:?}");
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    assert!(
        latency < Duration::from_millis(200),
        "abort latency {latency:?}"
    );
    sim.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_relock_that_finds_no_reflector_searches_before_measuring_again() {
    let text = no_setup_config(20, 14);
    let mut armed = false;
    let (outcome, store, id) = run_steered(&text, move |e, cell, _| {
        if matches!(e, CampaignEvent::Measured { done: 3, .. }) && !armed {
            armed = true;
            // the beam breaks; pointing at the last point does not find the reflector there
            let mut f = cell.tracker_faults.lock().expect("faults");
            f.beam_break_before_measure = 1;
            f.go_last_without_lock = 1;
        }
    })
    .await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let breaks = Store::open(&store)
        .expect("store")
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .filter(|e| {
            e.event.kind() == "fault"
                && serde_json::to_string(&e.event)
                    .expect("JSON")
                    .contains("BeamBroken")
        })
        .count();
    // one break, one relock (GoLast, not locked → FindReflector): no second failed measurement
    assert_eq!(breaks, 1, "the relock was not checked");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tracker_moved_between_sessions_is_re_registered_and_the_campaign_stays_in_one_frame() {
    let dir = tempfile::tempdir().expect("tempdir");
    let store = dir.path().join("c.db");
    let (id, cfg_path) = measure_ten_then_abort(dir.path(), &frame_config([0.0; 3], 0.0)).await;

    // session 2: the tracker stands 1.2 mm elsewhere and turned by 0.1° about z
    let moved = frame_config([1.0, -0.6, 0.3], 0.1);
    let s2 = resume_session(&moved, &cfg_path, &store, id).await;
    let (ctx, mut devices) = (s2.ctx, s2.devices);
    // as `run --reregister` does
    ctx.control.apply(&CampaignCommand::Reregister);
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("runs");
    let Outcome::Done(report) = outcome else {
        panic!("{outcome:?}: {:?}", journal_messages(&store, id));
    };
    drop((ctx, devices, s2.lock));
    s2.sim.expect("sim").stop().await;

    let s = Store::open(&store).expect("store");
    let refs = s.frame_refs(id).expect("refs");
    assert_eq!(refs.len(), 2, "a second frame segment");
    let t = refs[1].to_first.as_ref().expect("segment 1's transform");
    assert!(t.points >= 4 && t.rms_mm < 0.05 && t.max_mm < 0.1, "{t:?}");
    let turned = t.to_first.rotation_angle().to_degrees();
    assert!((turned - 0.1).abs() < 0.01, "rotation {turned}°");
    assert_eq!(refs[1].poses_done, 10);
    // identification used one frame: the result is as good as an unmoved campaign's
    let verify = report.metrics.verify.as_ref().expect("verify set");
    let after = verify.after.position_mean_mm;
    assert!(after < 0.08, "verify mean after {after} mm (frames mixed?)");
    let journal = journal_messages(&store, id);
    assert!(
        journal
            .iter()
            .any(|m| m.contains("re-registered (segment 1)")),
        "{journal:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_relock_looks_first_where_the_ball_should_be() {
    let mut armed = false;
    // setup on: the registered base predicts the ball
    let (outcome, store, id) = run_steered(&frame_config([0.0; 3], 0.0), move |e, cell, _| {
        if matches!(e, CampaignEvent::Measured { done: 3, .. }) && !armed {
            armed = true;
            // the beam breaks; the last point is the previous pose's, and the search misses
            let mut f = cell.tracker_faults.lock().expect("faults");
            f.beam_break_before_measure = 1;
            f.find_reflector_fails = 1;
        }
    })
    .await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let faults: Vec<String> = Store::open(&store)
        .expect("store")
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .filter(|e| e.event.kind() == "fault")
        .map(|e| serde_json::to_string(&e.event).expect("JSON"))
        .collect();
    // one break, relocked at the predicted position: no failed search, no second attempt
    assert_eq!(faults.len(), 1, "{faults:?}");
    assert!(faults[0].contains("BeamBroken"), "{faults:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_re_registration_refuses_poses_measured_after_an_unnoticed_move() {
    // session 1: the tracker is bumped 0.5 mm after pose 10; no drift check notices it before
    // the abort after pose 15
    let mut bumped = false;
    let (outcome, store, id) = run_steered(
        &frame_config([0.0; 3], 0.0),
        move |e, cell, control| match e {
            CampaignEvent::Measured { done: 10, .. } if !bumped => {
                bumped = true;
                cellcal::sim::lock_world(&cell.world)
                    .bump_base(nalgebra::Vector3::new(0.5, 0.0, 0.0));
            }
            CampaignEvent::Measured { done: 15, .. } => control.apply(&CampaignCommand::Abort),
            _ => {}
        },
    )
    .await;
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");

    // session 2: the tracker stays where the bump left it, and re-registration is asked for
    let dir = store.parent().expect("dir");
    let s2 = resume_session(
        &frame_config([0.5, 0.0, 0.0], 0.0),
        &dir.join("cell.toml"),
        &store,
        id,
    )
    .await;
    let (ctx, mut devices) = (s2.ctx, s2.devices);
    let watcher = abort_at_first_pause(&ctx.control);
    ctx.control.apply(&CampaignCommand::Reregister);
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("runs");
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    let reason = watcher.await.expect("watcher").expect("the resume paused");
    // poses 11-15 sit in the new frame, 1-10 in the old one: no rigid fit joins them
    assert!(reason.contains("re-registration refused"), "{reason}");
    drop((ctx, devices, s2.lock));
    s2.sim.expect("sim").stop().await;
    let s = Store::open(&store).expect("store");
    assert_eq!(
        s.frame_refs(id).expect("refs").len(),
        1,
        "no segment stored"
    );
    assert_eq!(s.done_poses(id).expect("done").len(), 15);
}
