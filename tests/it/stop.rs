//! Stopping the cell: a disarm stops the robot and the stage at once and pauses (nothing is
//! powered on or moved while disarmed), abort and disarm stop the motorised stage, the
//! cell-wide stop of `POST /api/cell/stop`, and no robot motion after a manual stage answer
//! until the technician confirms the cell clear. The robot's side is watched through a logging
//! robotlink proxy between cellcal and the simulated controller (every line timestamped).

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

use cellcal::campaign::{run_campaign, CampaignCommand, CampaignEvent, CampaignState, Outcome};
use cellcal::cell::{Answer, LinkRobot, ScriptedPrompter, CONFIRM_CLEAR};
use cellcal::config::parse_cell_config;

use super::campaign::{config_text, sim_session, write_config};
use super::serve::{get, get_as, post_as, role_tokens, start_as_operator, wait_for_state};

/// One robotlink line the proxy passed on.
#[derive(Debug, Clone)]
struct Line {
    at: Instant,
    /// Sent by cellcal (else by the controller).
    from_client: bool,
    text: String,
}

impl Line {
    /// The request's verb and arguments (`MOVEJ 1 2 …`, `POWER ON`), without its sequence
    /// number; a reply's text after its sequence number.
    fn body(&self) -> &str {
        self.text
            .split_once(' ')
            .map_or(self.text.as_str(), |(_, rest)| rest)
    }
}

/// A TCP proxy between cellcal and the simulated robot controller that logs every line.
struct Proxy {
    addr: SocketAddr,
    log: Arc<Mutex<Vec<Line>>>,
}

impl Proxy {
    /// Listen on a free loopback port; every connection is forwarded to `upstream`.
    fn start(upstream: SocketAddr) -> Proxy {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind proxy");
        let addr = listener.local_addr().expect("proxy address");
        let log: Arc<Mutex<Vec<Line>>> = Arc::default();
        let sink = Arc::clone(&log);
        std::thread::spawn(move || {
            for conn in listener.incoming() {
                let Ok(client) = conn else { return };
                let Ok(server) = TcpStream::connect(upstream) else {
                    continue;
                };
                let (c2, s2) = (
                    client.try_clone().expect("clone"),
                    server.try_clone().expect("clone"),
                );
                pump(client, s2, true, Arc::clone(&sink));
                pump(server, c2, false, Arc::clone(&sink));
            }
        });
        Proxy { addr, log }
    }

    fn lines(&self) -> Vec<Line> {
        self.log.lock().expect("log").clone()
    }

    /// Requests from cellcal whose body starts with `verb`, sent at or after `t`.
    fn sent(&self, verb: &str, t: Instant) -> Vec<Line> {
        self.lines()
            .into_iter()
            .filter(|l| l.from_client && l.at >= t && l.body().starts_with(verb))
            .collect()
    }

    /// Wait (≤ 60 s) until `verb` has been sent at or after `t`; the first such line.
    fn until_sent(&self, verb: &str, t: Instant) -> Line {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(l) = self.sent(verb, t).into_iter().next() {
                return l;
            }
            assert!(Instant::now() < deadline, "no {verb} after {t:?}");
            std::thread::sleep(Duration::from_millis(2));
        }
    }
}

/// Copy lines from `from` to `to`, logging each with the time it passed.
fn pump(from: TcpStream, mut to: TcpStream, from_client: bool, log: Arc<Mutex<Vec<Line>>>) {
    std::thread::spawn(move || {
        let mut r = BufReader::new(from);
        let mut line = String::new();
        loop {
            line.clear();
            if !matches!(r.read_line(&mut line), Ok(n) if n > 0) {
                let _ = to.shutdown(std::net::Shutdown::Both);
                return;
            }
            log.lock().expect("log").push(Line {
                at: Instant::now(),
                from_client,
                text: line.trim_end().to_owned(),
            });
            if to.write_all(line.as_bytes()).is_err() {
                return;
            }
        }
    });
}

