//! The corrected model (`--model-out`, `GET /api/campaigns/{id}/model`): its forward
//! kinematics equal the identified model's, identifying the same data from it reproduces the
//! original result, every command loads it, and bad cases are clear errors.

use std::path::Path;

use cellcal::calibrate::{calibrate, calibrate_result, corrected_model, BaseSource};
use cellcal::identify::ObsModel;
use cellcal::model::kinematics::{measured_point, measured_rotation};
use cellcal::model::rotation::{from_rotation_vector, log_so3};
use cellcal::model::{parse_robot, RobotModel};
use cellcal::report::corrected_model_toml;
use cellcal::simulate::SimConfig;
use nalgebra::Vector3;
use serde_json::Value;

use crate::cli::{cellcal, identify_json, simulate};
use crate::common::{options, paper_truth, sim, tx60};

/// Largest tool position (mm) and flange orientation (rad) difference of two models over the
/// generic poses.
fn fk_difference(a: &RobotModel, b: &RobotModel) -> (f64, f64) {
    cellcal::identify::generic_poses(a, 500)
        .iter()
        .map(|q| {
            let dp = (measured_point(a, q) - measured_point(b, q)).norm();
            let dr =
                log_so3(&(measured_rotation(a, q) * measured_rotation(b, q).transpose())).norm();
            (dp, dr)
        })
        .fold((0.0, 0.0), |(p, r), (dp, dr)| {
            (f64::max(p, dp), f64::max(r, dr))
        })
}

#[test]
fn the_model_file_has_the_identified_kinematics_and_reidentifies_to_the_same_result() {
    // a base far from the robot's and rotated, identified with the MDH errors
    let mut truth = paper_truth();
    truth.base_translation = Vector3::new(2100.0, -350.0, 120.0);
    truth.base_rotation = from_rotation_vector(&Vector3::new(0.01, -0.02, 2.5));
    truth.tool = Vector3::new(0.5, 40.0, 60.0);
    let cfg = SimConfig {
        poses: 160,
        ident: 100,
        ..SimConfig::default()
    };
    let data = sim(&truth, &cfg);
    let mut opts = options(ObsModel::Op, Vector3::y());
    opts.identify_base = true;
    let mut nominal = tx60();
    nominal.tool = truth.tool;
    let (report, id) = calibrate_result(
        &nominal,
        &data.observations,
        &opts,
        10.0,
        BaseSource::Identified,
    )
    .expect("identifies");

    // the file, read back, is the identified model
    let text = corrected_model_toml(
        &report,
        &nominal,
        &["Data: test".into()],
        BaseSource::Identified,
    )
    .expect("writes");
    let file = parse_robot(&text, Path::new("identified.toml")).expect("reads back");
    let (dp, dr) = fk_difference(&file, &id.corrected);
    assert!(
        dp < 1e-9 && dr < 1e-12,
        "FK differs by {dp:e} mm, {dr:e} rad"
    );
    assert_eq!(file.limits, nominal.limits, "limits kept");
    assert_eq!(file.name, "Staubli TX60 (identified)");
    let (before, _) = fk_difference(&nominal, &id.corrected);
    assert!(
        before > 1000.0,
        "the nominal model is elsewhere: {before} mm"
    );
    for line in [
        "# Data: test",
        "# Base: identified from the measurements, so this model's frame is the measurement (laser tracker) frame",
        "# Held at nominal (not identified): ",
        "beta1 (structural)",
        "theta1 (structural)",
        "d1 (structural)",
    ] {
        assert!(text.contains(line), "{line}\n{text}");
    }

    // the same data identified from the file (its base is the tracker frame, so it is given,
    // not identified): before = the original after, nothing left to fit
    let held = cellcal::identify::IdentifyOptions {
        identify_base: false,
        ..opts
    };
    let (again, _) = calibrate(&file, &data.observations, &held, 10.0).expect("identifies");
    for (set, a, b) in [
        (
            "ident",
            &again.metrics.ident.before,
            &report.report.metrics.ident.after,
        ),
        (
            "verify",
            &again.metrics.verify.as_ref().unwrap().before,
            &report.report.metrics.verify.as_ref().unwrap().after,
        ),
    ] {
        assert!(
            (a.position_mean_mm - b.position_mean_mm).abs() < 1e-9
                && (a.position_max_mm - b.position_max_mm).abs() < 1e-9,
            "{set}: before {a:?} vs original after {b:?}"
        );
    }
    for p in again.parameters.iter().filter(|p| p.identified) {
        let bound = if p.unit == "mm" { 1e-4 } else { 1e-7 };
        assert!(p.error.abs() < bound, "{} moved by {}", p.name, p.error);
    }

    // a result that does not fit the nominal model is refused, naming why
    let mut two = nominal.clone();
    two.joints.truncate(2);
    two.limits.truncate(2);
    let e = corrected_model(&report, &two).unwrap_err().to_string();
    assert_eq!(
        e,
        "the result has parameters of 6 joints, the nominal model has 2"
    );
    let mut gap = report.clone();
    gap.corrected.values.retain(|v| v.param.name() != "d3");
    let e = corrected_model(&gap, &nominal).unwrap_err().to_string();
    assert_eq!(e, "the result does not give `d3` exactly once");
}

