//! The identifiable sets of docs/method.md §2, with and without base and tool, and the errors for
//! too few or too similar poses.

use cellcal::identify::identifiability::analyze;
use cellcal::identify::{
    all_params, identify, predict, structural_set, DropKind, IdentifyError, Measured, ObsConfig,
    ObsModel, ParamId,
};
use cellcal::model::ParamKind;
use cellcal::plan::{sample_poses, Workspace};
use nalgebra::Vector3;
use rand::SeedableRng;

use super::common::*;

fn poses(n: usize) -> Vec<Measured> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4804);
    sample_poses(&tx60(), &Workspace::default(), n, &mut rng)
        .expect("sampled")
        .into_iter()
        .map(Measured::joints_only)
        .collect()
}

fn dropped(model: ObsModel, base: bool, tool: bool) -> Vec<(String, String)> {
    let m = tx60();
    let cfg = ObsConfig::new(model, 10.0);
    let cfg = ObsConfig {
        stage_axis: if model == ObsModel::Np {
            Vector3::x()
        } else {
            Vector3::y()
        },
        ..cfg
    };
    let r = analyze(&m, &poses(100), &cfg, &all_params(6, base, tool));
    assert!(
        r.condition_number() < 100.0,
        "cond {}",
        r.condition_number()
    );
    r.dropped
        .iter()
        .map(|d| (d.param.name(), d.reason.clone()))
        .collect()
}

fn names(v: &[(String, String)]) -> Vec<&str> {
    v.iter().map(|(n, _)| n.as_str()).collect()
}

#[test]
fn method_table_without_base_and_tool() {
    assert_eq!(
        names(&dropped(ObsModel::Position, false, false)),
        ["beta1", "d2", "beta3", "beta4", "a5", "alpha5", "beta5", "theta6", "alpha6", "beta6"]
    );
    assert_eq!(
        names(&dropped(ObsModel::Np, false, false)),
        ["beta1", "d2", "beta3", "beta4", "beta5", "alpha6"]
    );
    assert_eq!(
        names(&dropped(ObsModel::Op, false, false)),
        ["beta1", "d2", "beta3", "beta4", "beta5", "beta6"]
    );
    assert_eq!(
        names(&dropped(ObsModel::Full, false, false)),
        ["beta1", "d2", "beta3", "beta4", "beta5"]
    );
}

#[test]
fn reasons_are_given() {
    let d = dropped(ObsModel::Op, false, false);
    let reason = |n: &str| {
        d.iter()
            .find(|(x, _)| x == n)
            .map(|(_, r)| r.as_str())
            .unwrap_or("")
    };
    assert_eq!(reason("d2"), "dependent on d3");
    assert_eq!(reason("beta1"), "dependent on theta1");
    assert_eq!(reason("beta6"), "no effect on this measurement");
    let np = dropped(ObsModel::Np, false, false);
    assert!(np
        .iter()
        .any(|(n, r)| n == "alpha6" && r == "no effect on this measurement"));
}

#[test]
fn base_and_tool_gauge_redundancies_go_to_the_frames() {
    // frame first: base and tool are all kept; the robot parameters they cannot be told apart
    // from stay at nominal, named as dependent on them
    for model in [ObsModel::Np, ObsModel::Op, ObsModel::Full] {
        let d = dropped(model, true, true);
        assert!(
            !d.iter()
                .any(|(n, _)| n.starts_with("base") || n.starts_with("tool")),
            "{model:?}: {d:?}"
        );
        for (name, reason) in [
            ("theta1", "dependent on base_rz"),
            ("d1", "dependent on base_tz"),
            ("a6", "dependent on tool_x"),
            ("d6", "dependent on tool_z"),
        ] {
            assert!(
                d.iter().any(|(n, r)| n == name && r == reason),
                "{model:?} {name}: {d:?}"
            );
        }
        // as many parameters as before: the frames took the robot's place, nothing more
        let without = dropped(model, false, false).len();
        assert_eq!(d.len(), without + 4, "{model:?}: {d:?}");
    }
    // position only: the tool also takes theta6's effect on the ball
    let d = dropped(ObsModel::Position, true, true);
    let n = names(&d);
    assert!(
        !n.iter()
            .any(|n| n.starts_with("base") || n.starts_with("tool")),
        "{n:?}"
    );
    assert!(
        n.contains(&"d1") && n.contains(&"d6") && n.contains(&"theta6"),
        "{n:?}"
    );
}

#[test]
fn deterministic() {
    let a = dropped(ObsModel::Full, true, true);
    let b = dropped(ObsModel::Full, true, true);
    assert_eq!(a, b);
}

#[test]
fn too_few_poses_is_an_error() {
    let opts = options(ObsModel::Op, Vector3::y());
    let mut p = poses(4);
    for m in &mut p {
        m.direction = Some(Vector3::y());
    }
    match identify(&tx60(), &p, &opts) {
        Err(IdentifyError::TooFewPoses {
            poses: 4,
            parameters: 24,
            needed: 5,
            ..
        }) => {}
        other => panic!("expected TooFewPoses, got {other:?}"),
    }
}

#[test]
fn rank_deficient_poses_are_an_error() {
    let opts = options(ObsModel::Op, Vector3::y());
    // 40 poses that only move joint 1: nothing separates the rest
    let mut p = poses(40);
    let q0 = p[0].q.clone();
    for (i, m) in p.iter_mut().enumerate() {
        m.q = q0.clone();
        m.q[0] = -1.0 + 0.05 * i as f64;
        m.direction = Some(Vector3::y());
    }
    match identify(&tx60(), &p, &opts) {
        Err(IdentifyError::RankDeficient { missing }) => assert!(!missing.is_empty()),
        other => panic!("expected RankDeficient, got {other:?}"),
    }
}

#[test]
fn a_formally_identifiable_but_undetermined_parameter_is_held_back_not_an_error() {
    // the README campaign's setup: the ball 60 mm above the flange, the stage axis measured
    // 4.4 mrad off +y. β6 moves the ball like a6 and turns the measured direction like θ6 and
    // α6, which also move the ball: structurally independent, but only through 4.4e-3 of α6's
    // effect — inside the box a6, θ6 and α6 cancel it
    let axis = Vector3::new(-0.0044, 1.0, 0.0012).normalize();
    let opts = options(ObsModel::Op, axis);
    let mut m = tx60();
    m.tool = Vector3::new(0.4, -0.3, 60.0);
    let beta6 = ParamId::Mdh {
        joint: 5,
        kind: ParamKind::Beta,
    };
    let structural = structural_set(&m, &opts.obs, &all_params(6, false, false));
    assert!(structural.identified.contains(&beta6));
    let mut p = poses(100);
    for x in &mut p {
        let t = predict(&m, &x.q);
        x.p1 = t.p;
        x.direction = Some(t.r * axis);
    }
    let id = identify(&m, &p, &opts).expect("held back, not rank-deficient");
    let d = id
        .identifiability
        .dropped
        .iter()
        .find(|d| d.param == beta6)
        .expect("beta6 held back");
    assert_eq!(d.kind, DropKind::Dependent);
    assert!(
        d.reason.starts_with("indistinguishable from a6"),
        "{}",
        d.reason
    );
    assert!(d.predicted_sigma.is_some_and(|s| s > 0.01), "{d:?}");
    // the structural analysis of the same poses keeps it
    let s = analyze(&m, &p, &opts.obs, &all_params(6, false, false));
    assert!(s.identified.contains(&beta6));
}
