//! Progress wherever a campaign runs: `cellcal run` with stderr piped (as under nohup or
//! systemd) writes a progress line per measured pose and per state change as they happen, none
//! with `--progress none`; `cellcal serve` logs the same lines per campaign, with its id.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use super::campaign::{config_text, write_config};
use super::common::cellcal_process;
use super::serve::{arm_and_start, create, get, start_logged, wait_for_state};

/// Poses of the campaigns here (identification poses: 20).
const POSES: usize = 30;

/// README command 1's configuration (`config/cell.sim.toml`) with [`POSES`] poses, each point
/// measured for 30 ms (a run of a few seconds), written to `dir`.
fn readme_config(dir: &Path) -> PathBuf {
    let text = config_text("", "", "")
        .replace("poses = 300", &format!("poses = {POSES}"))
        .replace("ident = 100", "ident = 20")
        .replace("measure_ms = 5 ", "measure_ms = 30 ");
    assert!(text.contains("measure_ms = 30 "), "{text}");
    write_config(dir, &text)
}

/// The contract of a pose line after its prefix: `pose n/N set · elapsed D · left ~D · last
/// X.XXX mm · faults F`; returns n.
fn parse_pose_line(line: &str, total: usize) -> usize {
    let parts: Vec<&str> = line.split(" · ").collect();
    assert_eq!(parts.len(), 5, "{line}");
    let head: Vec<&str> = parts[0].split(' ').collect();
    assert_eq!((head.len(), head[0]), (3, "pose"), "{line}");
    let (n, of) = head[1].split_once('/').expect("n/N");
    assert_eq!(of, total.to_string(), "{line}");
    assert!(["ident", "verify"].contains(&head[2]), "{line}");
    let duration = |s: &str| {
        let ok = s.ends_with(" s") || s.ends_with(" min");
        assert!(ok && !s.contains('e'), "duration `{s}`: {line}");
    };
    duration(parts[1].strip_prefix("elapsed ").expect("elapsed"));
    let left = parts[2].strip_prefix("left ").expect("left");
    duration(left.strip_prefix('~').unwrap_or(left));
    let last = parts[3]
        .strip_prefix("last ")
        .and_then(|l| l.strip_suffix(" mm"))
        .expect("last … mm");
    let decimals = last.split_once('.').expect("decimals").1;
    assert_eq!(decimals.len(), 3, "{line}");
    last.parse::<f64>().expect("deviation");
    parts[4]
        .strip_prefix("faults ")
        .and_then(|f| f.parse::<usize>().ok())
        .expect("faults");
    n.parse().expect("n")
}

