//! `cellcal serve`: the real binary driven over its REST API the way an operator's client and a
//! technician's page would: bad requests, a whole campaign with the live event stream, technician
//! questions answered over HTTP, and a clean stop on SIGTERM.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::campaign::{config_text, write_config};
use cellcal::store::Store;

struct Server {
    child: Child,
    base: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start(cfg: &Path, store: &Path) -> Server {
    start_with_env(cfg, store, &[])
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(30)))
        .build()
        .into()
}

fn get(s: &Server, path: &str) -> (u16, Value) {
    let mut r = agent()
        .get(&format!("{}{path}", s.base))
        .call()
        .expect("GET");
    let status = r.status().as_u16();
    (status, r.body_mut().read_json().expect("JSON body"))
}

fn post(s: &Server, path: &str, body: &str) -> (u16, Value) {
    let mut r = agent()
        .post(&format!("{}{path}", s.base))
        .header("content-type", "application/json")
        .send(body)
        .expect("POST");
    let status = r.status().as_u16();
    (status, r.body_mut().read_json().expect("JSON body"))
}

fn wait_for_state(s: &Server, id: i64, want: &str) -> Value {
    let deadline = Instant::now() + Duration::from_secs(90);
    loop {
        let (code, v) = get(s, &format!("/api/campaigns/{id}"));
        assert_eq!(code, 200, "{v}");
        if v["state"] == want {
            return v;
        }
        assert!(Instant::now() < deadline, "state never became {want}: {v}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn fast_config(dir: &Path, stage_kind: &str, poses: usize, ident: usize) -> std::path::PathBuf {
    let text = config_text("", "", "")
        .replace("kind = \"serial\"", &format!("kind = \"{stage_kind}\""))
        .replace("poses = 300", &format!("poses = {poses}"))
        .replace("ident = 100", &format!("ident = {ident}"));
    write_config(dir, &text)
}

#[test]
fn the_daemon_runs_a_campaign_over_rest_with_live_events() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    let (code, v) = get(&s, "/api/health");
    assert_eq!((code, v["ok"].clone()), (200, Value::Bool(true)));

    // bad requests: a clear error, nothing created
    for (body, want) in [
        (r#"{"poses": 40, "sneaky": 1}"#, "sneaky"),
        (r#"{"poses": 10, "ident": 10}"#, "ident"),
        (r#"{"model": "xyz"}"#, "model"),
        // infeasible: the feasibility checks of `cellcal run`, before anything is stored
        (r#"{"model": "full"}"#, "campaign.model: full needs"),
        (
            r#"{"poses": 40, "ident": 10}"#,
            "campaign.ident: 10 identification poses",
        ),
        (r#"{"poses": "many"}"#, "poses"),
        ("{", "EOF"),
    ] {
        let (code, v) = post(&s, "/api/campaigns", body);
        assert_eq!(code, 400, "{body}: {v}");
        let msg = v["error"].as_str().expect("error message");
        assert!(msg.contains(want), "{body}: {msg}");
    }
    assert_eq!(get(&s, "/api/campaigns").1, Value::Array(vec![]));
    assert_eq!(get(&s, "/api/campaigns/7").0, 404);

    let (code, v) = post(&s, "/api/campaigns", r#"{"poses": 60, "ident": 30}"#);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    assert_eq!(v["poses_total"], 60);
    assert_eq!(v["loaded"], true);
    // one cell, one loaded campaign
    assert_eq!(post(&s, "/api/campaigns", "{}").0, 409);
    let (code, v) = post(
        &s,
        &format!("/api/campaigns/{id}/commands"),
        r#"{"command": "fly"}"#,
    );
    assert_eq!(code, 400, "{v}");

    // start without arm: refused and forgotten, so a later arm alone moves nothing
    let path = format!("/api/campaigns/{id}/commands");
    let (code, v) = post(&s, &path, r#"{"command": "start"}"#);
    assert_eq!(code, 409, "{v}");
    assert!(
        v["error"].as_str().expect("error").contains("not armed"),
        "{v}"
    );
    let (code, v) = post(&s, &path, r#"{"command": "arm"}"#);
    assert_eq!(code, 200, "{v}");
    std::thread::sleep(Duration::from_millis(300));
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["poses_done"], 0, "{v}");
    assert_eq!(v["armed"], true, "{v}");
    assert_eq!(v["state"], "armed", "{v}");

    // live events, read like a browser's EventSource
    let url = format!("{}/api/campaigns/{id}/stream", s.base);
    let reader = std::thread::spawn(move || {
        let r = agent().get(&url).call().expect("stream");
        let mut kinds = Vec::new();
        for line in BufReader::new(r.into_body().into_reader()).lines() {
            let line = line.expect("line");
            if let Some(k) = line.strip_prefix("event: ") {
                kinds.push(k.to_owned());
            }
            if line.starts_with("data: ") && line.contains(r#""state":"done""#) {
                break;
            }
        }
        kinds
    });
    std::thread::sleep(Duration::from_millis(200));
    let (code, v) = post(&s, &path, r#"{"command": "start"}"#);
    assert_eq!(code, 200, "{v}");
    let v = wait_for_state(&s, id, "done");
    assert_eq!(v["poses_done"], 60);
    assert_eq!(v["has_result"], true);
    let kinds = reader.join().expect("stream reader");
    assert_eq!(
        kinds.iter().filter(|k| *k == "measured").count(),
        60,
        "{kinds:?}"
    );
    assert!(kinds.contains(&"result".to_owned()), "{kinds:?}");

    let (code, result) = get(&s, &format!("/api/campaigns/{id}/result"));
    assert_eq!(code, 200);
    assert_eq!(result["model"], "op");
    let after = result["metrics"]["verify"]["after"]["position_mean_mm"]
        .as_f64()
        .expect("verify after");
    let before = result["metrics"]["verify"]["before"]["position_mean_mm"]
        .as_f64()
        .expect("verify before");
    assert!(after < 0.1 * before, "after {after} mm, before {before} mm");
    let (_, journal) = get(&s, &format!("/api/campaigns/{id}/events"));
    let states: Vec<&Value> = journal
        .as_array()
        .expect("journal")
        .iter()
        .filter(|e| e["kind"] == "state")
        .map(|e| &e["event"]["state"]["state"])
        .collect();
    assert_eq!(
        states.last().map(|v| v.as_str()),
        Some(Some("done")),
        "{states:?}"
    );

    // a done campaign cannot be armed, started or resumed again: nothing moves, no new result
    for cmd in ["arm", "start", "resume"] {
        let (code, v) = post(&s, &path, &format!(r#"{{"command": "{cmd}"}}"#));
        assert_eq!(code, 409, "{cmd}: {v}");
        assert!(
            v["error"].as_str().expect("error").contains("is done"),
            "{v}"
        );
    }
    assert_eq!(get(&s, &format!("/api/campaigns/{id}")).1["state"], "done");

    // the cell is free again; SIGTERM aborts the new (idle) campaign and exits cleanly
    let (code, v) = post(&s, "/api/campaigns", "");
    assert_eq!(code, 201, "{v}");
    let second = v["id"].as_i64().expect("id");
    let mut s = s;
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(s.child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .expect("SIGTERM");
    let status = s.child.wait().expect("wait");
    assert!(status.success(), "{status:?}");
    let st = Store::open(&store).expect("store");
    assert_eq!(st.campaign(second).expect("row").state, "aborted");
}

#[test]
fn technician_questions_are_answered_over_rest() {
    let dir = tempfile::tempdir().expect("tempdir");
    // 14 ident poses × 6 equations ≥ 3 × 28 parameters (OP with base): the fewest create accepts
    let cfg = fast_config(dir.path(), "manual", 20, 14);
    let s = start(&cfg, &dir.path().join("c.db"));
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let path = format!("/api/campaigns/{id}/commands");
    post(&s, &path, r#"{"command": "arm"}"#);
    post(&s, &path, r#"{"command": "start"}"#);
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut answered = 0;
    let mut checked_bad = false;
    loop {
        let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
        if v["state"] == "done" {
            assert_eq!(v["poses_done"], 20);
            break;
        }
        assert!(Instant::now() < deadline, "campaign stuck: {v}");
        if let Some(q) = v["prompt"].as_object() {
            let seq = q["seq"].as_u64().expect("seq");
            let want = q["expected_mm"].as_f64().expect("a reading is asked for");
            assert!(q["text"]
                .as_str()
                .expect("text")
                .contains("Set the micrometer"));
            if !checked_bad {
                // a stale question number and a non-number are refused, the question stays
                let (code, e) = post(
                    &s,
                    &path,
                    &format!(
                        r#"{{"command": "answer", "seq": {}, "value_mm": 1.0}}"#,
                        seq + 5
                    ),
                );
                assert_eq!(code, 409, "{e}");
                let (code, e) = post(
                    &s,
                    &path,
                    &format!(r#"{{"command": "answer", "seq": {seq}, "value_mm": "ten"}}"#),
                );
                assert_eq!(code, 400, "{e}");
                checked_bad = true;
            }
            let (code, e) = post(
                &s,
                &path,
                &format!(r#"{{"command": "answer", "seq": {seq}, "value_mm": {want}}}"#),
            );
            assert_eq!(code, 200, "{e}");
            answered += 1;
        } else {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    // one question for the drift reference at start, two per pose, and the P1 of each drift check
    assert!(answered >= 41, "{answered} questions answered");
    let (code, _) = get(&s, &format!("/api/campaigns/{id}/result"));
    assert_eq!(code, 200);
}

/// Create a campaign with `body`; its id.
fn create(s: &Server, body: &str) -> i64 {
    let (code, v) = post(s, "/api/campaigns", body);
    assert_eq!(code, 201, "{v}");
    v["id"].as_i64().expect("id")
}

/// Arm and start campaign `id`.
fn arm_and_start(s: &Server, id: i64) {
    let path = format!("/api/campaigns/{id}/commands");
    for c in ["arm", "start"] {
        let (code, v) = post(s, &path, &format!(r#"{{"command": "{c}"}}"#));
        assert_eq!(code, 200, "{c}: {v}");
    }
}

fn start_with_env(cfg: &Path, store: &Path, env: &[(&str, &str)]) -> Server {
    let mut cmd = Command::new(assert_cmd::cargo::cargo_bin("cellcal"));
    cmd.args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(cfg)
        .arg("--store")
        .arg(store)
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    let mut child = cmd.spawn().expect("spawn cellcal serve");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("first line");
    let base = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("first line: {line}"))
        .to_owned();
    Server { child, base }
}

/// One Server-Sent Event as a client sees it.
#[derive(Debug, Clone, PartialEq)]
struct Sse {
    id: Option<i64>,
    kind: String,
    data: Value,
}

/// What a stream delivered: its events, its comments, and whether the server ended it.
#[derive(Debug, Default)]
struct Streamed {
    events: Vec<Sse>,
    comments: Vec<String>,
    ended: bool,
}

/// Read a stream until the server ends it or `stop` says so after an event; `pause` between
/// lines makes a slow client.
fn read_stream(
    url: &str,
    last_event_id: Option<i64>,
    pause: Duration,
    mut stop: impl FnMut(&[Sse]) -> bool,
) -> Streamed {
    let mut req = agent_long().get(url);
    if let Some(id) = last_event_id {
        req = req.header("Last-Event-ID", &id.to_string());
    }
    let r = req.call().expect("stream");
    assert_eq!(r.status().as_u16(), 200);
    let mut out = Streamed::default();
    let (mut id, mut kind, mut data) = (None, String::new(), String::new());
    for line in BufReader::new(r.into_body().into_reader()).lines() {
        let line = line.expect("line");
        if !pause.is_zero() {
            std::thread::sleep(pause);
        }
        if let Some(c) = line.strip_prefix(':') {
            out.comments.push(c.trim().to_owned());
        } else if let Some(v) = line.strip_prefix("id: ") {
            id = Some(v.parse().expect("numeric id"));
        } else if let Some(v) = line.strip_prefix("event: ") {
            kind = v.to_owned();
        } else if let Some(v) = line.strip_prefix("data: ") {
            data = v.to_owned();
        } else if line.is_empty() && !kind.is_empty() {
            out.events.push(Sse {
                id: id.take(),
                kind: std::mem::take(&mut kind),
                data: serde_json::from_str(&std::mem::take(&mut data)).expect("JSON data"),
            });
            if stop(&out.events) {
                return out;
            }
        }
    }
    out.ended = true;
    out
}

fn agent_long() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(300)))
        .build()
        .into()
}

/// Run `f` on a thread; panic if it does not finish within `limit`.
fn within<T: Send + 'static>(
    limit: Duration,
    what: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(limit)
        .unwrap_or_else(|_| panic!("{what}: not finished within {limit:?}"))
}

fn ids(events: &[Sse]) -> Vec<i64> {
    events
        .iter()
        .map(|e| e.id.expect("every event has an id"))
        .collect()
}

fn journal_seqs(s: &Server, id: i64) -> Vec<i64> {
    let (code, journal) = get(s, &format!("/api/campaigns/{id}/events"));
    assert_eq!(code, 200, "{journal}");
    journal
        .as_array()
        .expect("journal")
        .iter()
        .map(|e| e["seq"].as_i64().expect("seq"))
        .collect()
}

#[test]
fn reads_stay_fast_while_a_30000_pose_campaign_is_planned() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    let s = start(&cfg, &dir.path().join("c.db"));
    // an earlier campaign, aborted: its GET and an abort must not wait for the planning either
    let small = create(&s, r#"{"poses": 20, "ident": 10}"#);
    let abort = format!("/api/campaigns/{small}/commands");
    assert_eq!(post(&s, &abort, r#"{"command": "abort"}"#).0, 200);
    wait_for_state(&s, small, "aborted");
    let deadline = Instant::now() + Duration::from_secs(30);
    while get(&s, &format!("/api/campaigns/{small}")).1["loaded"] == true {
        assert!(Instant::now() < deadline, "campaign {small} stays loaded");
        std::thread::sleep(Duration::from_millis(20));
    }

    let url = format!("{}/api/campaigns", s.base);
    let planning = std::thread::spawn(move || {
        let t0 = Instant::now();
        let mut r = agent_long()
            .post(&url)
            .header("content-type", "application/json")
            .send(r#"{"poses": 30000, "ident": 15000}"#)
            .expect("POST");
        let v: Value = r.body_mut().read_json().expect("JSON");
        (r.status().as_u16(), v, t0.elapsed())
    });
    let paths = [
        "/api/health".to_owned(),
        "/api/campaigns".to_owned(),
        format!("/api/campaigns/{small}"),
    ];
    let mut worst = [Duration::ZERO; 4];
    let mut rounds = 0;
    while !planning.is_finished() {
        for (i, p) in paths.iter().enumerate() {
            let t = Instant::now();
            let (code, v) = get(&s, p);
            worst[i] = worst[i].max(t.elapsed());
            assert_eq!(code, 200, "{p}: {v}");
        }
        let t = Instant::now();
        let (code, v) = post(&s, &abort, r#"{"command": "abort"}"#);
        worst[3] = worst[3].max(t.elapsed());
        assert_eq!(code, 200, "{v}");
        rounds += 1;
        std::thread::sleep(Duration::from_millis(20));
    }
    let (code, v, took) = planning.join().expect("POST thread");
    assert_eq!(code, 201, "{v}");
    assert_eq!(v["poses_total"], 30000);
    eprintln!(
        "30000-pose create took {took:?}; {rounds} rounds; slowest health {:?}, list {:?}, one {:?}, abort {:?}",
        worst[0], worst[1], worst[2], worst[3]
    );
    assert!(rounds >= 5, "only {rounds} rounds during a {took:?} create");
    for (what, w) in ["health", "list", "one campaign", "abort"]
        .iter()
        .zip(worst)
    {
        assert!(
            w < Duration::from_millis(100),
            "{what}: {w:?} during planning"
        );
    }
}

#[test]
fn too_few_identification_poses_are_refused_before_anything_runs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    let s = start(&cfg, &dir.path().join("c.db"));
    // two identification poses cannot determine the OP model: refused at create (the engine's
    // failed-identification path is tested in process: safety::a_failed_identification_*)
    let (code, v) = post(&s, "/api/campaigns", r#"{"poses": 20, "ident": 2}"#);
    assert_eq!(code, 400, "{v}");
    assert!(
        v["error"].as_str().unwrap_or_default().contains("ident"),
        "{v}"
    );
}

#[test]
fn a_lagging_stream_replays_the_gap_from_the_journal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    // a live channel of two events and a follower pausing 20 ms per event: it must lag
    let s = start_with_env(
        &cfg,
        &dir.path().join("c.db"),
        &[
            ("CELLCAL_EVENT_CAPACITY", "2"),
            ("CELLCAL_FOLLOW_PACE_MS", "20"),
        ],
    );
    let id = create(&s, r#"{"poses": 40, "ident": 20}"#);
    let url = format!("{}/api/campaigns/{id}/stream", s.base);
    let reader =
        std::thread::spawn(move || read_stream(&url, None, Duration::from_millis(1), |_| false));
    std::thread::sleep(Duration::from_millis(200));
    arm_and_start(&s, id);
    let streamed = within(Duration::from_secs(120), "the stream", move || {
        reader.join().expect("stream reader")
    });
    assert!(streamed.ended);
    assert!(
        streamed.comments.iter().any(|c| c.starts_with("replayed")),
        "the follower never lagged: {:?}",
        streamed.comments
    );
    let seqs = ids(&streamed.events);
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{seqs:?}");
    let poses: Vec<i64> = streamed
        .events
        .iter()
        .filter(|e| e.kind == "measured")
        .map(|e| e.data["done"].as_i64().expect("done"))
        .collect();
    assert_eq!(poses, (1..=40).collect::<Vec<_>>(), "measured events");
    let last = streamed.events.last().expect("events");
    assert_eq!(last.data["state"]["state"], "done", "{last:?}");
    // nothing the journal has since the stream opened is missing
    let journal = journal_seqs(&s, id);
    let first = seqs[0];
    let want: Vec<i64> = journal.into_iter().filter(|q| *q >= first).collect();
    assert_eq!(seqs, want);
}

#[test]
fn last_event_id_resumes_from_the_journal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    let s = start_with_env(
        &cfg,
        &dir.path().join("c.db"),
        &[("CELLCAL_FOLLOW_PACE_MS", "5")],
    );
    let id = create(&s, r#"{"poses": 30, "ident": 15}"#);
    let url = format!("{}/api/campaigns/{id}/stream", s.base);
    let u = url.clone();
    let first =
        std::thread::spawn(move || read_stream(&u, None, Duration::ZERO, |e| e.len() == 10));
    std::thread::sleep(Duration::from_millis(200));
    arm_and_start(&s, id);
    let first = within(Duration::from_secs(60), "ten events", move || {
        first.join().expect("first reader")
    });
    let tenth = ids(&first.events)[9];
    // reconnect (header) while the campaign runs: the rest, from the next journal entry
    let u = url.clone();
    let rest = within(Duration::from_secs(120), "the resumed stream", move || {
        read_stream(&u, Some(tenth), Duration::ZERO, |_| false)
    });
    assert!(rest.ended);
    wait_for_state(&s, id, "done");
    let journal = journal_seqs(&s, id);
    let after: Vec<i64> = journal.iter().copied().filter(|q| *q > tenth).collect();
    assert_eq!(ids(&rest.events), after, "resumed after {tenth}");
    let measured = |ev: &[Sse]| ev.iter().filter(|e| e.kind == "measured").count();
    assert_eq!(measured(&first.events) + measured(&rest.events), 30);
    // the campaign has ended: the query form replays the journal after the id and ends
    let replay = within(Duration::from_secs(30), "the replay", move || {
        read_stream(
            &format!("{url}?last_event_id={tenth}"),
            None,
            Duration::ZERO,
            |_| false,
        )
    });
    assert!(replay.ended);
    assert_eq!(ids(&replay.events), after);
    // and from the start without an id
    let whole = within(Duration::from_secs(30), "the whole journal", {
        let u = format!("{}/api/campaigns/{id}/stream", s.base);
        move || read_stream(&u, None, Duration::ZERO, |_| false)
    });
    assert_eq!(ids(&whole.events), journal);
    let (code, e) = get(&s, &format!("/api/campaigns/{id}/stream?last_event_id=ten"));
    assert_eq!(code, 400, "{e}");
}
