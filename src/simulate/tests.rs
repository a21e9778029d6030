//! Unit tests of the data simulator: the AT960 noise figure, the error tables, and what a
//! simulated data set is (seeded, split, noise-free geometry exact).

use nalgebra::Vector3;

use super::truth::{
    apply_errors, apply_terms, paper_errors, random_errors, typical_terms, TermErrors,
    PAPER_ERRORS, TYPICAL_COMPLIANCE_RAD_PER_NM,
};
use super::{simulate, SimConfig, TrackerNoise};
use crate::dataset::PoseSet;
use crate::model::kinematics::forward;
use crate::model::TermKind;

#[test]
fn at960_sigma_is_half_of_15_um_plus_6_um_per_metre() {
    let n = TrackerNoise::at960(Vector3::new(1000.0, 0.0, 0.0));
    assert!((n.sigma_mm(&Vector3::new(1000.0, 0.0, 0.0)) - 0.0075).abs() < 1e-15);
    // 2.5 m away: (15 + 15) / 2 µm
    assert!((n.sigma_mm(&Vector3::new(1000.0, 2500.0, 0.0)) - 0.015).abs() < 1e-15);
}

#[test]
fn the_paper_table_names_every_mdh_parameter_of_the_six_joints() {
    let t = paper_errors();
    assert_eq!(t.len(), 30);
    assert_eq!(t["theta1"], PAPER_ERRORS[0][0]);
    assert_eq!(t["a2"], 0.299495);
    assert_eq!(t["beta2"], 1.79e-5);
    assert_eq!(t["d6"], -0.10686);
}

#[test]
fn random_errors_are_seeded_and_of_the_stated_size() {
    let a = random_errors(6, 11);
    assert_eq!(a, random_errors(6, 11));
    assert_ne!(a, random_errors(6, 12));
    assert_eq!(a.len(), 30);
    let rms = |angle: bool| {
        let v: Vec<f64> = a
            .iter()
            .filter(|(k, _)| {
                (k.starts_with("theta") || k.starts_with("alpha") || k.starts_with("beta")) == angle
            })
            .map(|(_, v)| *v)
            .collect();
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    };
    // σ = 0.2 mm and 0.5 mrad: 12 lengths and 18 angles stay within a factor 2.5
    assert!((0.08..0.5).contains(&rms(false)), "lengths {}", rms(false));
    assert!((2e-4..1.25e-3).contains(&rms(true)), "angles {}", rms(true));
}

#[test]
fn applying_errors_moves_the_named_parameters_and_refuses_unknown_or_nan_ones() {
    let nominal = crate::model::tx60();
    let same = apply_errors(&nominal, &Default::default()).expect("no errors");
    assert_eq!(same.joints, nominal.joints);
    let t = [("d3".to_owned(), 0.25), ("theta5".to_owned(), -0.001)]
        .into_iter()
        .collect();
    let m = apply_errors(&nominal, &t).expect("errors");
    assert!((m.joints[2].d - nominal.joints[2].d - 0.25).abs() < 1e-12);
    assert!((m.joints[4].theta - nominal.joints[4].theta + 0.001).abs() < 1e-12);
    assert_eq!(m.joints[0], nominal.joints[0]);
    let unknown = [("d7".to_owned(), 1.0)].into_iter().collect();
    assert_eq!(
        apply_errors(&nominal, &unknown).expect_err("unknown"),
        "unknown parameter `d7`"
    );
    let nan = [("a1".to_owned(), f64::NAN)].into_iter().collect();
    assert!(apply_errors(&nominal, &nan)
        .expect_err("nan")
        .contains("not a finite number"));
}

#[test]
fn a_simulated_set_is_seeded_split_and_without_noise_exactly_the_true_geometry() {
    let nominal = crate::model::tx60();
    let cfg = SimConfig {
        poses: 12,
        ident: 8,
        tracker: None,
        joint_jitter_rad: 0.0,
        ..SimConfig::default()
    };
    let a = simulate(&nominal, &nominal, &cfg).expect("poses");
    let sets: Vec<PoseSet> = a.observations.iter().map(|o| o.set).collect();
    assert_eq!(sets.iter().filter(|s| **s == PoseSet::Ident).count(), 8);
    assert!(sets[..8].iter().all(|s| *s == PoseSet::Ident));
    assert!(a.outliers.is_empty());
    for o in &a.observations {
        let fl = *forward(&nominal, &o.q).flange();
        let ball =
            nominal.base_rotation * fl.transform_point(&nominal.tool) + nominal.base_translation;
        assert!((o.p1 - ball).norm() < 1e-9, "pose {}", o.id);
        let travel = o.p2.expect("P2") - o.p1;
        let along = nominal.base_rotation * fl.r * Vector3::y() * cfg.stage_travel_mm;
        assert!((travel - along).norm() < 1e-9, "pose {}", o.id);
    }
    // noise and outliers: the same seed gives the same bits, another seed other data
    let noisy = SimConfig {
        poses: 12,
        ident: 8,
        outlier_fraction: 0.25,
        ..SimConfig::default()
    };
    let b = simulate(&nominal, &nominal, &noisy).expect("poses");
    let c = simulate(&nominal, &nominal, &noisy).expect("poses");
    assert_eq!(b.outliers.len(), 3);
    assert_eq!(b.outliers, c.outliers);
    assert!(b
        .observations
        .iter()
        .zip(&c.observations)
        .all(|(x, y)| x == y));
    let d = simulate(&nominal, &nominal, &SimConfig { seed: 1, ..noisy }).expect("poses");
    assert_ne!(b.observations[0].p1, d.observations[0].p1);
}

