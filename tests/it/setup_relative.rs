//! What a parameter is relative to, and one "before", on the README campaign against its
//! simulated truth: the parameters whose identified value misses the truth by many σ are
//! exactly those the measured tool and stage axis absorb, and they are marked so (JSON status,
//! CLI table, report); the live deviation of every measured pose, the result's "before" and
//! the report's text use one named base, the setup's registration.

use cellcal::calibrate::ParamStatus;
use cellcal::campaign::report::campaign_report;
use cellcal::dataset::PoseSet;
use cellcal::identify::BeforeBase;
use cellcal::model::ParamKind;
use cellcal::report::summary_text;
use cellcal::store::identification_rows;
use cellcal::store::Store;

use super::campaign::{config_text, run_in_process};

/// The true error of MDH parameter `kind` of joint `joint` (1-based): truth − nominal.
fn true_error(
    truth: &cellcal::model::RobotModel,
    nominal: &cellcal::model::RobotModel,
    joint: usize,
    kind: &str,
) -> f64 {
    let k = match kind {
        "theta" => ParamKind::Theta,
        "d" => ParamKind::D,
        "a" => ParamKind::A,
        "alpha" => ParamKind::Alpha,
        "beta" => ParamKind::Beta,
        other => panic!("kind {other}"),
    };
    truth.joints[joint - 1].get(k) - nominal.joints[joint - 1].get(k)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readme_campaign_marks_what_the_setup_absorbs_and_names_one_before() {
    let f = run_in_process(&config_text("", "", "")).await;
    let r = &f.report;

    // 12: every identified robot parameter far from the truth is marked relative to the setup
    // (and the marked ones are those of the tool frame's wrist)
    let relative: Vec<&str> = r.setup_relative.iter().map(|d| d.name.as_str()).collect();
    let mut far = Vec::new();
    for p in r.parameters.iter().filter(|p| p.joint.is_some()) {
        let marked = relative.contains(&p.name.as_str());
        let want = match (p.identified, marked) {
            (false, _) => ParamStatus::NotIdentified,
            (true, true) => ParamStatus::SetupRelative,
            (true, false) => ParamStatus::Identified,
        };
        assert_eq!(p.status, want, "{}", p.name);
        if !p.identified {
            continue;
        }
        let truth = true_error(&f.truth, &f.nominal, p.joint.expect("joint"), &p.kind);
        let z = (p.error - truth).abs() / p.std.expect("σ");
        if z > 5.0 {
            far.push(p.name.clone());
            assert!(
                marked,
                "{}: {:+e} ± {:e} vs truth {truth:+e} (|z| {z:.0}) not marked relative to the setup",
                p.name,
                p.error,
                p.std.unwrap_or(0.0)
            );
        }
    }
    assert!(
        !far.is_empty(),
        "the setup absorbs part of the wrist's errors"
    );
    for name in ["alpha6", "theta6"] {
        assert!(relative.contains(&name), "{name}: {relative:?}");
    }
    for d in &r.setup_relative {
        assert!(
            d.reason
                .starts_with("relative to the setup's tool and stage axis: were they free"),
            "{d:?}"
        );
    }
    let text = summary_text(r);
    assert!(text.contains("* Relative to the setup:"), "{text}");
    assert!(text.contains("given the setup"), "{text}");
    assert!(
        text.contains("before = the nominal model with the tool in use and the setup's base registration (before_base: setup_registration)"),
        "{text}"
    );

    // 13: one before. The live deviation of the identification poses, the result's before and
    // the report's text: the setup's registration
    assert_eq!(r.before_base, Some(BeforeBase::SetupRegistration));
    let store = Store::open(&f.store).expect("store");
    let ident: Vec<String> = store
        .measured(f.id)
        .map(identification_rows)
        .expect("rows")
        .into_iter()
        .filter(|o| o.set == PoseSet::Ident)
        .map(|o| o.id)
        .collect();
    let live: Vec<f64> = store
        .events::<cellcal::campaign::CampaignEvent>(f.id)
        .expect("events")
        .iter()
        .filter(|e| e.event.kind() == "measured")
        .map(|e| serde_json::to_value(&e.event).expect("JSON"))
        .filter(|m| ident.contains(&m["pose"].to_string()))
        .map(|m| m["deviation_mm"].as_f64().expect("deviation_mm"))
        .collect();
    assert_eq!(live.len(), ident.len());
    let live_mean = live.iter().sum::<f64>() / live.len() as f64;
    let before = r.metrics.ident.before.position_mean_mm;
    assert!(
        (live_mean - before).abs() < 1e-6,
        "live mean deviation {live_mean:.6} mm vs the result's before {before:.6} mm"
    );
    let input = campaign_report(&store, f.id, "c.db", 0)
        .expect("report")
        .expect("a result");
    let html = cellcal::report::html::render(&input);
    assert!(
        html.contains(
            "before = nominal model with the setup's tool and <span id=\"before-base\">the \
             setup&#39;s base registration (<code>before_base</code> = <span \
             data-json=\"/before_base\" data-value=\"setup_registration\">"
        ),
        "the report names the before's base"
    );
    assert!(html.contains("id=\"setup-relative-note\""));
    assert!(html.contains("identified, relative to the setup"));
    println!(
        "before (live = result) {before:.4} mm; relative to the setup: {relative:?}; far from the truth: {far:?}"
    );
}
