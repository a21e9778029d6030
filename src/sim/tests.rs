//! Unit tests of the simulated cell's pieces that need no server: the `[sim]` helpers (VAL3
//! angles, error tables, the true model, effective timings) and the
//! [`World`]'s physics and faults.

use nalgebra::{Matrix3, Rotation3, Vector3};
use robotlink::ErrorCode;

use super::world::{val3_angles_deg, StageSource, World};
use super::{load_error_table, true_model, SimError, SimWorldConfig};
use crate::model::kinematics::forward;
use crate::simulate::truth::{paper_errors, random_errors};

#[test]
fn val3_angles_are_x_then_y_then_z() {
    let (rx, ry, rz) = (10.0_f64, -20.0_f64, 30.0_f64);
    let r: Matrix3<f64> = (Rotation3::from_axis_angle(&Vector3::x_axis(), rx.to_radians())
        * Rotation3::from_axis_angle(&Vector3::y_axis(), ry.to_radians())
        * Rotation3::from_axis_angle(&Vector3::z_axis(), rz.to_radians()))
    .into_inner();
    let a = val3_angles_deg(&r);
    for (got, want) in a.iter().zip([rx, ry, rz]) {
        assert!((got - want).abs() < 1e-9, "{a:?}");
    }
}

#[test]
fn error_tables_come_by_name_or_from_a_file_and_bad_ones_are_named() {
    assert_eq!(
        load_error_table("paper", 6, 1).expect("paper"),
        paper_errors()
    );
    assert!(matches!(
        load_error_table("paper", 5, 1),
        Err(SimError::Errors { .. })
    ));
    assert!(load_error_table("none", 6, 1).expect("none").is_empty());
    assert!(load_error_table("", 6, 1).expect("empty").is_empty());
    let r = load_error_table("random", 6, 7).expect("random");
    assert_eq!(r, random_errors(6, 7));
    assert_ne!(r, random_errors(6, 8), "the seed matters");

    let dir = tempfile::tempdir().expect("tempdir");
    let toml = dir.path().join("e.toml");
    std::fs::write(&toml, "d3 = 0.2\ntheta2 = 0.001\n").expect("write");
    let t = load_error_table(toml.to_str().expect("utf-8"), 6, 1).expect("toml file");
    assert_eq!(t.get("d3"), Some(&0.2));
    let json = dir.path().join("e.json");
    std::fs::write(&json, r#"{"a2": -0.1}"#).expect("write");
    let t = load_error_table(json.to_str().expect("utf-8"), 6, 1).expect("json file");
    assert_eq!(t.get("a2"), Some(&-0.1));
    let missing = dir.path().join("missing.toml");
    let e = load_error_table(missing.to_str().expect("utf-8"), 6, 1).expect_err("missing");
    assert!(e.to_string().contains("missing.toml"), "{e}");
}

#[test]
fn the_true_model_takes_the_configured_base_and_tool_and_refuses_unknown_errors() {
    let nominal = crate::model::tx60().bare();
    let cfg = SimWorldConfig {
        errors: "none".into(),
        base_translation_mm: Some([100.0, -50.0, 20.0]),
        base_rotation_vector_deg: Some([0.0, 0.0, 90.0]),
        tool_mm: Some([0.0, 0.0, 60.0]),
        ..SimWorldConfig::default()
    };
    let t = true_model(&nominal, &cfg).expect("truth");
    assert_eq!(t.base_translation, Vector3::new(100.0, -50.0, 20.0));
    assert!((t.base_rotation * Vector3::x() - Vector3::y()).norm() < 1e-12);
    assert_eq!(t.tool, Vector3::new(0.0, 0.0, 60.0));
    assert_eq!(t.joints, nominal.joints, "no errors: the nominal chain");

    let dir = tempfile::tempdir().expect("tempdir");
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "d9 = 1.0\n").expect("write");
    let cfg = SimWorldConfig {
        errors: bad.to_string_lossy().into_owned(),
        ..SimWorldConfig::default()
    };
    let e = true_model(&nominal, &cfg).expect_err("unknown parameter");
    assert!(e.to_string().contains("d9"), "{e}");
}

