//! The operator's and technician's flow (issue 19, item 7): every command × state pair of the
//! command route either acts or says why not, a pause answers while a question is open, setup
//! readings survive a resume, and a manual campaign without a terminal is refused at start.

use std::process::Stdio;
use std::time::{Duration, Instant};

use serde_json::Value;

use super::serve::{fast_config, get, post, start, Server};

/// The binary as a plain process (stdin set by the caller).
fn cellcal() -> std::process::Command {
    std::process::Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
}

/// `cellcal run --arm` of a manual-stage campaign with stdin from /dev/null (no terminal):
/// refused with exit 2 and what to do, before anything is planned, stored, locked or moved.
#[test]
fn a_manual_campaign_without_a_terminal_is_refused_at_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    for kind in ["manual", "manual_gauge"] {
        let cfg = fast_config(dir.path(), kind, 20, 14);
        let store = dir.path().join(format!("{kind}.db"));
        let out = cellcal()
            .args(["run", "--arm", "--config"])
            .arg(&cfg)
            .arg("--store")
            .arg(&store)
            .stdin(Stdio::null())
            .output()
            .expect("run");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{kind}: {err}");
        for says in ["not a terminal", "cellcal serve", "in a terminal", kind] {
            assert!(err.contains(says), "{kind}: `{says}` missing: {err}");
        }
        assert!(!store.exists(), "{kind}: a store was created: {err}");
    }
    // a motorised stage asks nobody: the same run measures without a terminal
    let cfg = fast_config(dir.path(), "serial", 20, 14);
    let out = cellcal()
        .args(["run", "--arm", "--quiet", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(dir.path().join("serial.db"))
        .stdin(Stdio::null())
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// POST `body` to campaign `id`'s command route.
fn command(s: &Server, id: i64, body: &str) -> (u16, Value) {
    post(s, &format!("/api/campaigns/{id}/commands"), body)
}

/// The campaign view.
fn view(s: &Server, id: i64) -> Value {
    let (code, v) = get(s, &format!("/api/campaigns/{id}"));
    assert_eq!(code, 200, "{v}");
    v
}

/// Wait (≤ 60 s) until `f` accepts the campaign view; that view.
fn wait_view(s: &Server, id: i64, what: &str, f: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let v = view(s, id);
        if f(&v) {
            return v;
        }
        assert!(Instant::now() < deadline, "never {what}: {v}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// The open technician question, once there is one.
fn question(s: &Server, id: i64) -> Value {
    wait_view(s, id, "asked", |v| v["prompt"].is_object())["prompt"].clone()
}

/// Answer question `q` as the exact technician (the expected reading; the cell clear).
fn answer(s: &Server, id: i64, q: &Value) -> (u16, Value) {
    let seq = q["seq"].as_u64().expect("seq");
    if q["id"] == "confirm_clear" {
        command(
            s,
            id,
            &format!(r#"{{"command": "confirm_clear", "seq": {seq}}}"#),
        )
    } else {
        let mm = q["expected_mm"].as_f64().expect("a reading is asked for");
        command(
            s,
            id,
            &format!(r#"{{"command": "answer", "seq": {seq}, "value_mm": {mm}}}"#),
        )
    }
}

/// Answer every question until the view's state is `state`.
fn answer_until(s: &Server, id: i64, state: &str) -> Value {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let v = view(s, id);
        if v["state"] == state {
            return v;
        }
        assert!(Instant::now() < deadline, "never {state}: {v}");
        if v["prompt"].is_object() {
            let (code, e) = answer(s, id, &v["prompt"]);
            assert_eq!(code, 200, "{e}");
        } else {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// Abort campaign `id` and wait until the daemon has let go of it.
fn abort_and_unload(s: &Server, id: i64) {
    let (code, v) = command(s, id, r#"{"command": "abort"}"#);
    assert_eq!(code, 200, "{v}");
    wait_view(s, id, "unloaded", |v| v["loaded"] == false);
}

/// The states a campaign of a manual-stage cell is brought to (a technician question holds
/// the engine where the test wants it).
#[derive(Debug, Clone, Copy)]
enum At {
    /// Created and loaded, not armed.
    Idle,
    /// Created, armed, not started.
    Armed,
    /// Running, a technician question open.
    Running,
    /// Paused by the operator.
    Paused,
    /// Aborted after some setup readings; not loaded.
    Aborted,
    /// Aborted, then armed: loaded from the store, waiting for its start.
    AbortedArmed,
}

/// A new campaign of `s` brought to `at`.
fn bring(s: &Server, at: At) -> i64 {
    let id = super::serve::create(s, "{}");
    let cmd = |c: &str| {
        let (code, v) = command(s, id, &format!(r#"{{"command": "{c}"}}"#));
        assert_eq!(code, 200, "{at:?}: {c}: {v}");
    };
    if matches!(at, At::Idle) {
        return id;
    }
    cmd("arm");
    if matches!(at, At::Armed) {
        return id;
    }
    cmd("start");
    question(s, id);
    match at {
        At::Paused => {
            cmd("pause");
            answer_until(s, id, "paused");
        }
        At::Aborted | At::AbortedArmed => {
            let q = question(s, id);
            assert_eq!(answer(s, id, &q).0, 200);
            abort_and_unload(s, id);
            if matches!(at, At::AbortedArmed) {
                cmd("arm");
            }
        }
        _ => {}
    }
    id
}

/// What a command must answer: 200 with the state it leads to, or 409 saying why.
#[derive(Debug, Clone, Copy)]
enum Want {
    Ok(&'static str),
    Conflict(&'static str),
}

/// Every command × state pair of `POST /api/campaigns/{id}/commands` on the simulated cell
/// either acts (200, the reply in the state the command asks for) or is refused with the
/// reason (409): never a 200 that leaves the campaign where it was while the command asked
/// for something else. An aborted campaign, once armed, is resumed by `resume`.
#[test]
fn every_command_in_every_state_acts_or_says_why_not() {
    use At::*;
    use Want::{Conflict as No, Ok as Yes};
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "manual", 20, 14);
    let s = start(&cfg, &dir.path().join("c.db"));
    let commands = [
        "arm",
        "disarm",
        "start",
        "pause",
        "resume",
        "reregister",
        "abort",
        "answer",
        "confirm_clear",
    ];
    let table: [(At, [Want; 9]); 6] = [
        (
            Idle,
            [
                Yes("armed"),
                Yes("idle"),
                No("not armed"),
                No("has not started"),
                No("not armed"),
                No("not armed"),
                Yes("aborted"),
                No("not open"),
                No("not open"),
            ],
        ),
        (
            Armed,
            [
                Yes("armed"),
                Yes("idle"),
                Yes("running"),
                No("has not started"),
                No("has not started"),
                No("has not started"),
                Yes("aborted"),
                No("not open"),
                No("not open"),
            ],
        ),
        (
            Running,
            [
                Yes("running"),
                Yes("paused"),
                Yes("running"),
                Yes("running"),
                Yes("running"),
                No("not paused"),
                Yes("aborted"),
                Yes("running"),
                No("answered with `answer`"),
            ],
        ),
        (
            Paused,
            [
                Yes("paused"),
                Yes("paused"),
                No("send resume"),
                Yes("paused"),
                Yes("running"),
                Yes("running"),
                Yes("aborted"),
                No("not open"),
                No("not open"),
            ],
        ),
        (
            Aborted,
            [
                Yes("armed"),
                Yes("aborted"),
                No("not armed"),
                No("not loaded"),
                No("arm it, then resume"),
                No("not loaded"),
                Yes("aborted"),
                No("not loaded"),
                No("not loaded"),
            ],
        ),
        (
            AbortedArmed,
            [
                Yes("armed"),
                Yes("idle"),
                Yes("running"),
                No("has not started"),
                Yes("running"),
                Yes("running"),
                Yes("aborted"),
                No("not open"),
                No("not open"),
            ],
        ),
    ];
    for (at, wants) in table {
        for (cmd, want) in commands.iter().zip(wants) {
            let id = bring(&s, at);
            let before = view(&s, id);
            let seq = before["prompt"]["seq"].as_u64().unwrap_or(1);
            let body = match *cmd {
                "answer" if before["prompt"].is_object() => {
                    let mm = before["prompt"]["expected_mm"].as_f64().expect("reading");
                    format!(r#"{{"command": "answer", "seq": {seq}, "value_mm": {mm}}}"#)
                }
                "answer" => format!(r#"{{"command": "answer", "seq": {seq}, "value_mm": 0.0}}"#),
                "confirm_clear" => format!(r#"{{"command": "confirm_clear", "seq": {seq}}}"#),
                c => format!(r#"{{"command": "{c}"}}"#),
            };
            let (code, v) = command(&s, id, &body);
            let row = format!("{at:?} × {cmd}: {code} {v}");
            match want {
                Yes(state) => {
                    assert_eq!(code, 200, "{row}");
                    assert_eq!(v["state"], state, "{row}");
                }
                No(why) => {
                    assert_eq!(code, 409, "{row}");
                    let e = v["error"].as_str().expect("error");
                    assert!(e.contains(why), "{row}: `{why}` missing");
                }
            }
            if matches!((at, *cmd), (AbortedArmed, "resume" | "reregister")) {
                // the resume acts: the engine prepares the cell and asks for the next reading
                question(&s, id);
            }
            abort_and_unload(&s, id);
        }
    }
    // a done campaign: nothing loads or moves; the stops answer its true state
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 20, 14);
    let s = start(&cfg, &dir.path().join("c.db"));
    let id = super::serve::create(&s, "{}");
    super::serve::arm_and_start(&s, id);
    wait_view(&s, id, "done", |v| {
        v["state"] == "done" && v["loaded"] == false
    });
    for (cmd, want) in commands.iter().zip([
        No("is done"),
        Yes("done"),
        No("is done"),
        No("not loaded"),
        No("is done"),
        No("not loaded"),
        Yes("done"),
        No("not loaded"),
        No("not loaded"),
    ]) {
        let body = match *cmd {
            "answer" => r#"{"command": "answer", "seq": 1, "value_mm": 0.0}"#.to_owned(),
            "confirm_clear" => r#"{"command": "confirm_clear", "seq": 1}"#.to_owned(),
            c => format!(r#"{{"command": "{c}"}}"#),
        };
        let (code, v) = command(&s, id, &body);
        let row = format!("done × {cmd}: {code} {v}");
        match want {
            Yes(state) => assert_eq!((code, v["state"].as_str()), (200, Some(state)), "{row}"),
            No(why) => {
                assert_eq!(code, 409, "{row}");
                assert!(v["error"].as_str().expect("error").contains(why), "{row}");
            }
        }
        assert_eq!(view(&s, id)["loaded"], false, "{row}");
    }
}

/// `resume` of an aborted campaign over REST (after arm) resumes it as `cellcal run --campaign
/// N --arm` does: the tracker frame is checked again at the start, the poses measured before
/// the abort are kept, and the campaign ends done with every pose.
#[test]
fn resume_of_an_aborted_campaign_measures_it_to_the_end() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    let s = start(&cfg, &dir.path().join("c.db"));
    let id = super::serve::create(&s, "{}");
    super::serve::arm_and_start(&s, id);
    wait_view(&s, id, "measuring", |v| v["poses_done"].as_u64() >= Some(3));
    abort_and_unload(&s, id);
    let kept = view(&s, id)["poses_done"].as_u64().expect("done");
    assert!(kept < 300, "finished before the abort");
    let (code, v) = command(&s, id, r#"{"command": "resume"}"#);
    assert_eq!(code, 409, "{v}");
    assert!(
        v["error"]
            .as_str()
            .expect("error")
            .contains("arm it, then resume"),
        "{v}"
    );
    let (code, v) = command(&s, id, r#"{"command": "arm"}"#);
    assert_eq!((code, v["state"].as_str()), (200, Some("armed")), "{v}");
    let (code, v) = command(&s, id, r#"{"command": "resume"}"#);
    assert_eq!(code, 200, "{v}");
    assert_ne!(v["state"], "armed", "the resume did nothing: {v}");
    let v = wait_view(&s, id, "done", |v| v["state"] == "done");
    assert_eq!(v["poses_done"], 300, "{v}");
    let (_, journal) = get(&s, &format!("/api/campaigns/{id}/events"));
    let text = journal.to_string();
    assert!(
        text.contains(&format!("resuming: {kept} of 300 poses already measured")),
        "{text}"
    );
}

/// `pause` while a technician question is open answers at once (it used to wait 5 s for a
/// state change that needs the technician): `running` with `pausing`, the question still open.
/// The question's fate: it stays open and is answered as usual; the campaign pauses at the
/// next pause point (before the next pose or setup target) after that answer.
#[test]
fn pause_during_an_open_question_answers_at_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "manual", 20, 14);
    let s = start(&cfg, &dir.path().join("c.db"));
    let id = bring(&s, At::Running);
    let q = question(&s, id);
    let asked = Instant::now();
    let (code, v) = command(&s, id, r#"{"command": "pause"}"#);
    let took = asked.elapsed();
    assert_eq!(code, 200, "{v}");
    assert!(
        took < Duration::from_secs(1),
        "pause answered after {took:?}"
    );
    assert_eq!(v["state"], "running", "{v}");
    assert_eq!(v["pausing"], true, "{v}");
    assert_eq!(
        v["prompt"]["seq"], q["seq"],
        "the question was withdrawn: {v}"
    );
    std::thread::sleep(Duration::from_millis(300));
    let v = view(&s, id);
    assert_eq!(
        v["prompt"]["seq"], q["seq"],
        "the question was withdrawn: {v}"
    );
    let v = answer_until(&s, id, "paused");
    assert_eq!(v["pausing"], false, "{v}");
    assert!(v["prompt"].is_null(), "{v}");
}

/// The campaign's stored `setup` points (read beside the running daemon).
fn setup_points(store: &std::path::Path, id: i64) -> usize {
    let r = cellcal::store::Store::open_reader(store).expect("reader");
    r.point_count(id, cellcal::store::PointKind::Setup)
        .expect("count")
}

/// Answer the setup's questions until the engine asks for something after the setup (the
/// drift reference); how many stage readings it asked for during the setup.
fn answer_the_setup(s: &Server, id: i64) -> usize {
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut readings = 0;
    loop {
        assert!(
            Instant::now() < deadline,
            "setup never ended: {}",
            view(s, id)
        );
        let q = question(s, id);
        if q["step"] != "setup" {
            return readings;
        }
        if q["id"] == "stage_move" {
            readings += 1;
        }
        let (code, e) = answer(s, id, &q);
        assert_eq!(code, 200, "{e}");
        // until the engine has taken the answer (the next question replaces this one)
        wait_view(s, id, "past the question", |v| {
            v["prompt"]["seq"] != q["seq"]
        });
    }
}

/// Readings a technician typed during the setup survive an abort and a resume: each setup
/// point was stored when taken; the resumed setup reuses them (one reading at P1 is taken again
/// to check the tracker frame unmoved), so they are not asked again, and the setup result is
/// computed from them (no setup point is stored twice).
#[test]
fn setup_readings_survive_a_resume() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "manual", 20, 14);
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    // the reference: one setup without interruption
    let reference = super::serve::create(&s, "{}");
    super::serve::arm_and_start(&s, reference);
    let all = answer_the_setup(&s, reference);
    let all_points = setup_points(&store, reference);
    abort_and_unload(&s, reference);
    assert!(all >= 4, "{all} setup readings");

    // some readings typed, then aborted at the P1 question of a new target
    let id = super::serve::create(&s, "{}");
    super::serve::arm_and_start(&s, id);
    let mut typed = 0;
    loop {
        let q = question(&s, id);
        if typed >= all / 2 && q["id"] == "stage_move" && q["position"] == "P1" {
            break;
        }
        if q["id"] == "stage_move" {
            typed += 1;
        }
        assert_eq!(answer(&s, id, &q).0, 200);
        wait_view(&s, id, "past the question", |v| {
            v["prompt"]["seq"] != q["seq"]
        });
    }
    abort_and_unload(&s, id);
    let kept = setup_points(&store, id);
    assert!(
        kept >= typed,
        "{kept} setup points stored for {typed} readings"
    );

    // resumed: the typed readings are not asked again
    for c in ["arm", "resume"] {
        let (code, v) = command(&s, id, &format!(r#"{{"command": "{c}"}}"#));
        assert_eq!(code, 200, "{c}: {v}");
    }
    let again = answer_the_setup(&s, id);
    assert!(
        again <= all - typed + 1,
        "{again} readings asked after the resume; {typed} of {all} were typed before"
    );
    // … and the setup used them: every setup point stored once, as in the reference
    assert_eq!(setup_points(&store, id), all_points);
    let (_, journal) = get(&s, &format!("/api/campaigns/{id}/events"));
    let text = journal.to_string();
    assert!(
        text.contains(&format!("setup: {kept} points taken before are reused")),
        "{text}"
    );
    let setups: Vec<&Value> = journal
        .as_array()
        .expect("journal")
        .iter()
        .filter(|e| e["kind"] == "setup")
        .collect();
    assert_eq!(setups.len(), 1, "{setups:?}");
    let targets = &setups[0]["event"]["result"]["tool_frame"]["targets"];
    assert!(targets.as_u64() > Some(0), "{setups:?}");
    abort_and_unload(&s, id);
}
