//! The campaign end to end against the simulated cell over the real protocols: accuracy,
//! faults with nothing lost or duplicated, the armed gate, crash-resume of the real binary,
//! bad configuration.

use cellcal::store::identification_rows;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use cellcal::analysis::evaluate;
use cellcal::campaign::engine::identify_options;
use cellcal::campaign::session::open_session;
use cellcal::campaign::session::Session;
use cellcal::campaign::CampaignContext;
use cellcal::campaign::{
    run_campaign, CampaignCommand, CampaignEvent, CampaignState, Control, Outcome,
};
use cellcal::cell::{Prompter, ScriptedPrompter, StagePosition};
use cellcal::config::parse_cell_config;
use cellcal::dataset::{split, to_measured};
use cellcal::sim::lock_world;
use cellcal::sim::RunningSimCell;
use cellcal::store::Store;

/// config/cell.sim.toml with fast motion and extra `[sim]` / `[campaign]` keys.
pub(crate) fn config_text(sim_extra: &str, campaign_extra: &str, faults: &str) -> String {
    let base =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml"))
            .expect("cell.sim.toml");
    let mut s = base
        .replace(
            "realistic = false\n",
            &format!("realistic = false\nmove_speed_deg_s = 200000.0\nstage_speed_mm_s = 100000.0\n{sim_extra}\n"),
        )
        .replace("[campaign]\n", &format!("[campaign]\n{campaign_extra}\n"));
    if !faults.is_empty() {
        s = s.replace("beam_break_probability = 0.0", faults);
    }
    s
}

/// A session on the simulated cell of `text` (written to `dir`), stored in `dir/c.db`, with a
/// scripted technician.
pub(crate) async fn sim_session(dir: &Path, text: &str) -> cellcal::campaign::session::Session {
    let cfg_path = write_config(dir, text);
    let cfg = parse_cell_config(text, &cfg_path).expect("config");
    open_session(
        cfg,
        &dir.join("c.db"),
        None,
        Arc::new(ScriptedPrompter::exact()),
    )
    .await
    .expect("session")
}

pub(crate) fn write_config(dir: &Path, text: &str) -> PathBuf {
    let robots = dir.join("robots");
    std::fs::create_dir_all(&robots).expect("mkdir");
    std::fs::copy(crate::cli::robot(), robots.join("staubli_tx60.toml")).expect("copy robot");
    let p = dir.join("cell.toml");
    std::fs::write(&p, text).expect("write config");
    p
}

pub(crate) struct Finished {
    pub(crate) report_after_mm: f64,
    pub(crate) floor_mm: f64,
    pub(crate) store: PathBuf,
    pub(crate) id: i64,
    /// The stored result.
    pub(crate) report: cellcal::calibrate::IdentifyReport,
    /// The simulated world's true robot (errors, base, tool) and stage axis in the flange.
    pub(crate) truth: cellcal::model::RobotModel,
    pub(crate) true_axis: nalgebra::Vector3<f64>,
    /// The campaign's configuration and nominal robot.
    pub(crate) cfg: cellcal::config::CellConfig,
    pub(crate) nominal: cellcal::model::RobotModel,
}

/// The campaign of `text` (written to `dir`, stored in `dir/c.db`) run in process to its end
/// with `prompter`: armed and started; nobody answers an operator fault, which ends the run with
/// its reason. The engine's context, the simulated cell and the outcome.
pub(crate) async fn run_with(
    dir: &Path,
    text: &str,
    prompter: Arc<dyn Prompter>,
) -> (CampaignContext, Option<RunningSimCell>, Outcome) {
    let cfg_path = write_config(dir, text);
    let cfg = parse_cell_config(text, &cfg_path).expect("config");
    let Session {
        mut ctx,
        mut devices,
        sim,
        lock,
        ..
    } = open_session(cfg, &dir.join("c.db"), None, prompter)
        .await
        .expect("session");
    ctx.on_fault = cellcal::campaign::FaultPolicy::Fail;
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = tokio::time::timeout(Duration::from_secs(120), run_campaign(&ctx, &mut devices))
        .await
        .expect("campaign finishes in time")
        .expect("campaign runs");
    drop(lock);
    (ctx, sim, outcome)
}

