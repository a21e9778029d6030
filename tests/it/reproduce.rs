//! Reproducible campaigns: a simulated campaign re-identified offline, from its exported CSV
//! (setup in the header) or straight from its store, gives the campaign's own result bit for
//! bit; a flag that contradicts the exported setup is refused.

use std::path::{Path, PathBuf};
use std::process::Output;

use cellcal::campaign::stored::stored_result;
use cellcal::campaign::Outcome;
use cellcal::store::Store;
use serde_json::Value;

use crate::campaign::{config_text, run_steered};

/// Run `cellcal` with `args` and `(flag, path)` pairs.
pub(crate) fn cellcal(args: &[&str], paths: &[(&str, &Path)]) -> Output {
    let mut c = crate::cli::cellcal();
    c.args(args);
    for (flag, p) in paths {
        c.arg(flag).arg(p);
    }
    c.output().expect("cellcal runs")
}

pub(crate) fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
}

pub(crate) fn json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("JSON written")).expect("JSON")
}

/// A 40-pose campaign on the simulated cell with a misaligned stage and a ball off the design
/// tool: the setup measures both, so the identification depends on them.
async fn campaign() -> (PathBuf, i64, Value) {
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20")
        .replace(
            "stage_misalignment_mrad = [0.0, 0.0, 0.0]",
            "stage_misalignment_mrad = [2.0, 0.0, -3.0]",
        );
    let (outcome, store, id) = run_steered(&text, |_, _, _| {}).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    let stored = stored_result(&Store::open(&store).expect("store"), id)
        .expect("read")
        .expect("a stored result");
    (
        store,
        id,
        serde_json::to_value(&stored.report).expect("the contract"),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn export_and_store_reidentify_a_campaign_exactly() {
    let (store, id, stored) = campaign().await;
    let dir = store.parent().expect("dir").to_owned();
    // identify exits as the stored verdict says (3 when poor), and writes the result either way
    let verdict_exit = if stored["quality"] == "poor" { 3 } else { 0 };
    let reidentified = |out: &Output| {
        assert_eq!(
            out.status.code(),
            Some(verdict_exit),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        )
    };
    let robot = dir.join("robots/staubli_tx60.toml");
    let csv = dir.join("export.csv");
    let id_text = id.to_string();
    ok(&cellcal(
        &["export", "--campaign", &id_text],
        &[("--store", &store), ("--out", &csv)],
    ));
    let text = std::fs::read_to_string(&csv).expect("csv");
    for key in [
        "# stage_axis = ",
        "# tool_mm = ",
        "# stage_travel_mm = 10.0\n",
    ] {
        assert!(text.contains(key), "{key} missing:\n{}", &text[..600]);
    }
    // from the CSV: the campaign's model and base flag, setup from the header
    let from_csv = dir.join("from_csv.json");
    reidentified(&cellcal(
        &["identify", "--model", "op", "--identify-base"],
        &[("--robot", &robot), ("--data", &csv), ("--json", &from_csv)],
    ));
    let from_csv = json(&from_csv);
    assert_eq!(from_csv["parameters"], stored["parameters"]);
    assert_eq!(from_csv["metrics"], stored["metrics"]);
    assert_eq!(from_csv, stored, "the whole result");
    // straight from the store, nothing but the campaign id
    let from_store = dir.join("from_store.json");
    reidentified(&cellcal(
        &["identify", "--campaign", &id_text],
        &[("--store", &store), ("--json", &from_store)],
    ));
    assert_eq!(json(&from_store), stored);
    // the header matters: the same rows with the design setup give other numbers
    let bare: String = text
        .lines()
        .filter(|l| !l.starts_with("# stage_axis") && !l.starts_with("# tool_mm"))
        .map(|l| format!("{l}\n"))
        .collect();
    let bare_csv = dir.join("bare.csv");
    std::fs::write(&bare_csv, bare).expect("write");
    let from_bare = dir.join("from_bare.json");
    let out = cellcal(
        &["identify", "--model", "op", "--identify-base"],
        &[
            ("--robot", &robot),
            ("--data", &bare_csv),
            ("--json", &from_bare),
        ],
    );
    assert!(out.status.code().is_some());
    assert_ne!(json(&from_bare)["parameters"], stored["parameters"]);
    // a flag that contradicts the exported setup is refused, naming both
    let out = cellcal(
        &[
            "identify",
            "--model",
            "op",
            "--identify-base",
            "--stage-axis",
            "+y",
        ],
        &[("--robot", &robot), ("--data", &csv)],
    );
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--stage-axis 0,1,0 contradicts `stage_axis = ") && err.contains("export.csv"),
        "{err}"
    );
    let out = cellcal(&["identify", "--tool-mm", "0,0,60"], &[("--store", &store)]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--tool-mm 0,0,60 contradicts `tool_mm = ") && err.contains("campaign 1 in"),
        "{err}"
    );
    // equal values are fine
    reidentified(&cellcal(
        &["identify", "--stage-travel-mm", "10", "--model", "op"],
        &[("--store", &store)],
    ));
}
