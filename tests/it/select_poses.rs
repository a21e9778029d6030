//! `cellcal select-poses`: the contract of issue 20 (CSV header and rows, JSON fields, exit 2
//! on bad input), and optimal selection in a campaign plan.

use serde_json::Value;

use super::cli::{cellcal, robot};

/// `select-poses` of the TX60 into `dir` with `args` after the robot.
fn select_poses(dir: &std::path::Path, args: &[&str]) -> assert_cmd::assert::Assert {
    cellcal()
        .args(["select-poses", "--robot"])
        .arg(robot())
        .arg("--out")
        .arg(dir.join("poses.csv"))
        .arg("--json")
        .arg(dir.join("sel.json"))
        .args(args)
        .assert()
}

#[test]
fn select_poses_writes_the_chosen_poses_and_their_predicted_figures() {
    let dir = tempfile::tempdir().expect("tempdir");
    select_poses(
        dir.path(),
        &[
            "--model",
            "op",
            "--count",
            "12",
            "--candidates",
            "300",
            "--seed",
            "3",
        ],
    )
    .success();
    let csv = std::fs::read_to_string(dir.path().join("poses.csv")).expect("csv");
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("pose,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg")
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().expect("number")).collect())
        .collect();
    assert_eq!(rows.len(), 12);
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 7);
        assert_eq!(r[0], (i + 1) as f64, "poses numbered in measuring order");
        let q: Vec<f64> = r[1..].iter().map(|d| d.to_radians()).collect();
        assert!(cellcal::plan::Workspace::default().accepts(&super::common::tx60(), &q));
    }
    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("sel.json")).expect("json"))
            .expect("valid JSON");
    let params = json["parameters"].as_array().expect("parameters");
    assert_eq!(
        params.len(),
        28,
        "OP with the base: 28 identifiable parameters"
    );
    for p in params {
        assert!(p["name"].is_string() && p["unit"].is_string());
        assert!(p["sigma_selected"].as_f64().expect("σ") > 0.0);
        assert!(p["sigma_random"].as_f64().expect("σ") > 0.0);
    }
    let v = &json["predicted_verification"];
    let sel = v["selected"]["mean_mm"].as_f64().expect("selected");
    let rand = v["random"]["mean_mm"].as_f64().expect("random");
    let floor = v["selected"]["noise_floor_mm"].as_f64().expect("floor");
    assert_eq!(v["random"]["poses"], 12);
    assert!(v["verification_poses"].as_u64().expect("poses") > 0);
    assert!(floor > 0.015 && sel > floor, "{sel} over the floor {floor}");
    assert!(sel < rand, "selected {sel} mm beat 12 random {rand} mm");
    assert_eq!(json["model"], "op");
    assert_eq!(json["count"], 12);
}

#[test]
fn select_poses_refuses_bad_input_with_exit_2_and_the_reason() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (args, says) in [
        (
            &["--model", "op", "--count", "5", "--candidates", "200"][..],
            "at least 6",
        ),
        (
            &["--model", "op", "--count", "10", "--candidates", "0"],
            "empty",
        ),
        (
            &["--model", "op", "--count", "10", "--noise-mm", "nan"],
            "--noise-mm",
        ),
        (
            &["--model", "op", "--count", "10", "--noise-mm", "inf"],
            "--noise-mm",
        ),
        (
            &["--model", "op", "--count", "10", "--tool-mm", "0,nan,0"],
            "finite",
        ),
        (
            &[
                "--model",
                "op",
                "--count",
                "10",
                "--box-size-mm",
                "1000,0,1000",
            ],
            "> 0",
        ),
        (
            &["--model", "op", "--count", "10", "--stage-axis", "sideways"],
            "sideways",
        ),
        (
            &["--model", "op", "--count", "10", "--stage-axis", "+x"],
            "±y",
        ),
        (&["--model", "xyz", "--count", "10"], "xyz"),
        (
            &["--model", "op", "--count", "10", "--stage-travel-mm=-1"],
            "--stage-travel-mm",
        ),
        // a box the arm cannot reach: no candidate at all
        (
            &[
                "--model",
                "op",
                "--count",
                "10",
                "--candidates",
                "20",
                "--box-center-mm",
                "5000,0,0",
            ][..],
            "poses found",
        ),
    ] {
        let out = select_poses(dir.path(), args).get_output().clone();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}
