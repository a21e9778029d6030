//! A campaign knows how long it takes (issue 20 item 1, cockpit part): the estimate is stored
//! with the campaign when it is created and the REST view carries it (`estimate`) the same
//! before and after a restart; while and after it runs, the view carries the measuring time
//! (`measuring_s`, in the state `running`, pauses excluded) and the paused time (`paused_s`)
//! from the journal's times; the stored result keeps planned against actual (`campaign_time`),
//! shown by the HTML report and by `cellcal run`'s summary.

use std::time::{Duration, Instant};

use cellcal::campaign::stored::stored_result;
use cellcal::store::Store;
use serde_json::Value;

use super::serve::{arm_and_start, create, fast_config, get, post, start, wait_for_state};

/// The estimate of a view, checked whole: a summary and finite parts that add up.
fn estimate_of(v: &Value) -> Value {
    let e = v["estimate"].clone();
    assert!(e.is_object(), "no estimate in {v}");
    let summary = e["summary"].as_str().expect("summary");
    assert!(
        summary.starts_with(&format!("{} poses, ", v["poses_total"]))
            && (summary.contains("about") || summary.ends_with("under 10 s")),
        "{summary}"
    );
    let part = |k: &str| e[k].as_f64().unwrap_or_else(|| panic!("{k} in {e}"));
    let parts: f64 = ["setup_s", "motion_s", "settle_s", "measure_s", "stage_s"]
        .iter()
        .map(|k| part(k))
        .sum();
    assert!(part("total_s") > 0.0, "{e}");
    assert!(
        (parts - part("total_s")).abs() <= 1e-6 * part("total_s"),
        "{e}"
    );
    e
}

fn seconds(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or_else(|| panic!("{key} in {v}"))
}