#[test]
fn timings_are_fast_by_default_realistic_on_request_and_explicit_values_win() {
    let fast = SimWorldConfig::default();
    let tx60 = crate::model::tx60();
    assert_eq!(
        fast.motion_limits(&tx60),
        crate::plan::MotionLimits::uniform(6, 3600f64.to_radians())
    );
    assert_eq!(fast.effective_settle_ms(), 0);
    assert_eq!(fast.effective_measure_ms(), 5);
    assert_eq!(fast.effective_stage_speed_mm_s(), 1000.0);
    let real = SimWorldConfig {
        realistic: true,
        settle_ms: Some(10),
        ..SimWorldConfig::default()
    };
    // realistic: the robot file's joint limits; an explicit speed still wins
    assert_eq!(
        real.motion_limits(&tx60),
        crate::plan::MotionLimits::of(&tx60, 100.0)
    );
    let given = SimWorldConfig {
        move_speed_deg_s: Some(60.0),
        ..real.clone()
    };
    assert_eq!(
        given.motion_limits(&tx60),
        crate::plan::MotionLimits::uniform(6, 60f64.to_radians())
    );
    assert_eq!(real.effective_settle_ms(), 10);
    assert_eq!(real.effective_measure_ms(), 1000);
    assert_eq!(real.effective_stage_speed_mm_s(), 5.0);
}

/// A world with instant motion, no noise, no jitter and a micrometer stage at 0 mm.
fn still_world(cfg: SimWorldConfig) -> World {
    let nominal = crate::model::tx60().bare();
    let cfg = SimWorldConfig {
        move_speed_deg_s: Some(1e12),
        tracker_noise_scale: 0.0,
        joint_jitter_rad: 0.0,
        ..cfg
    };
    let truth = true_model(&nominal, &cfg).expect("truth");
    World::new(
        nominal,
        truth,
        &cfg,
        StageSource::Manual { position_mm: 0.0 },
    )
    .expect("world")
}

#[test]
fn initial_joints_for_another_robot_are_a_config_error() {
    let mut nominal = crate::model::tx60().bare();
    nominal.joints.pop();
    nominal.limits.pop();
    let cfg = SimWorldConfig {
        errors: "none".into(),
        ..SimWorldConfig::default()
    };
    let truth = true_model(&nominal, &cfg).expect("truth");
    let e = World::new(
        nominal,
        truth,
        &cfg,
        StageSource::Manual { position_mm: 0.0 },
    )
    .expect_err("six initial joints, five-joint robot");
    assert!(
        e.to_string()
            .contains("initial_joints_deg has 6 values, the robot 5 joints"),
        "{e}"
    );
}

#[test]
fn the_world_checks_targets_moves_measures_the_true_ball_and_latches_an_e_stop() {
    let mut w = still_world(SimWorldConfig::default());
    let e = w.check_target(&[0.0; 5]).expect_err("five joints");
    assert_eq!(e.code, ErrorCode::Args);
    let e = w
        .check_target(&[0.0, 0.0, 0.0, 0.0, 0.0, 10.0])
        .expect_err("q6");
    assert_eq!(e.code, ErrorCode::Limit);
    assert!(e.text.starts_with("joint 6"), "{}", e.text);

    let q = vec![0.3, -0.2, 1.4, 0.1, 0.6, -0.4];
    w.set_power(true).expect("power");
    w.start_move(q.clone(), 100.0).expect("move");
    while !w.is_settled() {
        std::hint::spin_loop();
    }
    assert_eq!(w.readback_joints_rad(), q);
    assert_eq!(w.moves(), 1);
    // no noise, no drift: the tracker sees the true ball
    let truth = w.true_model().clone();
    let fl = *forward(&truth, &q).flange();
    let ball = truth.base_rotation * fl.transform_point(&truth.tool) + truth.base_translation;
    let emscon::BackendMeasurement::Point(p) = w.measure() else {
        panic!("target lost");
    };
    assert!((Vector3::from(p.xyz_mm) - ball).norm() < 1e-9);
    assert_eq!(w.measurements(), 1);

    w.set_estop(true);
    assert!(!w.power(), "an E-stop drops power");
    assert_eq!(
        w.set_power(true).expect_err("latched").code,
        ErrorCode::EStop
    );
    w.set_estop(false);
    w.set_power(true).expect("released");
    assert_eq!(w.power_on_requests(), 2);
}

