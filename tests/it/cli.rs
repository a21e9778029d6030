//! The `cellcal` binary: the identify contract (JSON fields) and every bad input (exit code 2,
//! a message naming the column, line or value, never a panic).

use std::path::{Path, PathBuf};

use assert_cmd::Command;
use serde_json::Value;

pub(crate) fn robot() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/robots/staubli_tx60.toml")
}

pub(crate) fn cellcal() -> Command {
    Command::cargo_bin("cellcal").expect("binary built")
}

pub(crate) fn simulate(dir: &Path, extra: &[&str]) -> PathBuf {
    simulate_poses(dir, 60, 40, extra)
}

/// `simulate-data` into `dir/d.csv`: `poses` poses, `ident` of them for identification.
pub(crate) fn simulate_poses(dir: &Path, poses: usize, ident: usize, extra: &[&str]) -> PathBuf {
    let out = dir.join("d.csv");
    cellcal()
        .args(["simulate-data", "--robot"])
        .arg(robot())
        .arg("--out")
        .arg(&out)
        .args(["--poses", &poses.to_string(), "--ident", &ident.to_string()])
        .args(extra)
        .assert()
        .success();
    out
}

/// `cellcal identify` of the TX60 on `data` with `--model model --json json`.
pub(crate) fn identify_json(data: &Path, model: &str, json: &Path) -> Command {
    let mut c = cellcal();
    c.args(["identify", "--robot"])
        .arg(robot())
        .arg("--data")
        .arg(data)
        .args(["--model", model, "--json"])
        .arg(json);
    c
}

/// `text` holds a number in e-notation (`-1.222478e-1`, `2E5`).
pub(crate) fn has_e_notation(text: &str) -> bool {
    let b = text.as_bytes();
    (1..b.len().saturating_sub(1)).any(|i| {
        let digit_after = match b[i + 1] {
            b'+' | b'-' => b.get(i + 2).is_some_and(u8::is_ascii_digit),
            c => c.is_ascii_digit(),
        };
        matches!(b[i], b'e' | b'E') && b[i - 1].is_ascii_digit() && digit_after
    })
}

#[test]
fn identify_prints_every_value_with_its_sigma_in_mm_and_mrad_without_e_notation() {
    use cellcal::units::human::{fmt_mm, fmt_mrad};
    assert!(has_e_notation("x -1.222478e-1 mm") && has_e_notation("2E5"));
    assert!(!has_e_notation("theta1 0.150 ± 0.008 held e-mail 2 e3"));
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate(dir.path(), &[]);
    let json = dir.path().join("r.json");
    let out = identify_json(&data, "op", &json).output().expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("UTF-8");
    assert!(!has_e_notation(&text), "e-notation in:\n{text}");
    let header = text
        .lines()
        .find(|l| l.starts_with("joint "))
        .unwrap_or_else(|| panic!("no table header in:\n{text}"));
    let columns: Vec<&str> = header
        .split("  ")
        .map(str::trim)
        .filter(|c| !c.is_empty())
        .collect();
    assert_eq!(
        columns,
        [
            "joint",
            "Δθ (mrad)",
            "Δd (mm)",
            "Δa (mm)",
            "Δα (mrad)",
            "Δβ (mrad)"
        ],
        "{header}"
    );
    assert!(
        text.contains("Accuracy (position mm, attitude mrad)"),
        "{text}"
    );
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("valid json");
    let mut checked = 0;
    for p in v["parameters"].as_array().expect("parameters") {
        let name = p["name"].as_str().expect("name");
        let Some(joint) = p["joint"].as_u64() else {
            continue;
        };
        let row = text
            .lines()
            .find(|l| l.split_whitespace().next() == Some(joint.to_string().as_str()))
            .unwrap_or_else(|| panic!("no row of joint {joint}"));
        let shown = |x: f64| match p["unit"].as_str() {
            Some("rad") => fmt_mrad(x),
            Some("mm") => fmt_mm(x),
            u => panic!("{name}: unit {u:?}"),
        };
        if p["identified"] == true {
            let value = p["error"].as_f64().expect("error");
            let sigma = p["std"].as_f64().expect("an identified value has its σ");
            let want = format!("{} ± {}", shown(value), shown(sigma));
            assert!(row.contains(&want), "{name}: `{want}` not in `{row}`");
            checked += 1;
        } else {
            assert!(
                row.contains("not identifiable") || row.contains("held"),
                "{name}: `{row}` does not say it is held"
            );
        }
    }
    assert_eq!(checked, 24, "every identified MDH parameter with its σ");
}