pub(crate) async fn run_in_process(text: &str) -> Finished {
    run_in_process_with(text, Arc::new(ScriptedPrompter::exact())).await
}

/// [`run_in_process`] with the technician's answers from `prompter`.
pub(crate) async fn run_in_process_with(text: &str, prompter: Arc<dyn Prompter>) -> Finished {
    let dir = tempfile::tempdir().expect("tempdir").keep();
    let store = dir.join("c.db");
    let (ctx, sim, outcome) = run_with(&dir, text, prompter).await;
    let Outcome::Done(report) = outcome else {
        panic!("campaign did not finish: {outcome:?}");
    };
    let sim = sim.expect("simulated cell");
    let (truth, true_axis) = {
        let w = lock_world(&sim.world);
        (w.true_model().clone(), w.stage_axis_actual())
    };
    // the noise floor: the true robot against the stored verification measurements
    let id = ctx.campaign_id;
    let rows = ctx
        .store
        .blocking(|s| s.measured(id))
        .map(identification_rows)
        .expect("rows");
    let opts = identify_options(&ctx.cfg);
    let (_, verify) = split(&rows);
    let verify = to_measured(&verify, opts.obs.model, ctx.cfg.stage.travel_mm).expect("verify");
    let floor_mm = evaluate(&truth, &verify, &opts.obs).position_mean_mm;
    let after = report
        .metrics
        .verify
        .as_ref()
        .expect("verify metrics")
        .after
        .position_mean_mm;
    sim.stop().await;
    Finished {
        report_after_mm: after,
        floor_mm,
        store,
        id: ctx.campaign_id,
        report: *report,
        truth,
        true_axis,
        cfg: ctx.cfg.clone(),
        nominal: ctx.nominal.clone(),
    }
}

pub(crate) fn check_complete(store: &Path, id: i64, poses: usize) {
    let s = Store::open(store).expect("store");
    let done = s.done_poses(id).expect("done");
    assert_eq!(done.len(), poses, "every pose measured once");
    let unique: BTreeSet<usize> = done.iter().copied().collect();
    assert_eq!(unique.len(), poses, "no duplicated pose");
    let rows = s.measured(id).map(identification_rows).expect("rows");
    assert_eq!(rows.len(), poses);
    assert!(
        s.latest_result(id).expect("result").is_some(),
        "result stored"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn full_simulated_campaign_reaches_the_noise_floor() {
    let f = run_in_process(&config_text("", "", "")).await;
    assert!(
        f.report_after_mm <= 1.10 * f.floor_mm,
        "verification after {:.5} mm vs floor {:.5} mm",
        f.report_after_mm,
        f.floor_mm
    );
    check_complete(&f.store, f.id, 300);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn campaign_with_faults_loses_and_duplicates_nothing() {
    let text = config_text("", "", "beam_break_probability = 0.05\nrelock_after_ms = 5")
        .replace(
            "disconnect_after_measurements = 0",
            "disconnect_after_measurements = 400",
        )
        .replace("never_settle = 0 ", "never_settle = 1 ");
    let f = run_in_process(&text).await;
    assert!(
        f.report_after_mm <= 1.10 * f.floor_mm,
        "verification after {:.5} mm vs floor {:.5} mm",
        f.report_after_mm,
        f.floor_mm
    );
    check_complete(&f.store, f.id, 300);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nothing_moves_unless_armed_and_abort_is_accepted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = config_text("", "", "");
    let session = sim_session(dir.path(), &text).await;
    let ctx = session.ctx;
    let mut devices = session.devices;
    let sim = session.sim.expect("sim");
    let moves_before = lock_world(&sim.world).moves();
    ctx.control.apply(&CampaignCommand::Start); // start without arming
    let control = ctx.control.clone();
    let world = sim.world.clone();
    let watcher = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(300)).await;
        let moved = lock_world(&world).moves();
        control.apply(&CampaignCommand::Abort);
        moved
    });
    let outcome = tokio::time::timeout(Duration::from_secs(10), run_campaign(&ctx, &mut devices))
        .await
        .expect("abort ends the run")
        .expect("runs");
    let moved = watcher.await.expect("watcher");
    assert_eq!(moved, moves_before, "the robot moved while not armed");
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    assert_eq!(
        ctx.store
            .blocking(|s| s.done_poses(ctx.campaign_id))
            .expect("done")
            .len(),
        0
    );
    sim.stop().await;
}

