//! `--robust` with 3 % gross outliers reaches ≤ 1.10 × the floor and names the outliers;
//! the plain fit does not (so the test can fail).

use cellcal::analysis::evaluate;
use cellcal::identify::{identify, ObsModel, RobustLoss};
use cellcal::simulate::SimConfig;
use nalgebra::Vector3;

use super::common::*;

fn check(loss: RobustLoss) {
    let truth = paper_truth();
    let cfg = SimConfig {
        outlier_fraction: 0.03,
        outlier_mm: 1.0,
        ..SimConfig::default()
    };
    let data = sim(&truth, &cfg);
    let mut opts = options(ObsModel::Op, Vector3::y());
    let (ident, verify) = measured(&data.observations, &opts);
    // clean verification poses for the floor and the score
    let clean_verify: Vec<_> = verify
        .iter()
        .enumerate()
        .filter(|(i, _)| !data.outliers.contains(&(i + cfg.ident)))
        .map(|(_, m)| m.clone())
        .collect();
    let fl = floor(&truth, &clean_verify, &opts);
    let plain = identify(&tx60(), &ident, &opts).expect("plain fit");
    let plain_after = evaluate(&plain.corrected, &clean_verify, &opts.obs).position_mean_mm;
    assert!(
        plain_after > 1.10 * fl,
        "outliers should hurt a plain fit: {plain_after} vs {fl}"
    );
    opts.robust = Some(loss);
    let id = identify(&tx60(), &ident, &opts).expect("robust fit");
    assert_structural_set(&id, &tx60(), &opts);
    let after = evaluate(&id.corrected, &clean_verify, &opts.obs).position_mean_mm;
    assert!(
        after <= 1.10 * fl,
        "{loss:?}: after {after:.5} vs floor {fl:.5}"
    );
    let expected: Vec<usize> = data
        .outliers
        .iter()
        .copied()
        .filter(|&i| i < cfg.ident)
        .collect();
    assert!(!expected.is_empty());
    assert_eq!(id.rejected, expected);
}

#[test]
fn huber_rejects_outliers() {
    check(RobustLoss::Huber);
}

#[test]
fn cauchy_rejects_outliers() {
    check(RobustLoss::Cauchy);
}