#[test]
fn the_world_rejects_the_scripted_move_and_slips_the_stage_once_away_from_zero() {
    let mut cfg = SimWorldConfig::default();
    cfg.faults.robot.reject_move_n = 2;
    cfg.faults.robot.reject_code = "E_UNREACHABLE".into();
    cfg.faults.stage.slip = 1;
    cfg.faults.stage.slip_mm = 0.5;
    let mut w = still_world(cfg);
    let q = vec![0.3, -0.2, 1.4, 0.1, 0.6, -0.4];
    w.start_move(q.clone(), 100.0).expect("move 1");
    let e = w.start_move(q, 100.0).expect_err("move 2");
    assert_eq!(e.code, ErrorCode::Unreachable);
    assert_eq!(w.moves(), 2, "a rejected move counts");

    // at 0 mm no slip; the first rest away from it slips, the next one does not
    assert_eq!(w.stage_true_mm(), 0.0);
    w.set_manual_stage_mm(10.0);
    assert!((w.stage_true_mm() - 10.5).abs() < 1e-12);
    assert!(
        (w.stage_true_mm() - 10.5).abs() < 1e-12,
        "the slip stays while it rests"
    );
    w.set_manual_stage_mm(20.0);
    assert!((w.stage_true_mm() - 20.0).abs() < 1e-12);
}

#[test]
fn an_unknown_reject_code_is_a_config_error() {
    let nominal = crate::model::tx60().bare();
    let mut cfg = SimWorldConfig::default();
    cfg.faults.robot.reject_code = "unreachable".into();
    let truth = true_model(&nominal, &cfg).expect("truth");
    let e = World::new(
        nominal,
        truth,
        &cfg,
        StageSource::Manual { position_mm: 0.0 },
    )
    .expect_err("bad code");
    assert!(e.to_string().contains("`unreachable`"), "{e}");
}

#[test]
fn the_simulated_robot_moves_to_the_pose_of_its_true_model_with_the_non_geometric_terms() {
    let compliance = [0.0, 4e-6, 5e-6, 6e-6, 6e-6, 0.0];
    let harmonics = [[20.0, -10.0, 5.0, 0.0]; 6];
    let with_terms = SimWorldConfig {
        errors: "none".into(),
        compliance_rad_per_nm: Some(compliance),
        harmonics_urad: Some(harmonics),
        ..SimWorldConfig::default()
    };
    let mut w = still_world(with_terms.clone());
    let truth = w.true_model().clone();
    for (j, t) in truth.terms.iter().enumerate() {
        assert_eq!(t.compliance, compliance[j]);
        for (got, want) in t.harmonics.iter().zip(harmonics[j]) {
            assert!((got - want * 1e-6).abs() < 1e-18);
        }
    }
    let q = vec![0.3, 0.9, 1.1, 0.1, 0.6, -0.4];
    w.set_power(true).expect("power");
    w.start_move(q.clone(), 100.0).expect("move");
    while !w.is_settled() {
        std::hint::spin_loop();
    }
    // the controller reports the commanded joints, the tracker sees the deflected chain
    assert_eq!(w.readback_joints_rad(), q);
    let fl = *forward(&truth, &q).flange();
    let ball = truth.base_rotation * fl.transform_point(&truth.tool) + truth.base_translation;
    let emscon::BackendMeasurement::Point(p) = w.measure() else {
        panic!("target lost");
    };
    assert!((Vector3::from(p.xyz_mm) - ball).norm() < 1e-9);
    let rigid = crate::model::RobotModel {
        terms: Vec::new(),
        ..truth.clone()
    };
    let fl = *forward(&rigid, &q).flange();
    let rigid_ball = rigid.base_rotation * fl.transform_point(&rigid.tool) + rigid.base_translation;
    let deflection = (ball - rigid_ball).norm();
    assert!(deflection > 0.1, "the terms move the ball {deflection} mm");

    // typical ones are seeded by error_seed; a compliance without masses is refused
    let typical = SimWorldConfig {
        errors: "none".into(),
        nongeometric_errors: super::config::NongeometricErrors::Typical,
        error_seed: 5,
        ..SimWorldConfig::default()
    };
    let nominal = crate::model::tx60().bare();
    assert_eq!(
        true_model(&nominal, &typical).expect("typical").terms,
        crate::simulate::truth::typical_terms(&nominal, 5)
    );
    let massless = crate::model::RobotModel {
        masses: Vec::new(),
        ..nominal
    };
    let e = true_model(&massless, &with_terms).expect_err("no masses");
    assert!(
        e.to_string().contains("compliance_rad_per_nm") && e.to_string().contains("[[masses]]"),
        "{e}"
    );
}