#[test]
fn error_tables_name_non_geometric_terms_too_and_a_compliance_needs_masses() {
    let nominal = crate::model::tx60();
    let t = [
        ("compliance2".to_owned(), 4e-6),
        ("sin_q3".to_owned(), 2e-5),
        ("d3".to_owned(), 0.25),
    ]
    .into_iter()
    .collect();
    let m = apply_errors(&nominal, &t).expect("errors");
    assert_eq!(m.term(1, TermKind::Compliance), 4e-6);
    assert_eq!(m.term(2, TermKind::SinQ), 2e-5);
    assert_eq!(m.term(0, TermKind::CosQ), 0.0);
    // the terms move the chain: a pose where joint 2 carries torque sees both
    let q = [0.3, 0.8, 1.2, 0.1, 0.6, -0.4];
    let geometric =
        apply_errors(&nominal, &[("d3".to_owned(), 0.25)].into_iter().collect()).expect("errors");
    let moved = (forward(&m, &q).flange().p - forward(&geometric, &q).flange().p).norm();
    assert!(moved > 0.05, "terms move the flange by {moved} mm");
    // plain MDH tables leave the model without terms
    assert!(paper_model_has_no_terms());
    let bare = crate::model::RobotModel {
        masses: Vec::new(),
        ..nominal.clone()
    };
    assert!(apply_errors(&bare, &t)
        .expect_err("no masses")
        .contains("[[masses]]"));
    let bad = [("sin_q7".to_owned(), 1e-5)].into_iter().collect();
    assert_eq!(
        apply_errors(&nominal, &bad).expect_err("joint 7"),
        "unknown parameter `sin_q7`"
    );
}

fn paper_model_has_no_terms() -> bool {
    let m = apply_errors(&crate::model::tx60(), &paper_errors()).expect("paper");
    m.terms.is_empty()
}

#[test]
fn typical_terms_are_seeded_give_loaded_joints_a_compliance_and_explicit_ones_are_checked() {
    let nominal = crate::model::tx60();
    let a = typical_terms(&nominal, 3);
    assert_eq!(a, typical_terms(&nominal, 3));
    assert_ne!(a, typical_terms(&nominal, 4));
    assert_eq!(a.len(), 6);
    let levers = crate::model::gravity_levers(&nominal);
    assert_eq!(levers, [false, true, true, true, true, false]);
    let (lo, hi) = TYPICAL_COMPLIANCE_RAD_PER_NM;
    for (t, lever) in a.iter().zip(&levers) {
        assert_eq!(*lever, (lo..=hi).contains(&t.compliance), "{a:?}");
        assert!(*lever || t.compliance == 0.0);
        assert!(t.harmonics.iter().all(|h| h.abs() < 2e-4 && *h != 0.0));
    }
    let m = apply_terms(
        &nominal,
        &TermErrors {
            typical_seed: Some(3),
            ..TermErrors::default()
        },
    )
    .expect("typical");
    assert_eq!(m.terms, a);
    assert_eq!(
        apply_terms(&nominal, &TermErrors::default()).expect("none"),
        nominal
    );
    let explicit = TermErrors {
        compliance_rad_per_nm: Some(vec![0.0, 4e-6, 5e-6, 0.0, 0.0, 0.0]),
        harmonics_rad: Some(vec![[1e-5, 0.0, 0.0, -2e-5]; 6]),
        typical_seed: None,
    };
    let m = apply_terms(&m, &explicit).expect("explicit on top of typical ones");
    assert_eq!(m.term(1, TermKind::Compliance), a[1].compliance + 4e-6);
    assert_eq!(m.term(5, TermKind::Cos2Q), a[5].harmonics[3] - 2e-5);
    for (bad, want) in [
        (
            TermErrors {
                compliance_rad_per_nm: Some(vec![0.0; 5]),
                ..TermErrors::default()
            },
            "compliance: 5 values for 6 joints",
        ),
        (
            TermErrors {
                compliance_rad_per_nm: Some(vec![0.0, -1e-6, 0.0, 0.0, 0.0, 0.0]),
                ..TermErrors::default()
            },
            "compliance: joint 2: -0.000001 is not a compliance",
        ),
        (
            TermErrors {
                harmonics_rad: Some(vec![[0.0, f64::NAN, 0.0, 0.0]; 6]),
                ..TermErrors::default()
            },
            "harmonics: joint 1: not a finite number",
        ),
        (
            TermErrors {
                typical_seed: Some(1),
                ..explicit.clone()
            },
            "not both",
        ),
    ] {
        let e = apply_terms(&nominal, &bad).expect_err(want);
        assert!(e.contains(want), "{e}");
    }
    let massless = crate::model::RobotModel {
        masses: Vec::new(),
        ..nominal
    };
    assert!(apply_terms(&massless, &explicit)
        .expect_err("no masses")
        .contains("[[masses]]"));
}
