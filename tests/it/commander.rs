//! One commander per cell, roles that hold on loading, truthful states: the real binaries
//! (`run --arm`, `serve`) on real store files, each test with its own lock directory (the
//! configuration's `lock_dir`).

use std::io::{BufRead, BufReader, Read};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::serve::{
    fast_config, get, post, post_as, role_tokens, start, start_as_operator, wait_for_state, Server,
};
use cellcal::store::Store;

/// `fast_config` with its own lock directory (`dir/locks`) and `extra` appended.
fn config(dir: &Path, poses: usize, ident: usize, extra: &str) -> PathBuf {
    let cfg = fast_config(dir, "serial", poses, ident);
    let text = std::fs::read_to_string(&cfg).expect("config");
    let locks = dir.join("locks");
    let text = text.replacen(
        "store = ",
        &format!("lock_dir = \"{}\"\nstore = ", locks.display()),
        1,
    ) + extra;
    std::fs::write(&cfg, text).expect("write config");
    cfg
}

/// `cellcal run --arm` on `cfg` and `store` (no terminal: faults fail the run).
fn run_arm(cfg: &Path, store: &Path, extra: &[&str]) -> Child {
    Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
        .args(["run", "--arm", "--quiet", "--on-fault", "fail", "--config"])
        .arg(cfg)
        .arg("--store")
        .arg(store)
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn cellcal run")
}

/// Wait (≤ 60 s) until `child` exits: its code and stderr.
fn finish(mut child: Child) -> (Option<i32>, String) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while child.try_wait().expect("try_wait").is_none() {
        assert!(Instant::now() < deadline, "the process never ended");
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut err = String::new();
    if let Some(mut e) = child.stderr.take() {
        e.read_to_string(&mut err).expect("stderr");
    }
    (child.wait().expect("wait").code(), err)
}

fn terminate(child: &Child) {
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
}

fn campaigns(store: &Path) -> Vec<cellcal::store::CampaignRow> {
    Store::open_reader(store)
        .expect("reader")
        .list_campaigns()
        .expect("list")
}

/// Wait until campaign `id`'s engine has ended (`loaded: false`).
fn wait_unloaded(s: &Server, id: i64) -> Value {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (_, v) = get(s, &format!("/api/campaigns/{id}"));
        if v["loaded"] == false {
            return v;
        }
        assert!(Instant::now() < deadline, "never unloaded: {v}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn journal_text(s: &Server, id: i64) -> String {
    let (code, v) = get(s, &format!("/api/campaigns/{id}/events"));
    assert_eq!(code, 200, "{v}");
    v.to_string()
}

#[test]
fn two_run_arm_started_together_on_one_store_one_is_refused_naming_the_other() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config(dir.path(), 300, 100, "");
    let store = dir.path().join("c.db");
    let mut a = run_arm(&cfg, &store, &[]);
    let mut b = run_arm(&cfg, &store, &[]);
    let deadline = Instant::now() + Duration::from_secs(60);
    let (loser, winner) = loop {
        if a.try_wait().expect("try_wait").is_some() {
            break (a, b);
        }
        if b.try_wait().expect("try_wait").is_some() {
            break (b, a);
        }
        assert!(Instant::now() < deadline, "neither was refused");
        std::thread::sleep(Duration::from_millis(10));
    };
    let winner_pid = winner.id();
    let (code, err) = finish(loser);
    assert_eq!(code, Some(2), "the second commander is refused: {err}");
    assert!(
        err.contains("commanded by") && err.contains(&format!("pid {winner_pid} ")),
        "names the holder: {err}"
    );
    // the first measures on, until stopped
    wait_for_a_pose(&store);
    terminate(&winner);
    let (won, err) = finish(winner);
    assert!(matches!(won, Some(0 | 143)), "{won:?}: {err}");
    assert_eq!(
        campaigns(&store).len(),
        1,
        "refused before anything was planned or stored"
    );
}

