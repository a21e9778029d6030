//! The outputs other programs rely on stay the same (issue 18 item 9): the `identify` JSON and
//! the corrected model of the README campaign (command 1) and of a seeded `simulate-data`
//! fixture are pinned by committed snapshots in `tests/snapshots/`. A field may be added; no
//! field may go, be renamed or change its value (numbers to 1e-9 relative plus 1e-9 absolute,
//! i.e. a nanometre or nanoradian: the last bits of a float may move with a refactored solver
//! or transform, a micrometre may not). Regenerate a snapshot only
//! for an intended change, with `CELLCAL_BLESS=1`, and say so in the commit.

use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::cli::{cellcal, robot};

fn snapshot_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/snapshots")
        .join(name)
}

/// Compare `actual` with the committed snapshot `name`, or write it under `CELLCAL_BLESS=1`.
fn assert_pinned(name: &str, actual: &Value) {
    let path = snapshot_path(name);
    if std::env::var_os("CELLCAL_BLESS").is_some() {
        let text = serde_json::to_string_pretty(actual).expect("JSON") + "\n";
        std::fs::write(&path, text).expect("snapshot written");
        return;
    }
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (CELLCAL_BLESS=1 writes it)", path.display()));
    let expected: Value = serde_json::from_str(&text).expect("snapshot JSON");
    let mut diffs = Vec::new();
    contained_in(&expected, actual, "", &mut diffs);
    assert!(
        diffs.is_empty(),
        "{name}: {} difference(s) from the snapshot:\n{}",
        diffs.len(),
        diffs
            .iter()
            .take(20)
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Every value of `expected` is in `actual` at the same JSON pointer (objects may have more keys).
fn contained_in(expected: &Value, actual: &Value, at: &str, diffs: &mut Vec<String>) {
    match (expected, actual) {
        (Value::Object(e), Value::Object(a)) => {
            for (k, ev) in e {
                let here = format!("{at}/{k}");
                match a.get(k) {
                    Some(av) => contained_in(ev, av, &here, diffs),
                    None => diffs.push(format!("{here}: missing")),
                }
            }
        }
        (Value::Array(e), Value::Array(a)) if e.len() == a.len() => {
            for (i, (ev, av)) in e.iter().zip(a).enumerate() {
                contained_in(ev, av, &format!("{at}/{i}"), diffs);
            }
        }
        (Value::Number(e), Value::Number(a)) => {
            let (e, a) = (
                e.as_f64().unwrap_or(f64::NAN),
                a.as_f64().unwrap_or(f64::NAN),
            );
            let close = (e - a).abs() <= 1e-9 * e.abs().max(a.abs()) + 1e-9;
            if !close {
                diffs.push(format!("{at}: {a} (snapshot {e})"));
            }
        }
        (e, a) if e == a => {}
        (e, a) => diffs.push(format!("{at}: {a} (snapshot {e})")),
    }
}

/// A corrected-model TOML as JSON (comments dropped: they quote the result's digest, which
/// changes when a field is added).
fn model_value(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).expect("model written");
    let table: toml::Table = toml::from_str(&text).expect("model TOML");
    serde_json::to_value(table).expect("model as JSON")
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("JSON written")).expect("JSON")
}

/// README command 1, verbatim but for the output paths: the result JSON and the corrected model.
#[test]
fn the_readme_campaign_gives_the_pinned_result_and_model() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (store, json, model) = (
        dir.path().join("campaign.db"),
        dir.path().join("result.json"),
        dir.path().join("m.toml"),
    );
    cellcal()
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "run",
            "--config",
            "config/cell.sim.toml",
            "--arm",
            "--quiet",
        ])
        .arg("--store")
        .arg(&store)
        .arg("--json")
        .arg(&json)
        .arg("--model-out")
        .arg(&model)
        .assert()
        .success();
    assert_pinned("readme_campaign.result.json", &read_json(&json));
    assert_pinned("readme_campaign.model.json", &model_value(&model));
}

/// `identify` on a seeded fixture with a robust loss and the held-back list exercised.
#[test]
fn identify_on_the_seeded_fixture_gives_the_pinned_result_and_model() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = crate::cli::simulate_poses(dir.path(), 80, 40, &["--seed", "1804"]);
    let (json, model) = (dir.path().join("r.json"), dir.path().join("m.toml"));
    cellcal()
        .args(["identify", "--robot"])
        .arg(robot())
        .arg("--data")
        .arg(&data)
        .args(["--model", "op", "--robust", "huber", "--identify-tool"])
        .arg("--json")
        .arg(&json)
        .arg("--model-out")
        .arg(&model)
        .assert()
        .success();
    assert_pinned("identify_fixture.result.json", &read_json(&json));
    assert_pinned("identify_fixture.model.json", &model_value(&model));
}

#[test]
fn the_containment_check_finds_a_changed_a_missing_and_a_moved_value() {
    let snap: Value = serde_json::json!({"a": 1.0, "b": {"c": [1, 2]}, "s": "x"});
    let mut d = Vec::new();
    contained_in(
        &snap,
        &serde_json::json!({"a": 1.0 + 1e-10, "b": {"c": [1, 2]}, "s": "x", "new": 5}),
        "",
        &mut d,
    );
    assert!(d.is_empty(), "{d:?}");
    contained_in(
        &snap,
        &serde_json::json!({"a": 1.001, "b": {"c": [2, 1]}}),
        "",
        &mut d,
    );
    assert_eq!(d.len(), 4, "{d:?}");
}
