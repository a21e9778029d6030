//! The variance of unit weight from the right redundancy: a unit direction observes 2 degrees of
//! freedom (not 3 rows), so on data with known isotropic noise σ0 of the NP and OP fits equals σ0
//! of the position fit, and both equal the simulated σ (rows counted instead of observations
//! give σ0_op/σ0_position = √(5/6) ≈ 0.91).

use cellcal::identify::{identify, ObsModel};
use cellcal::simulate::{SimConfig, TrackerNoise};
use nalgebra::Vector3;

use super::common::*;

/// Per-axis tracker σ of the simulation (mm), the same at every range.
const SIGMA_MM: f64 = 0.02;

/// 2 000 poses whose only error is isotropic tracker noise σ on P1 and P2.
fn isotropic_noise_config(axis: Vector3<f64>) -> SimConfig {
    SimConfig {
        poses: 2000,
        ident: 2000,
        tracker: Some(TrackerNoise {
            position_mm: Vector3::new(2550.0, 0.0, 0.0),
            a_um: SIGMA_MM * 1000.0,
            b_um_per_m: 0.0,
            k: 1.0,
        }),
        joint_jitter_rad: 0.0,
        stage_axis: axis,
        stage_repeatability_mm: 0.0,
        stage_cross_mm_per_mm: 0.0,
        stage_misalignment_rad: Vector3::zeros(),
        outlier_fraction: 0.0,
        ..SimConfig::default()
    }
}

fn sigma0(model: ObsModel, axis: Vector3<f64>) -> f64 {
    let data = sim(&paper_truth(), &isotropic_noise_config(axis));
    let opts = options(model, axis);
    let (ident, _) = measured(&data.observations, &opts);
    let id = identify(&tx60(), &ident, &opts).expect("identification runs");
    assert!(id.termination.converged(), "{model:?}");
    id.sigma0_mm
}

#[test]
fn sigma0_counts_two_degrees_of_freedom_per_direction() {
    let position = sigma0(ObsModel::Position, Vector3::y());
    let op = sigma0(ObsModel::Op, Vector3::y());
    let np = sigma0(ObsModel::Np, Vector3::x());
    // statistical spread of each σ0: ~1 % (6 000 and 10 000 degrees of freedom)
    for (name, s) in [("position", position), ("op", op), ("np", np)] {
        assert!(
            (s / SIGMA_MM - 1.0).abs() < 0.03,
            "{name}: σ0 {s:.5} mm vs simulated {SIGMA_MM} mm"
        );
    }
    for (name, s) in [("op", op), ("np", np)] {
        let ratio = s / position;
        assert!(
            (ratio - 1.0).abs() < 0.03,
            "σ0_{name}/σ0_position = {ratio:.4}"
        );
    }
}