#[test]
fn kill_9_at_random_moments_then_resume_loses_and_duplicates_nothing() {
    use rand::{Rng, SeedableRng};
    let dir = tempfile::tempdir().expect("tempdir");
    // default (not accelerated) simulated timing: ~80 ms per pose, so kills land mid-campaign
    let text = config_text("", "", "")
        .replace(
            "move_speed_deg_s = 200000.0\nstage_speed_mm_s = 100000.0\n",
            "",
        )
        .replace("poses = 300", "poses = 120")
        .replace("ident = 100", "ident = 40");
    let cfg = write_config(dir.path(), &text);
    let store = dir.path().join("c.db");
    let bin = assert_cmd::cargo::cargo_bin("cellcal");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(99);
    let mut previous: BTreeSet<usize> = BTreeSet::new();
    let mut kills = 0;
    let mut created = false;
    for round in 0..8 {
        let mut cmd = std::process::Command::new(&bin);
        cmd.args(["run", "--quiet", "--arm", "--config"])
            .arg(&cfg)
            .arg("--store")
            .arg(&store);
        if created {
            cmd.args(["--campaign", "1"]);
        }
        let mut child = cmd
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("spawn cellcal run");
        let wait_ms = rng.random_range(300..1500);
        std::thread::sleep(Duration::from_millis(wait_ms));
        if child.try_wait().expect("try_wait").is_none() && round < 4 {
            child.kill().expect("kill -9"); // SIGKILL
            kills += 1;
        }
        let status = child.wait().expect("wait");
        assert!(status.code() != Some(2), "bad input in round {round}");
        let s = Store::open(&store).expect("store");
        created = s.latest_campaign().expect("latest").is_some();
        if !created {
            continue;
        }
        let done: BTreeSet<usize> = s.done_poses(1).expect("done").into_iter().collect();
        assert!(
            previous.is_subset(&done),
            "acknowledged poses lost after a kill"
        );
        previous = done;
        if status.success() {
            break;
        }
        let _ = status;
    }
    assert!(
        kills >= 2,
        "the test must actually kill the binary ({kills})"
    );
    // finish if the rounds above did not
    let out = std::process::Command::new(&bin)
        .args(["run", "--quiet", "--arm", "--campaign", "1", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store)
        .output()
        .expect("final run");
    let s = Store::open(&store).expect("store");
    if s.latest_result(1).expect("result").is_none() {
        panic!("final run failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    check_complete(&store, 1, 120);
}

#[test]
fn bad_configuration_is_a_clear_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (text, want) in [
        ("[campaign]\nposes = \"x\"\n", "poses"),
        ("[campaign]\nmodel = \"xyz\"\n", "campaign.model"),
        ("[stage]\naxis = \"+q\"\n", "stage.axis"),
        ("[tracker]\nmeasure_ms = 0\n", "tracker.measure_ms"),
        ("[trackr]\nmode = \"sim\"\n", "trackr"),
    ] {
        let p = dir.path().join("bad.toml");
        std::fs::write(&p, text).expect("write");
        let out = std::process::Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
            .args(["run", "--config"])
            .arg(&p)
            .output()
            .expect("runs");
        assert_eq!(out.status.code(), Some(2), "{text}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("bad.toml") && err.contains(want),
            "{text}: {err}"
        );
    }
}

/// Run `text` in process; `on_event` sees every event with the live cell and may steer it.
pub(crate) async fn run_steered(
    text: &str,
    mut on_event: impl FnMut(&CampaignEvent, &cellcal::sim::RunningSimCell, &Control) + Send + 'static,
) -> (Outcome, PathBuf, i64) {
    let dir = tempfile::tempdir().expect("tempdir").keep();
    let cfg_path = write_config(&dir, text);
    let cfg = parse_cell_config(text, &cfg_path).expect("config");
    let store = dir.join("c.db");
    let session = open_session(cfg, &store, None, Arc::new(ScriptedPrompter::exact()))
        .await
        .expect("session");
    let ctx = session.ctx;
    let mut devices = session.devices;
    let sim = Arc::new(session.sim.expect("simulated cell"));
    let mut rx = ctx.control.events.subscribe();
    let control = ctx.control.clone();
    let cell = Arc::clone(&sim);
    let steer = tokio::spawn(async move {
        while let Ok(e) = rx.recv().await {
            on_event(&e.event, &cell, &control);
        }
    });
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = tokio::time::timeout(Duration::from_secs(60), run_campaign(&ctx, &mut devices))
        .await
        .expect("campaign ends in time")
        .expect("campaign runs");
    steer.abort();
    let _ = steer.await;
    if let Ok(sim) = Arc::try_unwrap(sim) {
        sim.stop().await;
    }
    (outcome, store, ctx.campaign_id)
}

pub(crate) fn journal_states(store: &Path, id: i64) -> Vec<serde_json::Value> {
    Store::open(store)
        .expect("store")
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .filter(|e| e.event.kind() == "state")
        .map(|e| serde_json::to_value(&e.event).expect("event JSON")["state"].clone())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_emergency_stop_pauses_with_the_reason_and_resume_completes() {
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20")
        .replace("estop_after_moves = 0 ", "estop_after_moves = 6 ");
    let (outcome, store, id) = run_steered(&text, |e, cell, control| {
        if let CampaignEvent::State {
            state: CampaignState::Paused { reason },
        } = e
        {
            assert!(reason.contains("emergency stop"), "pause reason: {reason}");
            // the operator clears the E-stop and resumes
            lock_world(&cell.world).set_estop(false);
            control.apply(&CampaignCommand::Resume);
        }
    })
    .await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    check_complete(&store, id, 40);
    let states = journal_states(&store, id);
    let paused: Vec<_> = states.iter().filter(|s| s["state"] == "paused").collect();
    assert_eq!(paused.len(), 1, "{states:?}");
    assert!(states.iter().any(|s| s["state"] == "done"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn drift_above_the_threshold_pauses_for_the_operator() {
    // 10 mm/s of tracker drift: the first check after 5 poses is far above 0.1 mm
    let text = config_text("", "", "")
        .replace("drift_um_per_min = 0.0", "drift_um_per_min = 600000.0")
        .replace("drift_every = 50", "drift_every = 5")
        // this much drift also spoils the setup's sphere fit (which pauses too): not the subject
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false");
    let (outcome, store, id) = run_steered(&text, |e, _cell, control| {
        if let CampaignEvent::State {
            state: CampaignState::Paused { reason },
        } = e
        {
            assert!(reason.contains("drift"), "pause reason: {reason}");
            control.apply(&CampaignCommand::Abort);
        }
    })
    .await;
    assert!(matches!(outcome, Outcome::Aborted), "{outcome:?}");
    let done = Store::open(&store)
        .expect("store")
        .done_poses(id)
        .expect("done");
    assert_eq!(done.len(), 5, "paused at the first drift check");
    let states = journal_states(&store, id);
    assert!(states.iter().any(|s| s["state"] == "paused"), "{states:?}");
    assert_eq!(states.last().expect("states")["state"], "aborted");
}

pub(crate) fn setup_of(store: &Path, id: i64) -> cellcal::campaign::SetupResult {
    let s = Store::open(store).expect("store");
    cellcal::campaign::SetupResult::load(&s, id)
        .expect("setup row")
        .expect("setup stored")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_tool_frame_setup_measures_the_ball_and_rescues_a_wrong_design_tool() {
    // the design tool is 12 mm off the real ball (0.4, -0.3, 60) and the tool is not identified
    let wrong = |setup: bool| {
        let t = config_text("", "", "")
            .replace("tool_mm = [0.0, 0.0, 60.0]", "tool_mm = [5.0, -5.0, 50.0]");
        if setup {
            t
        } else {
            // (the base registration would catch the wrong tool: its RMS pauses the campaign)
            t.replace("tool_frame = true", "tool_frame = false")
                .replace("base_registration = true", "base_registration = false")
        }
    };
    let f = run_in_process(&wrong(true)).await;
    let setup = setup_of(&f.store, f.id);
    let tf = setup.tool_frame.expect("tool frame measured");
    let tool = nalgebra::Vector3::from(tf.tool_mm);
    // the procedure sees the flange as the nominal model realises it on the true robot: the
    // Table 3 errors bias it by a few tenths of a millimetre, the identification absorbs that
    assert!(
        (tool - nalgebra::Vector3::new(0.4, -0.3, 60.0)).norm() < 1.0,
        "measured tool {tool:?}"
    );
    let axis = nalgebra::Vector3::from(tf.stage_axis);
    assert!(
        axis.y > 0.9999 - 1e-4 && axis.norm() > 0.999_999,
        "{axis:?}"
    );
    assert!(tf.sphere_rms_mm < 0.05, "sphere RMS {}", tf.sphere_rms_mm);
    assert!((tf.jog_axes_angle_deg - 90.0).abs() < 0.5);
    let base = setup.base.expect("base registered");
    assert!(base.rms_mm < 2.0, "base RMS {}", base.rms_mm);
    assert!(
        f.report_after_mm <= 1.10 * f.floor_mm,
        "with setup: verification after {:.5} mm vs floor {:.5} mm",
        f.report_after_mm,
        f.floor_mm
    );
    // the same campaign without the tool-frame step keeps the wrong tool
    let g = run_in_process(&wrong(false)).await;
    assert!(
        g.report_after_mm > 1.3 * g.floor_mm,
        "without setup: verification after {:.5} mm vs floor {:.5} mm",
        g.report_after_mm,
        g.floor_mm
    );
    let s = Store::open(&g.store).expect("store");
    assert_eq!(
        cellcal::campaign::SetupResult::load(&s, g.id).expect("setup"),
        None
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stage_fault_after_p1_keeps_p1_as_discarded_and_resume_measures_the_pose_again() {
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20");
    let armed = std::sync::atomic::AtomicBool::new(false);
    let (outcome, store, id) = run_steered(&text, move |e, cell, control| match e {
        CampaignEvent::Measured { done: 2, .. }
            if !armed.swap(true, std::sync::atomic::Ordering::SeqCst) =>
        {
            // after an even number of poses the stage is back at P1: the next pose reads P1
            // there, then its one stage move (to P2) fails
            cell.stage_sim.as_ref().expect("zaber stage").faults().fault = 1;
        }
        CampaignEvent::State {
            state: CampaignState::Paused { reason },
        } => {
            assert!(reason.contains("stage"), "pause reason: {reason}");
            control.apply(&CampaignCommand::Resume);
        }
        _ => {}
    })
    .await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    check_complete(&store, id, 40);
    let conn = rusqlite::Connection::open(&store).expect("sqlite");
    let (n, pose): (i64, Option<i64>) = conn
        .query_row(
            "SELECT count(*), max(pose_index) FROM measurements \
             WHERE kind = 'discarded' AND note LIKE 'P1 of an unfinished pose%'",
            [],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .expect("query");
    assert_eq!(n, 1, "the P1 taken before the fault is on disk");
    // that pose was measured again after the resume and is done once
    let pose = pose.expect("pose index") as usize;
    assert!(Store::open(&store)
        .expect("store")
        .done_poses(id)
        .expect("done")
        .contains(&pose));
}

/// The engine tells the technician where it is: every stage question of a manual campaign
/// names its step, pose n of N and P1 or P2 (agreeing with the requested position), and says
/// the robot stands still (each question comes after a settled move, before the next one);
/// every measured pose carries its deviation from the nominal model once the base is
/// registered.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn manual_questions_carry_their_context_and_poses_their_deviation() {
    let text = config_text("", "", "")
        .replace("kind = \"serial\"", "kind = \"manual\"")
        .replace("stage_mode = \"zaber\"", "stage_mode = \"manual\"")
        .replace("tool_frame = true", "tool_frame = false")
        .replace("poses = 300", "poses = 20")
        .replace("ident = 100", "ident = 14");
    let dir = tempfile::tempdir().expect("tempdir");
    let prompter = Arc::new(ScriptedPrompter::exact());
    let (ctx, sim, outcome) = run_with(dir.path(), &text, prompter.clone()).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let stage = &ctx.cfg.stage;
    let (p1, p2) = (stage.p1_mm, stage.p1_mm + stage.travel_mm);
    let all = prompter.asked();
    // after a stage answer the technician confirms the cell clear before the robot moves
    // (its own question; the robot stands still meanwhile)
    let (clears, asked): (Vec<_>, Vec<_>) = all
        .into_iter()
        .partition(|p| p.id == cellcal::cell::CONFIRM_CLEAR);
    assert!(clears.len() >= 20, "{} clears", clears.len());
    assert!(clears.iter().all(|p| p.context.robot_stopped), "{clears:?}");
    let steps: Vec<Option<&str>> = asked.iter().map(|p| p.context.step.as_deref()).collect();
    // base registration sets the stage at P1 once (the drift checks find it there), then the
    // poses ask for P2 and back to P1
    assert_eq!(steps.first(), Some(&Some("setup")), "{steps:?}");
    assert!(steps[1..].iter().all(|s| *s == Some("pose")), "{steps:?}");
    let mut poses = BTreeSet::new();
    for p in &asked {
        let c = &p.context;
        assert!(c.robot_stopped, "{p:?}");
        assert_eq!(c.retry_reason, None, "{p:?}");
        let want = match p.expected_mm {
            Some(mm) if (mm - p1).abs() < 1e-9 => Some(StagePosition::P1),
            Some(mm) if (mm - p2).abs() < 1e-9 => Some(StagePosition::P2),
            other => panic!("unexpected stage request {other:?}"),
        };
        assert_eq!(c.position, want, "{p:?}");
        match c.step.as_deref() {
            Some("pose") => {
                assert_eq!(c.poses_total, Some(20), "{p:?}");
                poses.insert(c.pose.expect("pose n"));
            }
            _ => assert_eq!((c.pose, c.poses_total), (None, None), "{p:?}"),
        }
    }
    assert_eq!(poses, (1..=20).collect(), "pose n of N, from 1 to 20");
    let events = ctx
        .store
        .blocking(|s| s.events::<CampaignEvent>(ctx.campaign_id))
        .expect("events");
    let measured: Vec<serde_json::Value> = events
        .iter()
        .filter(|e| e.event.kind() == "measured")
        .map(|e| serde_json::to_value(&e.event).expect("JSON"))
        .collect();
    assert_eq!(measured.len(), 20);
    for m in &measured {
        let d = m["deviation_mm"].as_f64().expect("deviation_mm");
        assert!(d.is_finite() && d > 0.0 && d < 20.0, "{m}");
        assert_eq!(
            m["deviation_xyz_mm"].as_array().map(Vec::len),
            Some(3),
            "{m}"
        );
    }
    if let Some(sim) = sim {
        sim.stop().await;
    }
}