#[test]
fn run_arm_is_refused_while_serve_runs_a_campaign_on_its_store() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config(dir.path(), 300, 100, "");
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let commands = format!("/api/campaigns/{id}/commands");
    assert_eq!(post(&s, &commands, r#"{"command": "arm"}"#).0, 200);
    assert_eq!(post(&s, &commands, r#"{"command": "start"}"#).0, 200);
    wait_for_state(&s, id, "running");
    let (code, err) = finish(run_arm(&cfg, &store, &[]));
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains(&format!("pid {} ", s.pid())) && err.contains(&format!("campaign {id},")),
        "names the daemon and its campaign: {err}"
    );
    // resuming the daemon's campaign from a second process is refused the same way
    let (code, err) = finish(run_arm(&cfg, &store, &["--campaign", &id.to_string()]));
    assert_eq!(code, Some(2), "{err}");
    assert_eq!(campaigns(&store).len(), 1, "nothing planned or stored");
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["state"], "running", "the daemon's campaign runs on: {v}");
    assert_eq!(post(&s, &commands, r#"{"command": "abort"}"#).0, 200);
}

#[test]
fn two_stores_whose_configs_name_one_robot_address_share_one_cell() {
    let dir = tempfile::tempdir().expect("tempdir");
    // nothing listens there: holding the cell needs no connection
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("addr")
        .port();
    let real_robot = |text: String| {
        text.replacen(
            "[robot_controller]\nmode = \"sim\"",
            &super::common::real_controller(dir.path(), format!("127.0.0.1:{port}")),
            1,
        )
    };
    let (da, db) = (dir.path().join("a"), dir.path().join("b"));
    let mut cfgs = Vec::new();
    for d in [&da, &db] {
        std::fs::create_dir_all(d).expect("mkdir");
        let cfg = config(d, 20, 14, "");
        let text = real_robot(std::fs::read_to_string(&cfg).expect("config"));
        // one host-wide lock directory for both cells
        let text = text.replace(
            &format!("lock_dir = \"{}\"", d.join("locks").display()),
            &format!("lock_dir = \"{}\"", dir.path().join("locks").display()),
        );
        assert!(text.contains("mode = \"real\""), "the robot is real");
        std::fs::write(&cfg, text).expect("write");
        cfgs.push(cfg);
    }
    let s = start(&cfgs[0], &da.join("a.db"));
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let (code, err) = finish(run_arm(&cfgs[1], &db.join("b.db"), &[]));
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains(&format!("robot controller 127.0.0.1:{port}"))
            && err.contains(&format!("pid {} ", s.pid()))
            && err.contains(&format!("campaign {id},")),
        "names the cell and its holder: {err}"
    );
    assert!(
        campaigns(&db.join("b.db")).is_empty(),
        "refused before anything was stored"
    );
}

/// The campaign of the first `run --arm` on `store`: poll until it has measured a pose.
fn wait_for_a_pose(store: &Path) -> i64 {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Ok(r) = Store::open_reader(store) {
            if let Some(c) = r.list_campaigns().expect("list").first() {
                if r.pose_counts(c.id).expect("counts").0 > 0 {
                    return c.id;
                }
            }
        }
        assert!(Instant::now() < deadline, "no pose measured");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_commander_killed_mid_run_leaves_an_interrupted_campaign_and_a_cell_taken_over() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config(dir.path(), 300, 100, "");
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    let mut run = run_arm(&cfg, &store, &[]);
    let id = wait_for_a_pose(&store);
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["state"], "running", "a live holder's state is shown: {v}");
    // the daemon may not command the cell `run` commands
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 409, "{v}");
    let msg = v["error"].as_str().expect("error");
    assert!(msg.contains(&format!("pid {} ", run.id())), "{msg}");
    // kill -9: no clean-up at all
    run.kill().expect("kill");
    run.wait().expect("wait");
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["state"], "interrupted", "its process is gone: {v}");
    let (_, list) = get(&s, "/api/campaigns");
    assert_eq!(list[0]["state"], "interrupted", "{list}");
    // ABORT on it answers its true state; nothing is loaded
    let commands = format!("/api/campaigns/{id}/commands");
    let (code, v) = post(&s, &commands, r#"{"command": "abort"}"#);
    assert_eq!(
        (code, v["state"].clone()),
        (200, "interrupted".into()),
        "{v}"
    );
    drop(s);
    // a daemon started now marks it interrupted in the store and journals why
    let s = start(&cfg, &store);
    assert_eq!(campaigns(&store)[0].state, "interrupted");
    assert!(
        journal_text(&s, id).contains("interrupted: stored `running`"),
        "journalled"
    );
    // resuming it takes over the cell the dead process held, and journals that
    let (code, v) = post(&s, &commands, r#"{"command": "arm"}"#);
    assert_eq!(code, 200, "{v}");
    let journal = journal_text(&s, id);
    assert!(
        journal.contains("took over the cell (simulated cell of store")
            && journal.contains("which died holding it"),
        "the takeover is journalled: {journal}"
    );
    assert_eq!(post(&s, &commands, r#"{"command": "abort"}"#).0, 200);
}

/// A daemon with role tokens on a small campaign (`dir/locks` its lock directory).
fn server_with_roles(dir: &Path) -> (Server, PathBuf) {
    let cfg = config(dir, 20, 14, &role_tokens());
    let store = dir.join("c.db");
    (start_as_operator(&cfg, &store), store)
}

#[test]
fn only_an_operator_loads_a_stored_campaign() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (s, store) = server_with_roles(dir.path());
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let commands = format!("/api/campaigns/{id}/commands");
    let (code, v) = post(&s, &commands, r#"{"command": "abort"}"#);
    assert_eq!((code, v["state"].clone()), (200, "aborted".into()), "{v}");
    wait_unloaded(&s, id);
    let before = get(&s, "/api/devices").1;
    // a technician's pause, or an answer with a wrong seq, on the stored campaign: refused
    for body in [
        r#"{"command": "pause"}"#,
        r#"{"command": "answer", "seq": 99, "value_mm": 1.0}"#,
    ] {
        let (code, v) = post_as(&s, "technician-token", &commands, body);
        assert_eq!(code, 409, "{body}: {v}");
        assert!(
            v["error"].as_str().expect("error").contains("not loaded"),
            "{v}"
        );
    }
    // … and nothing changed: state, lock, devices; the operator's create goes through
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(
        (v["state"].clone(), v["loaded"].clone()),
        ("aborted".into(), false.into())
    );
    assert_eq!(
        Store::open_reader(&store)
            .expect("reader")
            .campaign_holder(id)
            .expect("holder"),
        None
    );
    assert_eq!(get(&s, "/api/devices").1, before);
    let (code, v) = post(&s, "/api/campaigns", "{}");
    assert_eq!(code, 201, "the operator's create is not blocked: {v}");
    let loaded = v["id"].as_i64().expect("id");
    // an abort addressed to the stored campaign names the loaded one
    let (code, v) = post_as(&s, "viewer-token", &commands, r#"{"command": "abort"}"#);
    assert_eq!(code, 409, "{v}");
    let msg = v["error"].as_str().expect("error");
    assert!(
        msg.contains(&format!("campaign {loaded} is the loaded one")),
        "{msg}"
    );
    // a reregister is for the resume of a paused campaign: not remembered while idle
    let loaded_commands = format!("/api/campaigns/{loaded}/commands");
    assert_eq!(post(&s, &loaded_commands, r#"{"command": "arm"}"#).0, 200);
    let (code, v) = post(&s, &loaded_commands, r#"{"command": "reregister"}"#);
    assert_eq!(code, 409, "{v}");
    assert_eq!(post(&s, &loaded_commands, r#"{"command": "abort"}"#).0, 200);
}

#[test]
fn a_campaign_created_with_overrides_resumes_with_its_own_plan() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config(dir.path(), 300, 100, "");
    let s = start(&cfg, &dir.path().join("c.db"));
    let (code, v) = post(&s, "/api/campaigns", r#"{"poses": 3000, "ident": 1000}"#);
    assert_eq!(code, 201, "{v}");
    let id = v["id"].as_i64().expect("id");
    let commands = format!("/api/campaigns/{id}/commands");
    let plan = get(&s, &format!("/api/campaigns/{id}/plan")).1;
    let (code, v) = post(&s, &commands, r#"{"command": "abort"}"#);
    assert_eq!(
        (code, v["state"].clone(), v["loaded"].clone()),
        (200, "aborted".into(), false.into()),
        "an abort answers once the run has ended: {v}"
    );
    let (code, v) = post(&s, &commands, r#"{"command": "arm"}"#);
    assert_eq!(
        (code, v["armed"].clone()),
        (200, true.into()),
        "resumed: {v}"
    );
    assert_eq!(get(&s, &format!("/api/campaigns/{id}/plan")).1, plan);
    assert_eq!(post(&s, &commands, r#"{"command": "abort"}"#).0, 200);
}

#[test]
fn store_files_are_created_private_whatever_the_umask() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config(dir.path(), 20, 14, "");
    let store = dir.path().join("c.db");
    let mut child = Command::new("sh")
        .args(["-c", "umask 000 && exec \"$0\" \"$@\""])
        .arg(assert_cmd::cargo::cargo_bin("cellcal"))
        .args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("first line");
    assert!(line.starts_with("listening on"), "{line}");
    let modes: Vec<(String, u32)> = ["c.db", "c.db-wal", "c.db-shm"]
        .iter()
        .map(|n| {
            let m = std::fs::metadata(dir.path().join(n))
                .unwrap_or_else(|e| panic!("{n}: {e}"))
                .permissions()
                .mode();
            (n.to_string(), m & 0o777)
        })
        .collect();
    let _ = child.kill();
    let _ = child.wait();
    for (n, m) in modes {
        assert_eq!(m, 0o600, "{n} is {m:o}");
    }
}

/// A request's overrides are the campaign's own: written into the configuration it stores (so
/// `identify --store`, the report and the export read them back) and kept by a resume, which
/// the configuration file's other values do not change.
#[test]
fn a_campaigns_overridden_model_and_terms_are_stored_with_it_and_kept_on_resume() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config(dir.path(), 300, 100, "");
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    let body = r#"{"poses": 3000, "ident": 1000, "model": "position",
                   "nongeometric": ["harmonics"]}"#;
    let (code, v) = post(&s, "/api/campaigns", body);
    assert_eq!(code, 201, "{v}");
    assert_eq!(v["model"], "position", "{v}");
    let id = v["id"].as_i64().expect("id");
    let row = Store::open_reader(&store)
        .expect("store")
        .campaign(id)
        .expect("row");
    let stored = cellcal::config::parse_cell_config(&row.config_toml, Path::new("stored"))
        .expect("the stored configuration parses");
    assert_eq!((stored.campaign.poses, stored.campaign.ident), (3000, 1000));
    assert_eq!(stored.campaign.model, cellcal::identify::ObsModel::Position);
    assert_eq!(
        stored.campaign.nongeometric,
        [cellcal::model::TermFamily::Harmonics]
    );
    let commands = format!("/api/campaigns/{id}/commands");
    assert_eq!(post(&s, &commands, r#"{"command": "abort"}"#).0, 200);
    // resumed by the daemon of the unchanged file: no "changed configuration", its own model
    let (code, v) = post(&s, &commands, r#"{"command": "arm"}"#);
    assert_eq!((code, v["armed"].clone()), (200, true.into()), "{v}");
    assert_eq!(v["model"], "position", "{v}");
    assert_eq!(post(&s, &commands, r#"{"command": "abort"}"#).0, 200);
}