/// `cellcal run --arm` on `cfg` with stderr piped and `args` added; each stderr line as it
/// arrives, with whether the process was still running when it was read.
fn run_piped(cfg: &Path, store: &Path, args: &[&str]) -> (Vec<(String, bool)>, String, bool) {
    let mut child = cellcal_process()
        .args(["run", "--arm", "--on-fault", "fail", "--config"])
        .arg(cfg)
        .arg("--store")
        .arg(store)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn cellcal run");
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let stdout = child.stdout.take().expect("stdout");
    let out = std::thread::spawn(move || std::io::read_to_string(stdout).expect("stdout"));
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut lines = Vec::new();
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(line) => {
                let running = matches!(child.try_wait(), Ok(None));
                lines.push((line, running));
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {
                assert!(Instant::now() < deadline, "run did not end: {lines:#?}");
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
    let status = child.wait().expect("wait");
    (lines, out.join().expect("stdout"), status.success())
}

#[test]
fn piped_run_prints_progress_as_it_happens() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = readme_config(dir.path());
    // no --progress: stderr is no terminal, so lines
    let (lines, stdout, ok) = run_piped(&cfg, &dir.path().join("c.db"), &[]);
    let text: Vec<&str> = lines.iter().map(|(l, _)| l.as_str()).collect();
    assert!(ok, "{text:#?}");
    let progress: Vec<&str> = text
        .iter()
        .filter_map(|l| l.strip_prefix("progress: "))
        .collect();
    // pose 1 was read while the run went on (written and flushed as it happened)
    let first = lines
        .iter()
        .find(|(l, _)| l.starts_with(&format!("progress: pose 1/{POSES} ")))
        .unwrap_or_else(|| panic!("no line for pose 1: {text:#?}"));
    assert!(
        first.1,
        "pose 1's line arrived only after the run ended: {text:#?}"
    );
    // one line per pose, in order, in the contract's shape
    let poses: Vec<usize> = progress
        .iter()
        .filter(|l| l.starts_with("pose "))
        .map(|l| parse_pose_line(l, POSES))
        .collect();
    assert_eq!(poses, (1..=POSES).collect::<Vec<_>>(), "{text:#?}");
    let last = progress
        .iter()
        .find(|l| l.starts_with(&format!("pose {POSES}/{POSES} ")))
        .expect("last pose");
    assert!(last.contains(" · left 0 s · "), "{last}");
    // the state changes, in order
    let states: Vec<&str> = progress
        .iter()
        .filter(|l| l.starts_with("state ") || l.starts_with("setup measured"))
        .map(|l| l.split(" · ").next().unwrap_or(l))
        .map(|l| l.split(':').next().unwrap_or(l))
        .collect();
    assert_eq!(
        states,
        [
            "state armed",
            "state running",
            "setup measured",
            "state identifying",
            "state done"
        ],
        "{text:#?}"
    );
    // the result still prints
    assert!(stdout.contains("verify"), "{stdout}");
}

#[test]
fn run_with_progress_none_prints_no_progress_line_and_still_the_result() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = readme_config(dir.path());
    let (lines, stdout, ok) = run_piped(&cfg, &dir.path().join("c.db"), &["--progress", "none"]);
    let text: Vec<&str> = lines.iter().map(|(l, _)| l.as_str()).collect();
    assert!(ok, "{text:#?}");
    assert!(
        !text
            .iter()
            .any(|l| l.contains("progress") || l.contains("pose 1/")),
        "{text:#?}"
    );
    assert!(
        text[0].starts_with("campaign 1: 30 poses planned"),
        "{text:#?}"
    );
    assert!(stdout.contains("verify"), "{stdout}");
}

#[test]
fn serve_logs_a_progress_line_per_pose_with_the_campaign_id() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = readme_config(dir.path());
    let store = dir.path().join("c.db");
    let log = dir.path().join("serve.log");
    let s = start_logged(&cfg, &store, &log, &[]);
    let id = create(&s, "{}");
    arm_and_start(&s, id);
    // pose 1's line is in the log while the campaign still runs
    let pose1 = format!("campaign {id} progress: pose 1/{POSES} ");
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let text = std::fs::read_to_string(&log).expect("log");
        if text.contains(&pose1) {
            break;
        }
        assert!(Instant::now() < deadline, "no `{pose1}`: {text}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let (_, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(v["state"], "running", "{v}");
    wait_for_state(&s, id, "done");
    drop(s);
    let text = std::fs::read_to_string(&log).expect("log");
    let prefix = format!("campaign {id} progress: ");
    let ours: Vec<&str> = text
        .lines()
        .filter_map(|l| l.split_once(&prefix).map(|(_, rest)| rest))
        .collect();
    let poses: Vec<usize> = ours
        .iter()
        .filter(|l| l.starts_with("pose "))
        // the text log adds the structured fields after the message
        .map(|l| parse_pose_line(l.rsplit_once(" campaign=").map_or(*l, |(m, _)| m), POSES))
        .collect();
    assert_eq!(poses, (1..=POSES).collect::<Vec<_>>(), "{text}");
    for state in [
        "state armed",
        "state running",
        "state identifying",
        "state done",
    ] {
        assert!(ours.iter().any(|l| l.starts_with(state)), "{state}: {text}");
    }
}
