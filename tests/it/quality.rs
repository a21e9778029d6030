//! The verdict: a good simulated case is `ok`, an ill-posed one is `poor` and exits 3 (from
//! `identify`, and from `run` with the campaign still `done`), and data that contradicts the
//! stage axis (or the np/op model) is refused with exit 2 and the angle.

use std::path::Path;
use std::process::Output;

use serde_json::Value;

use crate::campaign::{config_text, journal_states, write_config};
use crate::cli::{robot, simulate_poses};
use crate::reproduce::{cellcal, json, ok};

fn codes(v: &Value) -> Vec<&str> {
    v["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .map(|w| w["code"].as_str().expect("code"))
        .collect()
}

/// `identify` with `args` on `data` (in `dir`): its output and JSON (null when none written).
fn identify(dir: &Path, data: &Path, args: &[&str]) -> (Output, Value) {
    let out_json = dir.join("r.json");
    let _ = std::fs::remove_file(&out_json);
    let mut all = vec!["identify"];
    all.extend_from_slice(args);
    let out = cellcal(
        &all,
        &[
            ("--robot", &robot()),
            ("--data", data),
            ("--json", &out_json),
        ],
    );
    let v = if out_json.exists() {
        json(&out_json)
    } else {
        Value::Null
    };
    (out, v)
}

#[test]
fn a_good_simulated_case_is_ok() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate_poses(dir.path(), 300, 100, &[]);
    let (out, v) = identify(dir.path(), &data, &["--model", "op"]);
    ok(&out);
    assert_eq!(v["quality"], "ok", "{}", v["warnings"]);
    assert!(codes(&v).is_empty());
    let angle = v["stage_axis_angle_rad"].as_f64().expect("angle");
    assert!(angle < 0.005, "{angle} rad");
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("quality: ok\n"));
}

#[test]
fn an_ill_posed_case_is_poor_and_exits_3() {
    // 8 identification poses for 24 parameters: the fit follows the noise
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate_poses(dir.path(), 60, 8, &[]);
    // every structurally identifiable parameter kept (`--noise-mm 0`): the ill-posed fit itself
    let (out, v) = identify(dir.path(), &data, &["--model", "op", "--noise-mm", "0"]);
    assert_eq!(out.status.code(), Some(3));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("poor (too_few_poses, overfit)"), "{err}");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with("quality: POOR"), "{text}");
    assert!(
        text.contains("poor    too_few_poses: 24 parameters from 8 poses"),
        "{text}"
    );
    // the result is still written, with the verdict
    assert_eq!(v["quality"], "poor");
    let c = codes(&v);
    assert!(
        c.contains(&"too_few_poses") && c.contains(&"overfit"),
        "{c:?}"
    );
    let poor: Vec<&Value> = v["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .filter(|w| w["severity"] == "poor")
        .collect();
    assert_eq!(poor.len(), 2, "{poor:?}");
}

#[test]
fn a_stage_axis_that_contradicts_the_data_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate_poses(dir.path(), 60, 40, &["--stage-axis", "+y"]);
    for (args, angle) in [
        (&["--model", "np"][..], "90."),
        (&["--model", "op", "--stage-axis", "-y"][..], "179."),
        (&["--model", "op", "--stage-axis", "0,0.9,0.3"][..], "18."),
    ] {
        let (out, v) = identify(dir.path(), &data, args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("contradicts the data") && err.contains(&format!(", {angle}")),
            "{args:?}: {err}"
        );
        assert!(v.is_null(), "no result for refused data");
    }
    // a couple of degrees off is a warning, not a refusal
    let (out, v) = identify(
        dir.path(),
        &data,
        &["--model", "op", "--stage-axis", "0.04,1,0"],
    );
    ok(&out);
    assert_eq!(v["quality"], "warning");
    assert!(codes(&v).contains(&"stage_axis"), "{v}");
}

#[test]
fn a_poor_campaign_ends_done_and_run_exits_3() {
    // joint jitter of 2 mrad (0.5–1.5 mm at the ball): the parameters drown in it
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20")
        .replace("joint_jitter_rad = 1.2746e-5", "joint_jitter_rad = 2.0e-3")
        .replace("drift_max_mm = 0.1", "drift_max_mm = 10.0")
        .replace(
            "[setup]",
            "[setup]\nmax_sphere_rms_mm = 10.0\nmax_base_rms_mm = 10.0\n",
        );
    let dir = tempfile::tempdir().expect("tempdir");
    let config = write_config(dir.path(), &text);
    let store = dir.path().join("c.db");
    let out_json = dir.path().join("r.json");
    let run = |arm: bool| {
        let mut args = vec!["run", "--quiet", "--on-fault", "fail", "--campaign", "1"];
        if arm {
            args.truncate(4);
            args.push("--arm");
        }
        cellcal(
            &args,
            &[
                ("--config", &config),
                ("--store", &store),
                ("--json", &out_json),
            ],
        )
    };
    let out = run(true);
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("campaign 1 is done, but its result is poor ("),
        "{err}"
    );
    let v = json(&out_json);
    assert_eq!(v["quality"], "poor");
    assert!(codes(&v).contains(&"parameter_sigma"), "{:?}", codes(&v));
    let states = journal_states(&store, 1);
    assert_eq!(
        states.last().map(|s| &s["state"]),
        Some(&Value::from("done"))
    );
    // the stored result keeps its verdict: a second run prints it and exits 3 again
    let out = run(false);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("quality: POOR"));
}
