//! Unit tests of the dry run's Monte Carlo: seeded whatever the threads, the verification error
//! near the noise floor, the verification-set precision formula against a direct simulation.

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::identify::observation::{ObsConfig, ObsModel};
use crate::identify::TrackerNoise;
use crate::plan::Workspace;

/// The paper's setup (docs/method.md §7): TX60, OP with the stage along +y, ball at the flange
/// origin, AT960 at (2550, 0, 0) mm, `verify` verification poses.
pub(crate) fn paper_setup(verify: usize) -> Setup {
    let mut obs = ObsConfig::new(ObsModel::Op, 10.0);
    obs.stage_axis = Vector3::y();
    let tracker_mm = Vector3::new(2550.0, 0.0, 0.0);
    Setup {
        nominal: crate::model::tx60(),
        opts: IdentifyOptions::new(obs),
        stage_travel_mm: 10.0,
        request: PlanRequest {
            workspace: Workspace::default(),
            poses: 0,
            ident: 0,
            seed: 0,
            tracker_mm,
            line_of_sight_max_rad: 80f64.to_radians(),
            tool_mm: Vector3::zeros(),
            drift_every: 0,
            ident_block: None,
            speed_pct: 20.0,
            move_speed_rad_s: None,
            settle_s: 0.0,
            stage_offset_mm: Vector3::new(0.0, 10.0, 0.0),
            selection: crate::plan::selection::Selection::Random,
            design: crate::plan::selection::DesignSetup {
                obs,
                stage_travel_mm: 10.0,
                identify_base: false,
                identify_tool: false,
                noise_mm: crate::identify::identifiability::DEFAULT_NOISE_MM,
                joint_jitter_rad: REAL_JOINT_JITTER_RAD,
            },
        },
        tracker: Some(TrackerNoise::at960(tracker_mm)),
        joint_jitter_rad: REAL_JOINT_JITTER_RAD,
        errors: ErrorSpread::default(),
        verify,
    }
}

#[test]
fn a_prediction_is_seeded_and_the_same_on_one_thread_or_two() {
    let setup = paper_setup(40);
    let one = monte_carlo(&setup, IdentPoses::Random(40), 3, 7, 1).expect("runs");
    let two = monte_carlo(&setup, IdentPoses::Random(40), 3, 7, 2).expect("runs");
    assert_eq!(one, two);
    assert_eq!(one.trials.len(), 3);
    assert_eq!(one.failed, 0);
    let other = monte_carlo(&setup, IdentPoses::Random(40), 3, 8, 2).expect("runs");
    assert_ne!(one, other);
}

#[test]
fn the_verification_error_of_100_random_poses_is_just_above_the_noise_floor() {
    let setup = paper_setup(100);
    let p = monte_carlo(&setup, IdentPoses::Random(100), 4, 1, 2).expect("runs");
    let (ratio, floor) = (p.ratio_to_floor(), p.floor_mm());
    // docs/method.md §7: the identified OP model reaches the floor within a few %
    assert!((1.0..1.08).contains(&ratio), "ratio {ratio}");
    // AT960 at 2.55 m, ‖3 × N(0, σ ≈ 0.014 mm)‖ ≈ 1.6 σ
    assert!((0.015..0.03).contains(&floor), "floor {floor}");
    // the model error is far below the noise (a random model of 0.2 mm errors is mm off)
    assert!(p.model_mean_mm() < 0.5 * floor, "{}", p.model_mean_mm());
}

#[test]
fn fewer_identification_poses_predict_a_larger_model_error() {
    let setup = paper_setup(60);
    let few = monte_carlo(&setup, IdentPoses::Random(25), 4, 3, 2).expect("runs");
    let many = monte_carlo(&setup, IdentPoses::Random(150), 4, 3, 2).expect("runs");
    assert!(
        few.model_mean_mm() > 1.5 * many.model_mean_mm(),
        "{} vs {}",
        few.model_mean_mm(),
        many.model_mean_mm()
    );
}

/// The standard error σ_pose/√V is what repeated verification sets of V poses of one identified
/// model scatter by.
#[test]
fn the_verification_set_precision_formula_matches_a_direct_simulation() {
    let setup = paper_setup(0);
    let id = identify_once(&setup, IdentPoses::Random(60), 5).expect("identifies");
    let (big, _) = verification_errors(&setup, &id, 3000, 1).expect("sampled");
    let pose_sd = sd(big.iter().copied());
    let v = 25;
    let means: Vec<f64> = (0..300)
        .map(|k| {
            let (e, _) = verification_errors(&setup, &id, v, 100 + k).expect("sampled");
            mean(e.iter().copied())
        })
        .collect();
    let direct = sd(means.iter().copied());
    let formula = standard_error_mm(pose_sd, v);
    // 300 sets: the sd of the sets' means is itself known to ±4 % (1σ)
    assert!(
        (direct / formula - 1.0).abs() < 0.15,
        "direct {direct} vs formula {formula}"
    );
    // and it is σ/√V, not σ/V or σ
    assert!((standard_error_mm(0.02, 100) - 0.002).abs() < 1e-15);
}

#[test]
fn bad_settings_are_refused() {
    let setup = paper_setup(10);
    assert!(matches!(
        monte_carlo(&setup, IdentPoses::Random(30), 0, 1, 1),
        Err(PredictError::Invalid(_))
    ));
    assert!(matches!(
        monte_carlo(&setup, IdentPoses::Random(0), 2, 1, 1),
        Err(PredictError::Invalid(_))
    ));
    assert!(matches!(
        monte_carlo(&paper_setup(0), IdentPoses::Random(30), 2, 1, 1),
        Err(PredictError::Invalid(_))
    ));
}

/// The Monte Carlo (simulate, identify the campaign's way, measure) and the selection's
/// analytic prediction ([`crate::plan::selection::predicted_verification`]) agree on the
/// verification error of one design of identification poses.
#[test]
fn the_monte_carlo_agrees_with_the_analytic_prediction() {
    use crate::plan::selection::predicted_verification;
    let setup = paper_setup(100);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let ident = random_poses(&setup, 30, &mut rng).expect("sampled");
    let verify = random_poses(&setup, 400, &mut rng).expect("sampled");
    let design = setup.design(&ident).expect("design");
    let cov = design.covariance(&ident).expect("determined");
    let analytic = predicted_verification(&design, &cov, &verify);
    let mc = monte_carlo(&setup, IdentPoses::Given(&ident), 24, 4, 2).expect("runs");
    let (m, a) = (mc.mean_mm(), analytic.mean_mm);
    assert!((m / a - 1.0).abs() < 0.1, "Monte Carlo {m} vs analytic {a}");
    let (mf, af) = (mc.floor_mm(), analytic.noise_floor_mm);
    assert!(
        (mf / af - 1.0).abs() < 0.1,
        "floor: Monte Carlo {mf} vs analytic {af}"
    );
    // what the parameters add over the floor agrees too, if less closely (24 trials)
    let (me, ae) = (m - mf, a - af);
    assert!(
        me > 0.0 && (me / ae - 1.0).abs() < 0.5,
        "excess {me} vs {ae}"
    );
}