#[test]
fn identify_model_out_loads_as_robot_everywhere() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = simulate(dir.path(), &[]);
    let json = dir.path().join("r.json");
    let model = dir.path().join("identified.toml");
    identify_json(&data, "op", &json)
        .arg("--model-out")
        .arg(&model)
        .assert()
        .success();
    let text = std::fs::read_to_string(&model).expect("model written");
    let data_text = std::fs::read_to_string(&data).expect("data");
    let sha = cellcal::report::model_file::sha256_hex(data_text.as_bytes());
    assert!(
        text.contains(&format!("# Data: {} (sha256 {sha})", data.display())),
        "{text}"
    );
    assert!(text.contains("# Nominal model: ") && text.contains("staubli_tx60.toml (sha256 "));
    assert!(text.contains("Base: the nominal model's"), "{text}");
    // deterministic: the same command writes the same bytes
    let model2 = dir.path().join("again.toml");
    identify_json(&data, "op", &json)
        .arg("--model-out")
        .arg(&model2)
        .assert()
        .success();
    assert_eq!(std::fs::read(&model2).unwrap(), text.as_bytes());

    // identify with it as --robot: before = the original after
    let first: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let json2 = dir.path().join("r2.json");
    cellcal()
        .args(["identify", "--robot"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .args(["--model", "op", "--json"])
        .arg(&json2)
        .assert()
        .success();
    let second: Value = serde_json::from_str(&std::fs::read_to_string(&json2).unwrap()).unwrap();
    for set in ["ident", "verify"] {
        let a = second["metrics"][set]["before"]["position_mean_mm"]
            .as_f64()
            .unwrap();
        let b = first["metrics"][set]["after"]["position_mean_mm"]
            .as_f64()
            .unwrap();
        assert!(
            (a - b).abs() < 1e-9,
            "{set}: before {a} vs original after {b}"
        );
    }
    // significance and simulate-data take it too
    cellcal()
        .args(["significance", "--samples", "5", "--robot"])
        .arg(&model)
        .arg("--json")
        .arg(dir.path().join("s.json"))
        .assert()
        .success();
    cellcal()
        .args(["simulate-data", "--poses", "20", "--ident", "10", "--robot"])
        .arg(&model)
        .arg("--out")
        .arg(dir.path().join("d2.csv"))
        .assert()
        .success();

    // an unwritable --model-out is exit 1 naming the path; the JSON is still written
    let bad = dir.path().join("no/such/dir/m.toml");
    let out = identify_json(&data, "op", &json)
        .arg("--model-out")
        .arg(&bad)
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no/such/dir/m.toml: cannot write"), "{err}");
    // a damaged file is refused naming the key
    let damaged = dir.path().join("damaged.toml");
    std::fs::write(&damaged, text.replacen("d_mm = ", "d_mm = nan #", 1)).unwrap();
    let out = cellcal()
        .args(["significance", "--robot"])
        .arg(&damaged)
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("joints[1].d_mm: nan is not a finite number"),
        "{err}"
    );
}

