//! `cellcal predict`: the dry run of a campaign prints the predicted verification error for
//! random and selected identification poses, the campaign time and the precision of the
//! verification set; bad input exits 2.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::cli::cellcal;

fn sim_config() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml")
}

/// Of `text`, the line starting with `prefix` (failing the test naming the text when none).
fn line<'a>(text: &'a str, prefix: &str) -> &'a str {
    text.lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no line `{prefix}…` in:\n{text}"))
}

/// The first number after `marker` in `text`.
fn number_after(text: &str, marker: &str) -> f64 {
    let at = text
        .find(marker)
        .unwrap_or_else(|| panic!("`{marker}` in {text}"))
        + marker.len();
    text[at..]
        .trim_start()
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("a number after `{marker}` in {text}"))
}

#[test]
fn predict_on_the_simulated_cell_prints_accuracy_time_and_the_verification_set_s_precision() {
    let dir = tempfile::tempdir().expect("tempdir");
    let json = dir.path().join("p.json");
    let out = cellcal()
        .arg("predict")
        .arg("--config")
        .arg(sim_config())
        .args(["--trials", "6", "--json"])
        .arg(&json)
        .output()
        .expect("runs");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let head = line(&text, "predict: ");
    assert!(
        head.contains("model op")
            && head.contains("100 identification poses")
            && head.contains("200 verification poses")
            && head.contains("6 trials (seed 4802)"),
        "{head}"
    );
    assert!(line(&text, "assumed: ").contains("tracker at (2500, 400, 200) mm"));
    let random = line(&text, "random poses: verification mean error ");
    let mean = number_after(random, "verification mean error");
    let ratio = number_after(random, "over trials,");
    let floor = number_after(random, "the noise floor");
    // cell.sim.toml: AT960 about 2.5 m away, σ ≈ 0.014 mm per axis
    assert!((0.015..0.04).contains(&floor), "{random}");
    assert!((1.0..1.1).contains(&ratio), "{random}");
    assert!((mean / floor - ratio).abs() < 0.01, "{random}");
    let optimal = line(&text, "optimal poses: verification mean error ");
    let ratio_optimal = number_after(optimal, "over trials,");
    assert!((1.0..1.1).contains(&ratio_optimal), "{optimal}");
    for label in ["random", "optimal"] {
        let time = line(&text, &format!("campaign time, {label} poses: "));
        assert!(time.contains("300 poses, 600 readings, about "), "{time}");
    }
    let set = line(
        &text,
        "verification set: 200 poses measure the mean error to ± ",
    );
    let se200 = number_after(set, "to ±");
    let se50 = number_after(set, "50: ±");
    assert!(se50 > se200, "{set}");
    let doc: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json written")).expect("json");
    assert_eq!(doc["ident_poses"], 100);
    assert_eq!(doc["verify_poses"], 200);
    let r = &doc["designs"]["random"];
    assert!((r["verify_mean_mm"].as_f64().expect("mean") - mean).abs() < 1e-4);
    let se = |v: &str| r["standard_error_mm"][v].as_f64().expect("standard error");
    assert!((se("200") - se200).abs() < 1e-4);
    // σ/√V: a quarter of the poses, twice the standard error
    assert!((se("50") / se("200") - 2.0).abs() < 1e-9, "{r}");
    assert!((se("50") - se50).abs() < 1e-4);
    assert_eq!(r["campaign_time"]["readings"], 600);
    assert!(doc["designs"]["optimal"]["verify_mean_mm"]
        .as_f64()
        .is_some());

    // seeded: the same run prints the same
    let again = cellcal()
        .arg("predict")
        .arg("--config")
        .arg(sim_config())
        .args(["--trials", "6", "--selection", "random"])
        .output()
        .expect("runs");
    let again = String::from_utf8_lossy(&again.stdout).into_owned();
    assert_eq!(line(&again, "random poses: "), random);
    assert!(!again.contains("optimal poses"), "{again}");
}

#[test]
fn predict_refuses_bad_input_with_exit_2_and_the_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    let robot = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/robots/staubli_tx60.toml");
    let text = std::fs::read_to_string(sim_config())
        .expect("sim config")
        .replace(
            "robot = \"robots/staubli_tx60.toml\"",
            &format!("robot = {:?}", robot.to_string_lossy()),
        );
    let nan = dir.path().join("nan.toml");
    std::fs::write(&nan, text.replace("travel_mm = 10.0", "travel_mm = nan")).expect("write");
    let missing = dir.path().join("missing.toml");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["--poses".into(), "0".into()],
            "--poses must be at least 1",
        ),
        (
            vec!["--trials".into(), "0".into()],
            "--trials must be between 1",
        ),
        (
            vec!["--verify".into(), "0".into()],
            "--verify must be at least 1",
        ),
        (
            vec!["--poses".into(), "3".into(), "--trials".into(), "2".into()],
            "identification poses enough",
        ),
        (
            vec!["--selection".into(), "best".into()],
            "invalid value 'best'",
        ),
    ];
    let run = |config: &Path, extra: &[String]| {
        cellcal()
            .arg("predict")
            .arg("--config")
            .arg(config)
            .args(extra)
            .output()
            .expect("runs")
    };
    for (extra, want) in cases {
        let out = run(&sim_config(), &extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(want), "{extra:?}: expected `{want}` in {err}");
    }
    for (config, want) in [(&nan, "travel_mm"), (&missing, "missing.toml")] {
        let out = run(config, &[]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(err.contains(want), "expected `{want}` in {err}");
    }
}
