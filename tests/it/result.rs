//! The typed calibration result: a campaign stores it once (contract, per-pose residuals,
//! corrected model) and every view renders the stored one — the report's per-pose errors and
//! the corrected model come from the store, not from identifying again; a result stored by an
//! earlier cellcal (the contract alone) still reports; the stored result renders byte for byte
//! the `identify` JSON of its exported CSV.

use std::path::{Path, PathBuf};

use cellcal::calibrate::result::RESULT_LAYOUT;
use cellcal::calibrate::CalibrationResult;
use cellcal::campaign::report::campaign_report;
use cellcal::campaign::stored::{stored_model_toml, stored_result, stored_result_json};
use cellcal::campaign::Outcome;
use cellcal::identify::ParamId;
use cellcal::model::{parse_robot, ParamKind};
use cellcal::store::Store;

use crate::campaign::{config_text, run_steered};
use crate::reproduce::{cellcal, ok};

/// A 40-pose campaign (20 ident, 20 verify) on the simulated cell: its store and id.
async fn campaign() -> (PathBuf, i64) {
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 40")
        .replace("ident = 100", "ident = 20");
    let (outcome, store, id) = run_steered(&text, |_, _, _| {}).await;
    assert!(matches!(outcome, Outcome::Done(_)), "{outcome:?}");
    (store, id)
}

fn stored(s: &Store, id: i64) -> CalibrationResult {
    stored_result(s, id)
        .expect("reads")
        .expect("a stored result")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn report_and_model_render_the_stored_result_and_never_identify_again() {
    let (path, id) = campaign().await;
    let mut s = Store::open(&path).expect("store");
    let mut r = stored(&s, id);
    assert_eq!(r.layout, RESULT_LAYOUT);
    let residuals = r.residuals.as_mut().expect("residuals stored");
    assert_eq!(residuals.ident.ids.len(), 20);
    assert_eq!(residuals.verify.as_ref().expect("verify set").ids.len(), 20);
    // a stored result no identification of these measurements gives: the views must show it
    residuals.ident.after[0].position_mm = [0.125, -0.25, 0.5];
    let d3 = ParamId::Mdh {
        joint: 2,
        kind: ParamKind::D,
    };
    let v = r
        .corrected
        .values
        .iter_mut()
        .find(|v| v.param == d3)
        .expect("d3 in the corrected model");
    v.value += 0.75;
    let d3_value = v.value;
    s.save_result_as(id, "op", &r).expect("stored again");

    let input = campaign_report(&s, id, "c.db", 0)
        .expect("report")
        .expect("a result");
    let poses = input.poses.expect("per-pose errors");
    assert_eq!(poses.ident.after[0].position_mm, [0.125, -0.25, 0.5]);
    assert_eq!(&poses, r.residuals.as_ref().expect("residuals"));
    assert!(input.notes.is_empty(), "{:?}", input.notes);

    let toml = stored_model_toml(&s, id).expect("model").expect("a result");
    let model = parse_robot(&toml, Path::new("m.toml")).expect("reads back");
    assert_eq!(
        model.joints[2].d, d3_value,
        "the stored corrected model's d3"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_result_stored_by_an_earlier_cellcal_still_reports() {
    let (path, id) = campaign().await;
    let mut s = Store::open(&path).expect("store");
    let new = stored(&s, id);
    let model = stored_model_toml(&s, id).expect("model").expect("a result");
    let contract = stored_result_json(&s, id).expect("json").expect("a result");
    // what the code before the typed result stored: the identify JSON alone
    let old_text = new.identify_json().expect("contract");
    s.save_result(id, "op", &old_text).expect("stored");

    let old = stored(&s, id);
    assert_eq!(old.layout, 0);
    assert!(old.residuals.is_none());
    assert_eq!(old.identify_json().expect("contract"), old_text);
    assert_eq!(old.corrected.values, new.corrected.values);
    assert_eq!(
        stored_model_toml(&s, id).expect("model").expect("a result"),
        model,
        "the same corrected model file"
    );
    assert_eq!(
        stored_result_json(&s, id).expect("json").expect("a result"),
        contract
    );
    assert_eq!(
        s.result_quality(id).expect("quality"),
        Some(new.report.quality.as_str().to_owned())
    );

    // the report: the per-pose errors evaluated from the stored corrected model, said so
    let input = campaign_report(&s, id, "c.db", 0)
        .expect("report")
        .expect("a result");
    assert!(
        input.notes.iter().any(|n| n.contains("earlier cellcal")),
        "{:?}",
        input.notes
    );
    let poses = input.poses.clone().expect("per-pose errors evaluated");
    let want = new.residuals.as_ref().expect("residuals");
    let sets = [
        (&poses.ident, &want.ident),
        (
            poses.verify.as_ref().expect("verify"),
            want.verify.as_ref().expect("verify"),
        ),
    ];
    for (got, want) in sets {
        assert_eq!(got.ids, want.ids);
        for (g, w) in got
            .before
            .iter()
            .zip(&want.before)
            .chain(got.after.iter().zip(&want.after))
        {
            for k in 0..3 {
                assert!(
                    (g.position_mm[k] - w.position_mm[k]).abs() < 1e-9,
                    "{g:?} vs {w:?}"
                );
            }
        }
    }
    // and the page renders, with its plots
    let html = cellcal::report::html::render(&input);
    assert!(html.contains("<svg"), "plots");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stored_result_is_byte_for_byte_the_identify_json_of_its_export() {
    let (store, id) = campaign().await;
    let dir = store.parent().expect("dir").to_owned();
    let r = stored(&Store::open(&store).expect("store"), id);
    let stored_json = r.identify_json().expect("contract");
    let verdict_exit = if r.report.quality == cellcal::calibrate::Quality::Poor {
        3
    } else {
        0
    };
    let csv = dir.join("export.csv");
    ok(&cellcal(
        &["export", "--campaign", &id.to_string()],
        &[("--store", &store), ("--out", &csv)],
    ));
    let from_csv = dir.join("from_csv.json");
    let out = cellcal(
        &["identify", "--model", "op", "--identify-base"],
        &[
            ("--robot", &dir.join("robots/staubli_tx60.toml")),
            ("--data", &csv),
            ("--json", &from_csv),
        ],
    );
    assert_eq!(out.status.code(), Some(verdict_exit));
    assert_eq!(
        std::fs::read_to_string(&from_csv).expect("written"),
        stored_json,
        "identify on the exported CSV writes the stored result's JSON"
    );
    // the REST body is the same document
    let rest = stored_result_json(&Store::open(&store).expect("store"), id)
        .expect("json")
        .expect("a result");
    let file: serde_json::Value = serde_json::from_str(&stored_json).expect("JSON");
    assert_eq!(rest, file);
}