/// 20 poses (14 to identify) and no setup steps: the subject here is stopping, not measuring.
fn twenty_poses_no_setup(text: String) -> String {
    text.replace("poses = 300", "poses = 20")
        .replace("ident = 100", "ident = 14")
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false")
}

use super::common::free_port;

/// The simulated cell of config/cell.sim.toml with slow joints (10 deg/s: a move takes
/// seconds), no setup steps, 20 poses, the robot controller reached through `proxy` (a "real"
/// robot at the proxy's address, the simulated one at `robot_port`), a `stage` of that kind,
/// the shared secret in `dir`, and the role tokens.
fn proxied_config(
    dir: &std::path::Path,
    robot_port: u16,
    proxy: SocketAddr,
    stage: &str,
) -> String {
    twenty_poses_no_setup(config_text("", "", ""))
        .replace("move_speed_deg_s = 200000.0\n", "move_speed_deg_s = 10.0\n")
        .replace(
            "[robot_controller]\nmode = \"sim\"\n",
            &(super::common::real_controller(dir, proxy) + "\n"),
        )
        .replace("robot_port = 0", &format!("robot_port = {robot_port}"))
        .replace("kind = \"serial\"", &format!("kind = \"{stage}\""))
        + &role_tokens()
}

/// The operator's `commands` to campaign `id`, one after the other, each answered 200.
fn operator_commands(s: &super::serve::Server, id: i64, commands: &[&str]) {
    for c in commands {
        let (code, v) = command(s, "operator-token", id, &format!(r#"{{"command": "{c}"}}"#));
        assert_eq!(code, 200, "{c}: {v}");
    }
}

/// A daemon (`serve`, role tokens) on [`proxied_config`] with a `stage` of that kind (`edit`
/// applied to the configuration text) and a campaign created by the operator: the directory,
/// the proxy, the daemon and the campaign id.
fn proxied_daemon(
    stage: &str,
    edit: impl FnOnce(String) -> String,
) -> (tempfile::TempDir, Proxy, super::serve::Server, i64) {
    let dir = tempfile::tempdir().expect("tempdir");
    let robot_port = free_port();
    let proxy = Proxy::start(SocketAddr::from(([127, 0, 0, 1], robot_port)));
    let text = edit(proxied_config(dir.path(), robot_port, proxy.addr, stage));
    let cfg = write_config(dir.path(), &text);
    let s = start_as_operator(&cfg, &dir.path().join("c.db"));
    let (code, v) = post_as(&s, "operator-token", "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    (dir, proxy, s, id)
}

/// A technician's command (JSON `body`) to campaign `id`: status and body.
fn technician(s: &super::serve::Server, id: i64, body: &str) -> (u16, Value) {
    command(s, "technician-token", id, body)
}

/// Send `command` to campaign `id` as `token`: status and body.
fn command(s: &super::serve::Server, token: &str, id: i64, body: &str) -> (u16, Value) {
    post_as(s, token, &format!("/api/campaigns/{id}/commands"), body)
}

/// Wait until a `MOVEJ` has been sent and the arm has been on its way for 300 ms with its
/// `WAIT` unanswered; the MOVEJ line.
fn mid_move(proxy: &Proxy, after: Instant) -> Line {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let lines = proxy.lines();
        let movej = lines
            .iter()
            .rposition(|l| l.from_client && l.at >= after && l.body().starts_with("MOVEJ"));
        if let Some(k) = movej {
            let replies_after = lines[k + 1..]
                .iter()
                .filter(|l| !l.from_client && l.body().contains("ERR"))
                .count();
            let waited = lines[k].at.elapsed() > Duration::from_millis(300);
            let settled = lines[k + 1..]
                .iter()
                .any(|l| !l.from_client && l.text.split_whitespace().count() >= 7);
            if waited && !settled && replies_after == 0 {
                return lines[k].clone();
            }
        }
        assert!(Instant::now() < deadline, "never mid-move: {lines:#?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn disarm_over_rest_stops_the_arm_within_200_ms_and_nothing_moves_or_powers_on_until_armed() {
    let (_dir, proxy, s, id) = proxied_daemon("serial", |t| t);
    let t0 = Instant::now();
    operator_commands(&s, id, &["arm", "start"]);
    // the arm on its way (10 deg/s), then a disarm
    mid_move(&proxy, t0);
    let disarmed = Instant::now();
    let (code, v) = command(&s, "operator-token", id, r#"{"command": "disarm"}"#);
    let answered = disarmed.elapsed();
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["armed"], Value::Bool(false), "{v}");
    assert_eq!(
        v["state"], "paused",
        "the reply says where the disarm led: {v}"
    );
    let stop = proxy.until_sent("STOP", disarmed);
    let latency = stop.at - disarmed;
    eprintln!("disarm request → STOP at the controller: {latency:?} (reply after {answered:?})");
    assert!(
        latency < Duration::from_millis(200),
        "STOP after {latency:?}"
    );
    // the controller ended the WAIT: the arm stopped where it was
    let lines = proxy.lines();
    assert!(
        lines
            .iter()
            .any(|l| !l.from_client && l.at >= disarmed && l.body().contains("E_STOPPED")),
        "{lines:#?}"
    );
    let v = wait_for_state(&s, id, "paused");
    let stopped = journal_kind(&s, id, "stopped");
    assert!(
        stopped
            .iter()
            .any(|e| e["reason"] == "disarm" && e["robot"] == "stopped" && e["stage"] == "stopped"),
        "{stopped:?} / {v}"
    );
    // resuming while disarmed is refused; nothing is powered on or moved meanwhile
    let (code, e) = command(&s, "operator-token", id, r#"{"command": "resume"}"#);
    assert_eq!(code, 409, "{e}");
    assert!(
        e["error"].as_str().expect("error").contains("not armed"),
        "{e}"
    );
    std::thread::sleep(Duration::from_millis(1500));
    for verb in ["MOVEJ", "POWER ON"] {
        let after = proxy.sent(verb, disarmed);
        assert!(after.is_empty(), "{verb} after the disarm: {after:#?}");
    }
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["state"], "paused", "{v}");
    // armed and resumed: power on again, then motion
    let resumed = Instant::now();
    operator_commands(&s, id, &["arm", "resume"]);
    let power = proxy.until_sent("POWER ON", resumed);
    let movej = proxy.until_sent("MOVEJ", resumed);
    assert!(power.at < movej.at, "power on before the next move");
    // the cell-wide stop, by a viewer: the campaign aborts, robot and stage are told to stop
    mid_move(&proxy, resumed);
    let stopping = Instant::now();
    let (code, v) = post_as(&s, "viewer-token", "/api/cell/stop", "{}");
    assert_eq!(code, 200, "{v}");
    let stop = proxy.until_sent("STOP", stopping);
    eprintln!("cell stop → STOP: {:?}", stop.at - stopping);
    assert!(stop.at - stopping < Duration::from_millis(200));
    assert_eq!(v["campaign"], id, "{v}");
    assert_eq!(v["state"], "aborted", "{v}");
    assert_eq!(v["robot"], "stopped", "{v}");
    assert_eq!(v["stage"], "stopped", "{v}");
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        proxy.sent("MOVEJ", stop.at).is_empty(),
        "no move after the stop"
    );
    // nothing loaded: nothing to stop, said so
    let (code, v) = post_as(&s, "viewer-token", "/api/cell/stop", "{}");
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["campaign"], Value::Null, "{v}");
    assert_eq!(v["robot"], Value::Null, "{v}");
}

/// The journalled events of `kind` of campaign `id` (their event JSON).
fn journal_kind(s: &super::serve::Server, id: i64, kind: &str) -> Vec<Value> {
    let (code, v) = get(s, &format!("/api/campaigns/{id}/events"));
    assert_eq!(code, 200, "{v}");
    v.as_array()
        .expect("journal")
        .iter()
        .filter(|e| e["kind"] == kind)
        .map(|e| e["event"].clone())
        .collect()
}

#[test]
fn a_manual_stage_answer_releases_no_motion_until_the_cell_is_confirmed_clear_over_rest() {
    let (_dir, proxy, s, id) = proxied_daemon("manual", |t| {
        t.replace("move_speed_deg_s = 10.0\n", "move_speed_deg_s = 2000.0\n")
    });
    operator_commands(&s, id, &["arm", "start"]);
    let question = |last: u64| {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let (_, v) = get_as(&s, "technician-token", &format!("/api/campaigns/{id}"));
            if let Some(seq) = v["prompt"]["seq"].as_u64().filter(|&q| q > last) {
                return (seq, v["prompt"].clone());
            }
            assert!(Instant::now() < deadline, "no question after {last}: {v}");
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    let mut last = 0;
    let mut cleared = 0;
    // the drift reference's P1, then two poses (P2, back to P1), each release checked
    while cleared < 2 {
        let (seq, q) = question(last);
        last = seq;
        assert_eq!(q["robot_stopped"], Value::Bool(true), "{q}");
        if q["id"] == CONFIRM_CLEAR {
            assert_eq!(q["expected_mm"], Value::Null, "{q}");
            // an ordinary answer does not release the robot
            let (code, e) =
                technician(&s, id, &format!(r#"{{"command": "answer", "seq": {seq}}}"#));
            assert_eq!(code, 409, "{e}");
            assert!(e["error"]
                .as_str()
                .expect("error")
                .contains("confirm_clear"));
            let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
            assert_eq!(v["prompt"]["seq"], seq, "still open: {v}");
            // nothing moved since the stage answer; the confirmation releases the move
            let before = Instant::now();
            let (code, v) = technician(
                &s,
                id,
                &format!(r#"{{"command": "confirm_clear", "seq": {seq}}}"#),
            );
            assert_eq!(code, 200, "{v}");
            let movej = proxy.until_sent("MOVEJ", before);
            eprintln!("confirm_clear → MOVEJ: {:?}", movej.at - before);
            cleared += 1;
            continue;
        }
        // a stage question: confirm_clear does not answer it
        let (code, e) = technician(
            &s,
            id,
            &format!(r#"{{"command": "confirm_clear", "seq": {seq}}}"#),
        );
        assert_eq!(code, 409, "{e}");
        let mm = q["expected_mm"].as_f64().expect("a reading");
        let (code, v) = technician(
            &s,
            id,
            &format!(r#"{{"command": "answer", "seq": {seq}, "value_mm": {mm}}}"#),
        );
        assert_eq!(code, 200, "{v}");
        let answered = Instant::now();
        // a hand may be at the stage: no robot command that moves, however long we wait
        let (next, nq) = question(seq);
        last = next - 1;
        if nq["id"] == CONFIRM_CLEAR {
            std::thread::sleep(Duration::from_millis(500));
            let moves = proxy.sent("MOVEJ", answered);
            assert!(
                moves.is_empty(),
                "moved before the cell was clear: {moves:#?}"
            );
        }
    }
    let (code, v) = post_as(&s, "operator-token", "/api/cell/stop", "{}");
    assert_eq!(code, 200, "{v}");
    assert_eq!(v["stage"], "manual", "{v}");
}

/// What [`stage_stops_on`] saw.
struct StageStop {
    outcome: Outcome,
    /// The run's `stopped` events and states, in order.
    events: Vec<CampaignEvent>,
    /// When the command was applied.
    applied: Instant,
    /// The robot's side of the run.
    proxy: Proxy,
}

/// A simulated cell with a slow Zaber stage (2 mm/s: the 10 mm travel to P2 takes 5 s) and no
/// setup steps, run in process until the stage is on its way to P2; then `cmd` is applied and
/// the stage must stand still (its simulated position read until it no longer changes) and stay
/// there. A run that pauses instead of ending is resumed (as a terminal's Enter would, still
/// disarmed), then aborted once the stage stood still.
/// The stage must stand within 200 ms, and the run's first `stopped` event (`reason`) say
/// that robot and stage stopped.
async fn stage_stops_on(cmd: CampaignCommand, reason: &str) -> StageStop {
    let text = twenty_poses_no_setup(config_text("stage_speed_mm_s = 2.0\n", "", ""))
        .replace("stage_speed_mm_s = 100000.0\n", "");
    let dir = tempfile::tempdir().expect("tempdir");
    let session = sim_session(dir.path(), &text).await;
    let (ctx, mut devices) = (session.ctx, session.devices);
    let sim = session.sim.expect("sim");
    let proxy = through_proxy(&sim, &mut devices);
    let stage = sim.stage_sim.clone().expect("a Zaber stage");
    let control = ctx.control.clone();
    let mut events = control.events.subscribe();
    let watcher = tokio::spawn(async move {
        until_on_its_way(&stage).await;
        let applied = Instant::now();
        control.apply(&cmd);
        (
            until_it_stands(&stage, applied, "the command").await,
            applied,
        )
    });
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let abort = ctx.control.clone();
    let (outcome, (stood, applied)) = tokio::time::timeout(
        Duration::from_secs(60),
        futures_join(run_campaign(&ctx, &mut devices), async move {
            // a disarm pauses (the run does not end by itself): a resume while disarmed
            // leaves it paused; then abort it
            let stood = watcher.await.expect("watcher");
            abort.apply(&CampaignCommand::Resume);
            tokio::time::sleep(Duration::from_millis(500)).await;
            abort.apply(&CampaignCommand::Abort);
            stood
        }),
    )
    .await
    .expect("the run ends");
    let outcome = outcome.expect("runs");
    let mut seen = Vec::new();
    while let Ok(j) = events.try_recv() {
        if matches!(
            j.event,
            CampaignEvent::Stopped { .. } | CampaignEvent::State { .. }
        ) {
            seen.push(j.event);
        }
    }
    sim.stop().await;
    assert!(
        stood < Duration::from_millis(200),
        "stage stood after {stood:?}"
    );
    let stops = stops(&seen);
    assert_eq!(
        stops.first(),
        Some(&(reason.into(), "stopped".into(), "stopped".into())),
        "{stops:?}"
    );
    StageStop {
        outcome,
        events: seen,
        applied,
        proxy,
    }
}

/// Put a logging proxy between the session's robot adapter and the simulated controller.
fn through_proxy(
    sim: &cellcal::sim::RunningSimCell,
    devices: &mut cellcal::campaign::Devices,
) -> Proxy {
    let proxy = Proxy::start(sim.robot_addr);
    devices.robot = Box::new(LinkRobot::new(cellcal::cell::LinkRobotConfig {
        address: proxy.addr.to_string(),
        ..sim.robot_config()
    }));
    proxy
}

/// Both futures to completion.
async fn futures_join<A: std::future::Future, B: std::future::Future>(
    a: A,
    b: B,
) -> (A::Output, B::Output) {
    tokio::join!(a, b)
}

/// Wait (≤ 60 s) until `stage` is on its way to P2, past 2 mm.
async fn until_on_its_way(stage: &zaber::sim::StageSim) {
    let k = sim_steps_per_mm();
    let deadline = Instant::now() + Duration::from_secs(60);
    while !(stage.is_busy() && stage.position_steps() as f64 / k > 2.0) {
        assert!(Instant::now() < deadline, "the stage never moved to P2");
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}

/// How long after `t` the position of `stage` stopped changing (read every 5 ms); it must
/// then stay there (500 ms) short of P2.
async fn until_it_stands(stage: &zaber::sim::StageSim, t: Instant, what: &str) -> Duration {
    let mut last = stage.position_steps();
    let stood = loop {
        tokio::time::sleep(Duration::from_millis(5)).await;
        let now = stage.position_steps();
        if now == last && !stage.is_busy() {
            break t.elapsed();
        }
        last = now;
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the stage never stopped"
        );
    };
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        stage.position_steps(),
        last,
        "the stage stays where it stopped"
    );
    let at = last as f64 / sim_steps_per_mm();
    eprintln!("stage stopped at {at:.3} mm, {stood:?} after {what}");
    assert!(at < 9.0, "stopped before P2: {at} mm");
    stood
}

/// The simulated stage's microsteps per mm (config/cell.sim.toml).
fn sim_steps_per_mm() -> f64 {
    cellcal::sim::config::SimWorldConfig::default().stage_microsteps_per_mm
}

/// The `stopped` events among `events`: (reason, robot, stage).
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abort_stops_the_motorised_stage_within_200_ms() {
    let r = stage_stops_on(CampaignCommand::Abort, "abort").await;
    assert!(matches!(r.outcome, Outcome::Aborted), "{:?}", r.outcome);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disarm_stops_the_motorised_stage_within_200_ms_and_pauses() {
    let r = stage_stops_on(CampaignCommand::Disarm, "disarm").await;
    let paused = |why: &str| {
        r.events.iter().any(|e| {
            matches!(e, CampaignEvent::State { state: CampaignState::Paused { reason } } if reason.starts_with(why))
        })
    };
    assert!(paused("disarmed"), "{:?}", r.events);
    // the resume while disarmed kept it paused: nothing powered on or moved after the disarm
    assert!(paused("not armed"), "{:?}", r.events);
    for verb in ["POWER ON", "MOVEJ"] {
        let sent = r.proxy.sent(verb, r.applied);
        assert!(sent.is_empty(), "{verb} after the disarm: {sent:#?}");
    }
    // paused, resumable; the abort that followed ended it
    assert!(matches!(r.outcome, Outcome::Aborted), "{:?}", r.outcome);
}

/// Robot lines and technician questions of an in-process run with a manual stage (the robot
/// behind a logging proxy; `confirm_clear` as configured): every question and answer with its
/// time, and the proxy.
async fn manual_run(confirm_clear: Option<bool>) -> (Vec<(Instant, String)>, Proxy) {
    let key = confirm_clear.map_or(String::new(), |b| format!("confirm_clear = {b}\n"));
    let text = twenty_poses_no_setup(config_text("", "", ""))
        .replace("kind = \"serial\"", &format!("kind = \"manual\"\n{key}"));
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg_path = write_config(dir.path(), &text);
    let cfg = parse_cell_config(&text, &cfg_path).expect("config");
    let asked: Arc<Mutex<Vec<(Instant, String)>>> = Arc::default();
    let log = Arc::clone(&asked);
    let prompter = ScriptedPrompter::from_fn(move |p| {
        let answer = match p.expected_mm {
            Some(v) => Answer::Number(v),
            None if p.id == CONFIRM_CLEAR => {
                assert!(
                    p.context.robot_stopped,
                    "robot stopped while a hand may be there"
                );
                Answer::Clear
            }
            None => Answer::Confirmed,
        };
        log.lock()
            .expect("log")
            .push((Instant::now(), p.id.clone()));
        answer
    });
    let session = cellcal::campaign::session::open_session(
        cfg,
        &dir.path().join("c.db"),
        None,
        Arc::new(prompter),
    )
    .await
    .expect("session");
    let (ctx, mut devices) = (session.ctx, session.devices);
    let sim = session.sim.expect("sim");
    let proxy = through_proxy(&sim, &mut devices);
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = tokio::time::timeout(Duration::from_secs(120), run_campaign(&ctx, &mut devices))
        .await
        .expect("in time")
        .expect("runs");
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    sim.stop().await;
    let asked = asked.lock().expect("log").clone();
    (asked, proxy)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_manual_stage_answer_the_robot_moves_only_once_the_cell_is_confirmed_clear() {
    let (asked, proxy) = manual_run(None).await;
    let moves: Vec<Instant> = proxy
        .lines()
        .into_iter()
        .filter(|l| l.from_client && l.body().starts_with("MOVEJ"))
        .map(|l| l.at)
        .collect();
    let answers = asked.iter().filter(|(_, id)| id == "stage_move").count();
    let clears = asked.iter().filter(|(_, id)| id == CONFIRM_CLEAR).count();
    // one stage answer per pose (P2 first when the last pose ended there), drift checks aside
    assert!(
        answers >= 20 && clears >= 20,
        "{answers} answers, {clears} clears"
    );
    // between every stage answer and the next MOVEJ, the cell was confirmed clear
    for (at, id) in asked.iter().filter(|(_, id)| id == "stage_move") {
        let Some(next_move) = moves.iter().find(|m| *m > at) else {
            continue;
        };
        let cleared = asked
            .iter()
            .any(|(t, i)| i == CONFIRM_CLEAR && t > at && t < next_move);
        assert!(
            cleared,
            "{id} answered at {at:?}, a MOVEJ at {next_move:?} without a clear"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn confirm_clear_false_asks_nothing_more_and_a_serial_stage_refuses_it() {
    let (asked, _) = manual_run(Some(false)).await;
    assert!(asked.iter().all(|(_, id)| id != CONFIRM_CLEAR), "{asked:?}");
    let dir = tempfile::tempdir().expect("tempdir");
    let text = config_text("", "", "").replace(
        "kind = \"serial\"",
        "kind = \"serial\"\nconfirm_clear = true",
    );
    let path = write_config(dir.path(), &text);
    let e = parse_cell_config(&text, &path).expect_err("refused");
    assert!(e.to_string().contains("stage.confirm_clear"), "{e}");
}

/// `cellcal run --arm` on a cell whose "real" Zaber stage is a simulated one on a pty hosted by
/// this test (2 mm/s), sent `sig` while the stage moves to P2: how long until the stage's
/// position stopped changing, and the run's exit code.
async fn signal_stops_the_stage(sig: nix::sys::signal::Signal) -> (Duration, Option<i32>) {
    let k = sim_steps_per_mm();
    let stage = zaber::sim::StageSim::new(zaber::sim::StageSimConfig {
        speed_steps_s: 2.0 * k,
        ..zaber::sim::StageSimConfig::default()
    });
    let pty = zaber::pty::spawn_stage_pty(stage.clone()).expect("stage pty");
    let text = twenty_poses_no_setup(config_text("", "", "")).replace(
        "[stage]\nmode = \"sim\"\n",
        &format!(
            "[stage]\nmode = \"real\"\nserial_path = \"{}\"\n",
            pty.path()
        ),
    );
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_config(dir.path(), &text);
    let mut child = std::process::Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
        .args(["run", "--arm", "--quiet", "--on-fault", "fail", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(dir.path().join("c.db"))
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("spawn cellcal run");
    until_on_its_way(&stage).await;
    let t = Instant::now();
    nix::sys::signal::kill(nix::unistd::Pid::from_raw(child.id() as i32), sig).expect("signal");
    let stood = until_it_stands(&stage, t, sig.as_str()).await;
    let code = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status.code();
        }
        assert!(t.elapsed() < Duration::from_secs(30), "run did not exit");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    pty.shutdown();
    (stood, code)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_and_sighup_stop_the_motorised_stage_within_200_ms() {
    for (sig, exit) in [
        (nix::sys::signal::Signal::SIGTERM, 143),
        (nix::sys::signal::Signal::SIGHUP, 129),
    ] {
        let (stood, code) = signal_stops_the_stage(sig).await;
        assert_eq!(code, Some(exit), "{sig}");
        assert!(
            stood < Duration::from_millis(200),
            "{sig}: stage stood after {stood:?}"
        );
    }
}