/// A model file with non-geometric terms (docs/method.md §10): the result's term values are
/// written per joint with the masses and gravity of the nominal model the identification used,
/// and the file loads back (`load_robot`) to the same model — same terms, masses, gravity and
/// forward kinematics; a geometric result's file has none of the keys.
#[test]
fn the_model_file_carries_the_terms_with_their_masses_and_gravity_and_loads_back() {
    use cellcal::calibrate::ParamValue;
    use cellcal::identify::params::ParamId;
    use cellcal::model::{load_robot, Mass, TermKind};
    let truth = paper_truth();
    let data = sim(
        &truth,
        &SimConfig {
            poses: 120,
            ident: 80,
            ..SimConfig::default()
        },
    );
    let opts = options(ObsModel::Op, Vector3::y());
    let mut nominal = tx60();
    nominal.tool = truth.tool;
    nominal.gravity = Vector3::new(0.0, 0.6, -0.8);
    nominal.masses = vec![
        Mass {
            frame: 2,
            at: Vector3::new(-150.0, 0.0, 120.0),
            kg: 8.4,
        },
        Mass {
            frame: 6,
            at: Vector3::new(0.0, 0.0, 30.0 + 1.0 / 3.0),
            kg: 0.35,
        },
    ];
    let (mut result, id) = calibrate_result(
        &nominal,
        &data.observations,
        &opts,
        10.0,
        BaseSource::Nominal,
    )
    .expect("identifies");
    let geometric =
        corrected_model_toml(&result, &nominal, &[], BaseSource::Nominal).expect("writes");
    for key in ["compliance", "harmonics", "Non-geometric"] {
        assert!(
            !geometric.contains(key),
            "{key} in a geometric file:\n{geometric}"
        );
    }

    // the terms as an extended identification keeps them in its corrected model
    let terms = [
        (1, TermKind::Compliance, 2.0e-6 + 1.0 / 3.0 * 1e-7),
        (2, TermKind::Compliance, -7.5e-7),
        (0, TermKind::SinQ, 1.0 / 7.0 * 1e-3),
        (2, TermKind::Cos2Q, -2.5e-4),
        (4, TermKind::Sin2Q, 3.0e-5),
    ];
    let mut expected = id.corrected.clone();
    for (joint, kind, value) in terms {
        result.corrected.values.push(ParamValue {
            param: ParamId::Term { joint, kind },
            value,
        });
        *expected.term_mut(joint, kind) = value;
    }
    // compliances keep the chain they were identified on: the nominal one
    expected.torque_chain = Some(nominal.joints.clone());
    let text = corrected_model_toml(
        &result,
        &nominal,
        &["Data: test".into()],
        BaseSource::Nominal,
    )
    .expect("writes");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("identified.toml");
    std::fs::write(&path, &text).unwrap();
    let file = load_robot(&path).expect("loads back");
    assert_eq!(file.terms, expected.terms, "{text}");
    assert_eq!(file.masses, nominal.masses, "{text}");
    assert_eq!(file.gravity, nominal.gravity, "{text}");
    assert_eq!(file.torque_chain, expected.torque_chain, "{text}");
    let (dp, dr) = fk_difference(&file, &expected);
    assert!(
        dp < 1e-9 && dr < 1e-12,
        "FK differs by {dp:e} mm, {dr:e} rad"
    );
    // the terms matter: without them the model is elsewhere
    let (apart, _) = fk_difference(&file, &id.corrected);
    assert!(apart > 0.05, "the terms move the tool by {apart} mm");
    for line in [
        "# Non-geometric terms (docs/method.md §10): compliance_rad_per_nm on joints 2, 3, \
         harmonics_rad on joints 1, 3, 5; gravity torques from the 2 [[masses]]",
        "on the chain it started from ([[torque_chain]])",
        "\n[[torque_chain]]\ntheta_rad = ",
        "compliance_rad_per_nm = ",
        "harmonics_rad = [",
        "[[masses]]",
        "gravity = [0.0, 0.6, -0.8]",
    ] {
        assert!(text.contains(line), "{line}\n{text}");
    }
    // the same bytes again, and what is written is what was identified
    assert_eq!(
        corrected_model_toml(
            &result,
            &nominal,
            &["Data: test".into()],
            BaseSource::Nominal
        )
        .unwrap(),
        text
    );
    // a term of a joint the nominal model does not have is refused
    result.corrected.values.push(ParamValue {
        param: ParamId::Term {
            joint: 6,
            kind: TermKind::SinQ,
        },
        value: 1e-4,
    });
    let e = corrected_model_toml(&result, &nominal, &[], BaseSource::Nominal).unwrap_err();
    assert_eq!(
        e.to_string(),
        "the result has parameters of 7 joints, the nominal model has 6"
    );
}
