//! Practical identifiability end to end: the README campaign's parameters are plausible with
//! every σ within its bound (joint 6 was nonsense: Δa6 ≈ −16 mm, Δβ6 ≈ 0.28 rad), and on real
//! UR5 data the parameters the narrow grid does not determine are held at nominal with their
//! reason, at no cost in rms.

use cellcal::store::identification_rows;
use std::path::PathBuf;

use cellcal::calibrate::{calibrate, IdentifyReport};
use cellcal::campaign::engine::identify_options;
use cellcal::dataset::{parse_csv, split, to_measured, Required};
use cellcal::identify::identifiability::{DEFAULT_MAX_SIGMA_MM, DEFAULT_MAX_SIGMA_RAD};
use cellcal::identify::{identify, predict, Measured, ObsModel};
use cellcal::model::load_robot;
use cellcal::simulate::truth::paper_errors;
use cellcal::store::Store;
use nalgebra::Vector3;

use super::campaign::{config_text, run_in_process, setup_of};
use super::cli::{identify_json, simulate};
use super::common::options;

/// The default σ bound of a parameter of unit `unit` (`mm` or `rad`).
fn bound(unit: &str) -> f64 {
    if unit == "rad" {
        DEFAULT_MAX_SIGMA_RAD
    } else {
        DEFAULT_MAX_SIGMA_MM
    }
}

fn assert_sigmas_within_bounds(r: &IdentifyReport) {
    for p in r.parameters.iter().filter(|p| p.identified) {
        let std = p.std.expect("identified has std");
        assert!(
            std <= bound(&p.unit),
            "{}: σ {std:e} {} over {:e}",
            p.name,
            p.unit,
            bound(&p.unit)
        );
    }
}

