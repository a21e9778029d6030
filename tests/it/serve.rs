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
    let mut child = Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
        .args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(cfg)
        .arg("--store")
        .arg(store)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn cellcal serve");
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

    // start without arm: nothing moves
    let path = format!("/api/campaigns/{id}/commands");
    assert_eq!(post(&s, &path, r#"{"command": "start"}"#).0, 200);
    std::thread::sleep(Duration::from_millis(300));
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["poses_done"], 0, "{v}");
    assert_eq!(v["armed"], false, "{v}");

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
    let (code, v) = post(&s, &path, r#"{"command": "arm"}"#);
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
