//! Frame-first absorption: where a frame parameter (base, tool) and a robot parameter cannot be
//! told apart, the frame takes the offset and the robot parameter stays at nominal. On
//! tracker-frame data with an unknown tool, `--identify-base --identify-tool` gives a robot
//! whose every identified parameter is the simulated truth's within its σ, a tool and a base at
//! the truth, and a model `cellcal compensate` accepts (before: Δd6 = +59.9 mm, refused).

use std::path::Path;

use serde_json::Value;

use super::cli::{cellcal, robot, simulate_poses};

/// The true ball position and tracker frame of `config/cell.sim.toml`'s simulated cell.
const TOOL: &str = "0.4,-0.3,60";
const BASE_MM: &str = "2434.177,-693.336,-209.929";
const BASE_DEG: &str = "0.3,-0.2,155";

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).expect("written")).expect("JSON")
}

#[test]
fn an_unknown_tool_and_tracker_frame_go_to_the_frames_not_the_robot() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate_poses(
        dir.path(),
        300,
        100,
        &[
            "--tool-mm",
            TOOL,
            "--base-translation-mm",
            BASE_MM,
            "--base-rotvec-deg",
            BASE_DEG,
        ],
    );
    let truth = read_json(&data.with_extension("truth.json"));
    let json = dir.path().join("r.json");
    let model = dir.path().join("identified.toml");
    let out = cellcal()
        .args([
            "identify",
            "--model",
            "op",
            "--identify-base",
            "--identify-tool",
        ])
        .arg("--robot")
        .arg(robot())
        .arg("--data")
        .arg(&data)
        .arg("--json")
        .arg(&json)
        .arg("--model-out")
        .arg(&model)
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    let r = read_json(&json);

    // every identified robot parameter at the truth (within 5σ) and plausible in size
    let mut identified = 0;
    for p in r["parameters"].as_array().expect("parameters") {
        if p["joint"].is_null() || p["identified"] != true {
            continue;
        }
        identified += 1;
        let name = p["name"].as_str().expect("name");
        let error = p["error"].as_f64().expect("error");
        let std = p["std"].as_f64().expect("σ");
        let true_error = truth["errors"][name].as_f64().unwrap_or(0.0);
        let plausible = if p["unit"] == "rad" { 5e-3 } else { 1.0 };
        assert!(
            error.abs() < plausible && (error - true_error).abs() <= 5.0 * std,
            "{name}: {error:+e} ± {std:e} vs truth {true_error:+e}\n{stdout}"
        );
    }
    assert!(identified >= 20, "{identified} robot parameters identified");
    // the robot parameters the frames absorb stay at nominal, named as dependent on them
    for (robot_param, frame) in [
        ("d1", "base_tz"),
        ("theta1", "base_r"),
        ("a6", "tool_x"),
        ("d6", "tool_z"),
    ] {
        let d = r["not_identifiable"]
            .as_array()
            .and_then(|a| a.iter().find(|d| d["name"] == robot_param))
            .unwrap_or_else(|| panic!("{robot_param} identified\n{stdout}"));
        let reason = d["reason"].as_str().unwrap_or("");
        assert!(reason.contains(frame), "{robot_param}: {reason}");
    }
    // the tool and the base at the truth (the tool carries d6 and a6's −0.11/−0.09 mm)
    let v3 = |v: &Value| -> Vec<f64> { (0..3).map(|k| v[k].as_f64().expect("number")).collect() };
    let dist = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>()
            .sqrt()
    };
    let tool = v3(&r["tool"]["translation_mm"]);
    let true_tool = v3(&truth["tool"]["translation_mm"]);
    assert!(
        dist(&tool, &true_tool) < 0.5,
        "tool {tool:?} vs {true_tool:?}"
    );
    let base = v3(&r["base"]["translation_mm"]);
    let true_base = v3(&truth["base"]["translation_mm"]);
    assert!(
        dist(&base, &true_base) < 1.0,
        "base {base:?} vs {true_base:?}"
    );
    let rot = v3(&r["base"]["rotation_vector_rad"]);
    let true_rot = v3(&truth["base"]["rotation_vector_rad"]);
    assert!(dist(&rot, &true_rot) < 2e-3, "base {rot:?} vs {true_rot:?}");

    // the corrected model is a robot the compensator accepts against the nominal one
    let program = dir.path().join("p.csv");
    std::fs::write(
        &program,
        "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n0,30,90,0,45,0\n10,20,80,5,50,-10\n",
    )
    .expect("write");
    let joints = dir.path().join("j.csv");
    let out = cellcal()
        .args(["compensate", "--robot"])
        .arg(robot())
        .arg("--identified")
        .arg(&model)
        .arg("--joints")
        .arg(&program)
        .arg("--out")
        .arg(&joints)
        .output()
        .expect("runs");
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j = std::fs::read_to_string(&joints).expect("J.csv");
    assert_eq!(j.lines().count(), 3, "{j}");
    assert!(j.lines().skip(1).all(|l| l.contains(",true,")), "{j}");
}