fn identify_err(data: &str, model: &str) -> (i32, String) {
    let dir = tempfile::tempdir().expect("tempdir");
    let f = dir.path().join("bad.csv");
    std::fs::write(&f, data).expect("write");
    let out = cellcal()
        .args(["identify", "--robot"])
        .arg(robot())
        .arg("--data")
        .arg(&f)
        .args(["--model", model])
        .output()
        .expect("runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn identify_writes_the_json_contract() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate(dir.path(), &[]);
    let json = dir.path().join("r.json");
    let out = cellcal()
        .args(["identify", "--robot"])
        .arg(robot())
        .arg("--data")
        .arg(&data)
        .args(["--model", "op", "--json"])
        .arg(&json)
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("Δθ (mrad)") && text.contains("verify  after"),
        "{text}"
    );
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("valid json");
    assert_eq!(v["model"], "op");
    assert_eq!(v["identified"].as_array().map(Vec::len), Some(24));
    assert_eq!(v["identified"][0], "theta1");
    let ni: Vec<&str> = v["not_identifiable"]
        .as_array()
        .expect("array")
        .iter()
        .map(|x| x["name"].as_str().unwrap_or(""))
        .collect();
    assert_eq!(ni, ["beta1", "d2", "beta3", "beta4", "beta5", "beta6"]);
    assert!(v["not_identifiable"][0]["reason"].is_string());
    let p = &v["parameters"][1];
    for key in [
        "name",
        "joint",
        "kind",
        "unit",
        "nominal",
        "error",
        "std",
        "identified",
    ] {
        assert!(p.get(key).is_some(), "parameters[].{key}");
    }
    assert_eq!(p["name"], "d1");
    assert_eq!(p["unit"], "mm");
    assert_eq!(
        v["base"]["translation_mm"].as_array().map(Vec::len),
        Some(3)
    );
    assert_eq!(
        v["base"]["rotation_vector_rad"].as_array().map(Vec::len),
        Some(3)
    );
    assert_eq!(
        v["tool"]["translation_mm"].as_array().map(Vec::len),
        Some(3)
    );
    for key in ["iterations", "converged", "final_cost"] {
        assert!(v["solver"].get(key).is_some(), "solver.{key}");
    }
    for set in ["ident", "verify"] {
        for state in ["before", "after"] {
            let m = &v["metrics"][set][state];
            for key in [
                "poses",
                "position_mean_mm",
                "position_max_mm",
                "position_rms_mm",
                "position_axial_mean_mm",
                "position_axial_max_mm",
                "attitude_mean_rad",
                "attitude_max_rad",
            ] {
                assert!(m.get(key).is_some(), "metrics.{set}.{state}.{key}");
            }
            assert!(m["attitude_mean_rad"].is_number());
        }
    }
    assert_eq!(v["metrics"]["verify"]["after"]["poses"], 20);
    let after = v["metrics"]["verify"]["after"]["position_mean_mm"]
        .as_f64()
        .unwrap_or(1.0);
    assert!(after < 0.04, "{after}");
}

#[test]
fn position_model_has_null_attitude() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate(dir.path(), &[]);
    let json = dir.path().join("r.json");
    identify_json(&data, "position", &json).assert().success();
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    assert!(v["metrics"]["ident"]["after"]["attitude_mean_rad"].is_null());
}

#[test]
fn robust_lists_rejected_poses_and_base_tool_flags_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate(
        dir.path(),
        &[
            "--outliers",
            "0.05",
            "--base-translation-mm",
            "2400,300,-500",
            "--base-rotvec-deg",
            "0,0,170",
            "--tool-mm",
            "0,-20,40",
        ],
    );
    let truth: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("d.truth.json")).expect("truth"),
    )
    .expect("json");
    let json = dir.path().join("r.json");
    cellcal()
        .args(["identify", "--robot"])
        .arg(robot())
        .arg("--data")
        .arg(&data)
        .args([
            "--model",
            "op",
            "--identify-base",
            "--identify-tool",
            "--robust",
            "--json",
        ])
        .arg(&json)
        .assert()
        .success();
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let rejected: Vec<String> = v["rejected_poses"]
        .as_array()
        .expect("array")
        .iter()
        .filter_map(|x| x.as_str().map(str::to_owned))
        .collect();
    let outliers: Vec<String> = truth["outlier_poses"]
        .as_array()
        .expect("array")
        .iter()
        .filter_map(|x| x.as_str().map(str::to_owned))
        .filter(|id| id.parse::<usize>().map(|i| i < 40).unwrap_or(false))
        .collect();
    assert_eq!(rejected, outliers);
    assert!(v["identified"]
        .as_array()
        .expect("array")
        .iter()
        .any(|x| x == "tool_y"));
    let ty = v["tool"]["translation_mm"][1].as_f64().unwrap_or(0.0);
    assert!((ty + 20.0).abs() < 0.05, "tool y {ty}");
}

const HEAD: &str = "pose,set,q1,q2,q3,q4,q5,q6,p1_x,p1_y,p1_z,p2_x,p2_y,p2_z\n";
const ROW: &str = "0,ident,0.1,0.2,0.3,0.4,0.5,0.6,300,10,400,300,20,400\n";

