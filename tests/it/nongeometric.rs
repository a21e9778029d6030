//! Non-geometric terms end to end (docs/method.md §10): a simulated campaign whose true robot
//! bends under gravity and has gear harmonics, told `[campaign] nongeometric = [...]`, stores a
//! result with the terms that verifies better than the geometric model, and `identify --store`
//! re-identifies it with the same terms.

use cellcal::store::Store;
use serde_json::Value;

use crate::campaign::{config_text, run_in_process};
use crate::reproduce::{cellcal, json};

/// The simulated cell of `config/cell.sim.toml` with the typical non-geometric errors of its
/// robot (seeded) and `campaign` added to `[campaign]`.
pub(crate) fn terms_config(campaign: &str) -> String {
    let text = config_text("", campaign, "");
    assert!(text.contains("nongeometric_errors = \"none\""));
    text.replace(
        "nongeometric_errors = \"none\"",
        "nongeometric_errors = \"typical\"",
    )
}

fn verify_rms(metrics: &Value) -> f64 {
    metrics["verify"]["after"]["position_rms_mm"]
        .as_f64()
        .expect("verification metrics")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_campaign_told_nongeometric_stores_the_terms_and_verifies_better_than_geometric() {
    let f = run_in_process(&terms_config(
        "nongeometric = [\"compliance\", \"harmonics\"]",
    ))
    .await;
    assert!(f.truth.has_terms(), "the simulated robot has terms");
    let stored = Store::open(&f.store)
        .expect("store")
        .latest_result(f.id)
        .expect("read")
        .expect("a result");
    let v: Value = serde_json::from_str(&stored).expect("JSON");
    assert_eq!(
        v["nongeometric"],
        serde_json::json!(["compliance", "harmonics"])
    );
    assert_eq!(v["nongeometric_kept"], "extended");
    let terms = v["nongeometric_terms"].as_array().expect("terms");
    assert_eq!(terms.len(), 6 * 5, "every candidate term");
    let identified = terms.iter().filter(|t| t["status"] == "identified").count();
    let (extended, geometric) = (
        verify_rms(&v["metrics"]),
        verify_rms(&v["metrics_geometric"]),
    );
    eprintln!(
        "campaign with terms: {identified} terms identified; verification rms extended \
         {extended:.5} mm, geometric {geometric:.5} mm, floor (mean) {:.5} mm",
        f.floor_mm
    );
    assert!(identified >= 15, "{identified} terms identified");
    assert!(
        extended < 0.95 * geometric,
        "extended {extended} mm, geometric {geometric} mm"
    );

    // `identify --store` re-identifies with the stored campaign's terms: the same result
    let dir = tempfile::tempdir().expect("tempdir");
    let out_json = dir.path().join("r.json");
    let out = cellcal(
        &["identify"],
        &[("--store", &f.store), ("--json", &out_json)],
    );
    assert_ne!(
        out.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let again = json(&out_json);
    assert_eq!(again["nongeometric_terms"], v["nongeometric_terms"]);
    assert_eq!(again["metrics"], v["metrics"]);
    assert_eq!(again["metrics_geometric"], v["metrics_geometric"]);
}