#[test]
fn the_estimate_is_stored_and_measuring_excludes_pauses() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 60, 30);
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    let id = create(&s, "{}");
    let (_, before) = get(&s, &format!("/api/campaigns/{id}"));
    let estimate = estimate_of(&before);
    assert_eq!(
        (
            seconds(&before, "measuring_s"),
            seconds(&before, "paused_s")
        ),
        (0.0, 0.0),
        "nothing measured before the start: {before}"
    );
    // the same estimate after a restart (stored with the campaign, not planned again)
    drop(s);
    let s = start(&cfg, &store);
    let (_, again) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(again["estimate"], estimate, "after a restart");
    let (_, list) = get(&s, "/api/campaigns");
    assert_eq!(list[0]["estimate"], estimate, "the list");

    // run: pause after two poses for a while, resume, to the end
    let path = format!("/api/campaigns/{id}/commands");
    let started = Instant::now();
    arm_and_start(&s, id);
    let deadline = Instant::now() + Duration::from_secs(60);
    while get(&s, &format!("/api/campaigns/{id}")).1["poses_done"].as_u64() < Some(2) {
        assert!(Instant::now() < deadline, "two poses never measured");
        std::thread::sleep(Duration::from_millis(20));
    }
    let (code, v) = post(&s, &path, r#"{"command": "pause"}"#);
    assert_eq!(code, 200, "{v}");
    let paused = wait_for_state(&s, id, "paused");
    std::thread::sleep(Duration::from_millis(1500));
    let later = get(&s, &format!("/api/campaigns/{id}")).1;
    // while paused the paused time grows, the measuring time does not
    assert_eq!(
        seconds(&later, "measuring_s"),
        seconds(&paused, "measuring_s"),
        "measuring while paused: {paused} then {later}"
    );
    assert!(
        seconds(&later, "paused_s") >= seconds(&paused, "paused_s") + 1.4,
        "{paused} then {later}"
    );
    assert!(seconds(&paused, "measuring_s") > 0.0, "{paused}");
    let (code, v) = post(&s, &path, r#"{"command": "resume"}"#);
    assert_eq!(code, 200, "{v}");
    let done = wait_for_state(&s, id, "done");
    let wall = started.elapsed().as_secs_f64();
    let (measuring, paused_s) = (seconds(&done, "measuring_s"), seconds(&done, "paused_s"));
    assert!(paused_s >= 1.5, "paused {paused_s} s: {done}");
    assert!(
        measuring > 0.0 && measuring + paused_s <= wall + 0.1,
        "measuring {measuring} s + paused {paused_s} s within the {wall:.1} s from start to done"
    );
    assert_eq!(done["estimate"], estimate, "the estimate after the run");
    eprintln!(
        "planned {} s, measured {measuring:.1} s, paused {paused_s:.1} s, wall {wall:.1} s",
        estimate["total_s"]
    );

    // the stored result keeps planned against actual: the same figures as the view
    let stored = stored_result(&Store::open(&store).expect("store"), id)
        .expect("result")
        .expect("a result");
    let t = stored
        .campaign_time
        .expect("campaign_time in the stored result");
    assert_eq!(t.planned_summary.as_deref(), estimate["summary"].as_str());
    let planned = t.planned.expect("planned estimate");
    for k in ["poses", "readings", "setup_s", "total_s"] {
        assert_eq!(planned[k], estimate[k], "{k}");
    }
    assert_eq!(t.planned_s, estimate["total_s"].as_f64());
    assert_eq!((t.measuring_s, t.paused_s), (measuring, paused_s));
    let ratio = t.ratio.expect("ratio");
    assert!((ratio - measuring / t.planned_s.expect("planned")).abs() < 1e-12);

    // a restart shows the same finished times (nothing runs: nothing grows)
    drop(s);
    let s = start(&cfg, &store);
    let (_, after) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(
        (seconds(&after, "measuring_s"), seconds(&after, "paused_s")),
        (measuring, paused_s)
    );

    // the report shows them
    let (code, _, page) =
        super::serve::get_text(&s, &format!("/api/campaigns/{id}/report"), Some(&s.token));
    assert_eq!(code, 200, "{page:.300}");
    for want in [
        "campaign time planned",
        "campaign time measuring (pauses excluded)",
        "campaign time paused",
        estimate["summary"].as_str().expect("summary"),
        "× planned",
    ] {
        assert!(page.contains(want), "report without {want}");
    }
}

#[test]
fn run_prints_planned_against_actual_after_its_summary() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 20, 14);
    let store = dir.path().join("c.db");
    let out = super::common::cellcal_process()
        .args(["run", "--quiet", "--arm", "--on-fault", "fail", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store)
        .stdin(std::process::Stdio::null())
        .output()
        .expect("cellcal run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("UTF-8");
    let block = text
        .split("Campaign time (measuring excludes pauses):\n")
        .nth(1)
        .unwrap_or_else(|| panic!("no campaign time in:\n{text}"));
    let lines: Vec<&str> = block.lines().take(3).collect();
    assert!(
        lines[0].starts_with("  planned    20 poses, 40 readings, about ")
            || lines[0].starts_with("  planned    20 poses, 40 readings, under 10 s"),
        "{block}"
    );
    assert!(
        lines[1].starts_with("  measuring  ") && lines[1].ends_with("× planned)"),
        "{block}"
    );
    assert!(lines[2].starts_with("  paused     0.0 s"), "{block}");
    // a done campaign prints the same from the store
    let again = super::common::cellcal_process()
        .args(["run", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store)
        .args(["--campaign", "1"])
        .stdin(std::process::Stdio::null())
        .output()
        .expect("cellcal run");
    let again = String::from_utf8(again.stdout).expect("UTF-8");
    assert!(again.contains(&lines.join("\n")), "{again}");
}

#[test]
fn a_dead_daemon_s_downtime_is_neither_measuring_nor_paused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = fast_config(dir.path(), "serial", 300, 100);
    let store = dir.path().join("c.db");
    let s = start(&cfg, &store);
    let id = create(&s, "{}");
    let view = format!("/api/campaigns/{id}");
    let started = Instant::now();
    arm_and_start(&s, id);
    let deadline = Instant::now() + Duration::from_secs(60);
    while get(&s, &view).1["poses_done"].as_u64() < Some(3) {
        assert!(Instant::now() < deadline, "three poses never measured");
        std::thread::sleep(Duration::from_millis(20));
    }
    // killed (SIGKILL) while running: no final state; down for 2 s
    drop(s);
    let alive_s = started.elapsed().as_secs_f64();
    std::thread::sleep(Duration::from_millis(2000));
    let s = start(&cfg, &store);
    let (_, v) = get(&s, &view);
    assert_eq!(v["state"], "interrupted", "{v}");
    let measured = seconds(&v, "measuring_s");
    assert!(
        measured > 0.0 && measured <= alive_s,
        "measuring {measured} s, but the run lived {alive_s:.2} s: {v}"
    );
    assert_eq!(seconds(&v, "paused_s"), 0.0, "{v}");
    std::thread::sleep(Duration::from_millis(500));
    let (_, again) = get(&s, &view);
    assert_eq!(
        seconds(&again, "measuring_s"),
        measured,
        "nothing runs it: nothing grows"
    );
    // resumed to the end: the downtime is still not counted
    let resumed = Instant::now();
    arm_and_start(&s, id);
    let done = wait_for_state(&s, id, "done");
    let total = seconds(&done, "measuring_s");
    let lived = alive_s + resumed.elapsed().as_secs_f64();
    assert!(
        total > measured && total <= lived,
        "measuring {total} s over runs that lived {lived:.2} s (2 s down between): {done}"
    );
    eprintln!("killed after {alive_s:.2} s (measuring {measured:.2} s); done: {total:.2} s");
}