#[test]
fn bad_inputs_exit_2_with_a_clear_message() {
    let cases: Vec<(String, &str, &str)> = vec![
        (HEAD.replace(",q3", ""), "op", "missing column `q3`"),
        (
            format!("{HEAD}{}", ROW.replace("0.2", "NaN")),
            "op",
            "line 2, column `q2`: `NaN` is not finite",
        ),
        (
            format!("{HEAD}{}", ROW.replace("0.2", "inf")),
            "op",
            "`inf` is not finite",
        ),
        (
            format!("{HEAD}{}", ROW.replace("0.2", "x1")),
            "op",
            "line 2, column `q2`: `x1` is not a number",
        ),
        (String::new(), "op", "empty"),
        (HEAD.to_owned(), "op", "no data rows"),
        (format!("{HEAD}{ROW}"), "op", "too few poses"),
        (
            format!("{HEAD}{}", ROW.replace("ident", "train")),
            "op",
            "`train` is neither `ident` nor `verify`",
        ),
        (HEAD.replace("pose", "q1"), "op", "duplicated column `q1`"),
        (
            format!("{HEAD}{ROW}"),
            "sideways",
            "invalid value 'sideways'",
        ),
        (
            format!("{}{ROW}", HEAD.replace(",p2_x,p2_y,p2_z", ",a,b,c")),
            "op",
            "missing column `p2_x`",
        ),
        (format!("{HEAD}{ROW}"), "full", "missing column `n_x`"),
    ];
    for (data, model, want) in cases {
        let (code, err) = identify_err(&data, model);
        assert_eq!(code, 2, "{want}: {err}");
        assert!(err.contains(want), "expected `{want}` in: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn bad_robot_file_names_the_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let f = dir.path().join("r.toml");
    std::fs::write(
        &f,
        include_str!("../../config/robots/staubli_tx60.toml").replacen(
            "a_mm = 290",
            "a_mm = \"x\"",
            1,
        ),
    )
    .expect("write");
    let out = cellcal()
        .args(["significance", "--robot"])
        .arg(&f)
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("r.toml") && err.contains("a_mm"), "{err}");
}

#[test]
fn significance_prints_and_writes_json() {
    let dir = tempfile::tempdir().expect("tempdir");
    let json = dir.path().join("s.json");
    let out = cellcal()
        .args(["significance", "--robot"])
        .arg(robot())
        .args(["--samples", "20", "--seed", "3", "--json"])
        .arg(&json)
        .output()
        .expect("runs");
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("ē_p"));
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    assert_eq!(v["parameters"].as_array().map(Vec::len), Some(30));
}

#[test]
fn simulate_data_is_deterministic() {
    let a = tempfile::tempdir().expect("tempdir");
    let b = tempfile::tempdir().expect("tempdir");
    let fa = simulate(a.path(), &["--seed", "9"]);
    let fb = simulate(b.path(), &["--seed", "9"]);
    assert_eq!(std::fs::read(fa).expect("a"), std::fs::read(fb).expect("b"));
}

#[test]
fn a_large_data_set_read_in_chunks_identifies_as_read_whole() {
    let dir = tempfile::tempdir().expect("tempdir");
    // over 1 MB: read in chunks by two readers
    let data = simulate_poses(dir.path(), 4000, 3000, &[]);
    let text = std::fs::read_to_string(&data).expect("csv");
    assert!(text.len() > 1 << 20);
    // one quoted cell: the same data, read whole by the csv crate
    let quoted = dir.path().join("quoted.csv");
    std::fs::write(&quoted, text.replacen(",ident,", ",\"ident\",", 1)).expect("write");
    let report = |data: &Path, name: &str| -> Value {
        let json = dir.path().join(name);
        identify_json(data, "op", &json).assert().success();
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json")
    };
    assert_eq!(report(&data, "chunks.json"), report(&quoted, "whole.json"));
    // a bad cell near the end: the same line named either way
    let line = text.lines().count() - 3;
    let bad_row = text.lines().nth(line - 1).expect("row");
    let bad = bad_row
        .replacen(",ident,", ",ident,x", 1)
        .replacen(",verify,", ",verify,x", 1);
    let message = |text: String| {
        let (code, err) = identify_err(&text, "op");
        assert_eq!(code, 2, "{err}");
        err.split("bad.csv")
            .nth(1)
            .map(str::to_owned)
            .expect("names the file")
    };
    let broken = text.replacen(bad_row, &bad, 1);
    let whole = broken.replacen(",ident,", ",\"ident\",", 1);
    let named = message(broken);
    assert!(
        named.contains(&format!("line {line}, column `q1`")),
        "{named}"
    );
    assert_eq!(named, message(whole));
}