/// A parameter held back by the practical test, with its figure over its bound.
fn assert_held_back(r: &IdentifyReport, name: &str) {
    let d = r
        .not_identifiable
        .iter()
        .find(|d| d.name == name)
        .unwrap_or_else(|| panic!("{name} identified: {:?}", r.identified));
    assert!(
        d.kind == "dependent" || d.kind == "poorly_determined",
        "{name}: {d:?}"
    );
    let unit = r
        .parameters
        .iter()
        .find(|p| p.name == name)
        .map_or("", |p| p.unit.as_str());
    assert!(
        d.predicted_sigma.expect("a figure") > bound(unit),
        "{name}: {d:?}"
    );
    assert!(
        d.reason.contains("given these poses: predicted σ")
            || d.reason.starts_with("poorly determined"),
        "{d:?}"
    );
    let p = r.parameters.iter().find(|p| p.name == name).expect("row");
    assert!(!p.identified && p.error == 0.0 && p.std.is_none(), "{p:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readme_campaign_parameters_are_plausible_with_sigma_within_bounds() {
    let f = run_in_process(&config_text("", "", "")).await;
    let r = &f.report;
    assert_sigmas_within_bounds(r);
    // the stage axis is measured a few mrad off +y: β6 is formally identifiable, but a6 and
    // d6 cancel it inside the box (before: Δa6 −16 mm, Δd6 +2 mm). Held at nominal, a6 and d6
    // are plausible; their comparison with the truth is the noise-free re-fit below, because
    // the tool-frame setup measures the tool with part of them in it (d6's −0.107 mm shows up
    // as the measured tool z 59.89 mm instead of 60.0).
    assert_held_back(r, "beta6");
    let truth = paper_errors();
    for name in ["a6", "d6"] {
        let p = r.parameters.iter().find(|p| p.name == name).expect(name);
        assert!(
            p.identified && p.error.abs() < 0.2 && (p.error - truth[name]).abs() < 0.2,
            "{name}: {} vs truth {}",
            p.error,
            truth[name]
        );
    }
    // every identified MDH parameter at the truth expressed in the identified parameters: the
    // same identification on noise-free measurements of the true robot at the same poses,
    // with the campaign's own setup (measured tool and stage axis)
    let rows = Store::open(&f.store)
        .expect("store")
        .measured(f.id)
        .map(identification_rows)
        .expect("rows");
    let (ident_rows, _) = split(&rows);
    let mut opts = identify_options(&f.cfg);
    let mut nominal = f.nominal.clone();
    setup_of(&f.store, f.id).apply(&mut nominal, &mut opts.obs.stage_axis, opts.identify_base);
    let ident = to_measured(&ident_rows, opts.obs.model, f.cfg.stage.travel_mm).expect("rows");
    let clean: Vec<Measured> = ident
        .iter()
        .map(|m| {
            let t = predict(&f.truth, &m.q);
            Measured {
                p1: t.p,
                direction: Some(t.r * f.true_axis),
                ..m.clone()
            }
        })
        .collect();
    let eq = identify(&nominal, &clean, &opts).expect("noise-free identification");
    let names: Vec<String> = eq
        .identifiability
        .identified
        .iter()
        .map(|p| p.name())
        .collect();
    assert_eq!(names, r.identified);
    for p in r
        .parameters
        .iter()
        .filter(|p| p.identified && p.joint.is_some())
    {
        let e = eq
            .estimates
            .iter()
            .find(|e| e.param.name() == p.name)
            .expect("same parameters");
        let z = (p.error - e.error) / p.std.expect("std");
        assert!(
            z.abs() <= 5.0,
            "{}: {:+e} vs equivalent truth {:+e} (z {z:.1})",
            p.name,
            p.error,
            e.error
        );
    }
}

/// The UR5 files copied into the repository (with their licence and provenance).
fn ur5_dir() -> PathBuf {
    super::common::realdata_dir("ur5")
}

#[test]
fn ur5_grid_holds_back_what_it_does_not_determine_at_no_cost_in_rms() {
    let dir = ur5_dir();
    let robot = load_robot(&dir.join("robot.toml")).expect("robot");
    let text = std::fs::read_to_string(dir.join("grid.csv")).expect("csv");
    let rows = parse_csv(&text, 6, Required::default()).expect("rows");
    let mut opts = options(ObsModel::Position, Vector3::y());
    opts.identify_base = true;
    opts.identify_tool = true;
    let (r, id) = calibrate(&robot, &rows, &opts, 10.0).expect("identifies");
    // without the practical test: Δθ5 = −0.17 rad, Δd5 = +20.9 mm, Δa5 = −18.8 mm,
    // Δθ6 = 3.67 rad (condition number 1.6e7). Frame first, the tool takes θ6 (in a position
    // model it only moves the ball about axis 6, as the tool does) and the test holds joint 5's
    for name in ["a5", "alpha5"] {
        assert_held_back(&r, name);
    }
    let theta6 = r
        .not_identifiable
        .iter()
        .find(|d| d.name == "theta6")
        .expect("theta6 held");
    assert_eq!(
        (theta6.kind.as_str(), theta6.reason.as_str()),
        ("structural", "dependent on tool_x")
    );
    let error = |n: &str| r.parameters.iter().find(|p| p.name == n).map(|p| p.error);
    assert!(
        error("theta5").is_some_and(|e| e.abs() < 5e-3),
        "{:?}",
        error("theta5")
    );
    assert!(
        error("d5").is_some_and(|e| e.abs() < 1.0),
        "{:?}",
        error("d5")
    );
    // every identified parameter predicted within its bound at the a-priori noise
    for (p, s) in id
        .identifiability
        .identified
        .iter()
        .zip(&id.identifiability.predicted_sigma)
    {
        assert!(*s <= bound(p.unit()), "{}: predicted σ {s:e}", p.name());
    }
    assert!(r.condition_number < 1e4, "condition {}", r.condition_number);
    // the reference least-squares optimum with all 27 parameters: ident rms 0.1124 mm
    let rms = r.metrics.ident.after.position_rms_mm;
    assert!(rms <= 1.01 * 0.1124, "ident rms after {rms}");
}

#[test]
fn identify_flags_set_the_bounds_and_bad_values_exit_2() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate(dir.path(), &[]);
    let json = dir.path().join("r.json");
    let run = |extra: &[&str]| {
        identify_json(&data, "op", &json)
            .args(extra)
            .output()
            .expect("runs")
    };
    // 40 poses: a 1 µm bound holds lengths back, each with its kind and figure
    let ok = identify_json(&data, "op", &json)
        .args(["--max-sigma-mm", "0.001"])
        .assert()
        .success();
    let text = String::from_utf8_lossy(&ok.get_output().stdout);
    assert!(
        text.contains("Held at nominal: not determined by these poses:"),
        "{text}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let held: Vec<&serde_json::Value> = v["not_identifiable"]
        .as_array()
        .expect("array")
        .iter()
        .filter(|d| d["kind"] != "structural")
        .collect();
    assert!(!held.is_empty(), "{v}");
    for d in &held {
        assert!(
            d["predicted_sigma"].as_f64().is_some_and(|s| s > 0.001),
            "{d}"
        );
        assert!(["dependent", "poorly_determined"].contains(&d["kind"].as_str().unwrap_or("")));
    }
    let beta1 = v["not_identifiable"]
        .as_array()
        .and_then(|a| a.iter().find(|d| d["name"] == "beta1"))
        .expect("beta1 listed");
    assert_eq!(beta1["kind"], "structural");
    assert!(beta1["predicted_sigma"].is_null());
    for (extra, want) in [
        (&["--max-sigma-mm", "0"][..], "--max-sigma-mm"),
        (
            &["--max-sigma-mrad", "NaN"][..],
            "must be a finite number > 0",
        ),
        (&["--noise-mm", "-0.01"][..], "must be a finite number ≥ 0"),
        (
            &["--noise-mm", "0.01", "--tracker-weights", "0,0,0"][..],
            "--noise-mm conflicts with --tracker-weights",
        ),
    ] {
        let out = run(extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(want), "{extra:?}: {err}");
    }
}
