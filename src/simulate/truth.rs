//! True parameter errors for simulations: the paper's Table 3 values, seeded random ones, or a
//! table given by name.

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::identify::params::{all_params, retract, ParamId};
use crate::model::RobotModel;

/// Parameter errors by name (`theta1` … `beta6`; rad or mm).
pub type ErrorTable = BTreeMap<String, f64>;

/// The TX60 errors of docs/method.md §7 (paper Table 3), rows `[θ, d, a, α, β]` per joint.
pub const PAPER_ERRORS: [[f64; 5]; 6] = [
    [-0.00015, -0.19537, -0.24464, 7.36e-5, 0.0],
    [0.000797, 0.0, 0.299495, -3.42e-5, 1.79e-5],
    [0.000343, 0.202538, 0.007822, 0.000877, 0.0],
    [0.001511, 0.200548, -0.08927, -0.00042, 0.0],
    [0.001, -0.06341, -0.01266, -0.00046, 0.0],
    [0.001394, -0.10686, -0.09432, 0.000783, 0.0],
];

/// The paper's error table (for a six-joint robot).
pub fn paper_errors() -> ErrorTable {
    let params = all_params(6, false, false);
    params
        .iter()
        .enumerate()
        .map(|(i, p)| (p.name(), PAPER_ERRORS[i / 5][i % 5]))
        .collect()
}

/// σ of the lengths (mm) of [`random_errors`].
pub const RANDOM_LENGTH_SIGMA_MM: f64 = 0.2;
/// σ of the angles (rad) of [`random_errors`].
pub const RANDOM_ANGLE_SIGMA_RAD: f64 = 5e-4;

/// Seeded random errors: lengths σ = 0.2 mm, angles σ = 0.5 mrad, for every MDH parameter.
pub fn random_errors(dof: usize, seed: u64) -> ErrorTable {
    random_errors_of(dof, seed, RANDOM_LENGTH_SIGMA_MM, RANDOM_ANGLE_SIGMA_RAD)
}

/// [`random_errors`] of stated σ: lengths `length_mm`, angles `angle_rad` (finite, ≥ 0; a
/// σ that is not is taken as 0).
pub fn random_errors_of(dof: usize, seed: u64, length_mm: f64, angle_rad: f64) -> ErrorTable {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let normal = |s: f64| {
        Normal::new(0.0, if s.is_finite() && s >= 0.0 { s } else { 0.0 })
            .unwrap_or_else(|_| unreachable!("valid σ"))
    };
    let len = normal(length_mm);
    let ang = normal(angle_rad);
    all_params(dof, false, false)
        .iter()
        .map(|p| {
            let v = if p.is_angle() {
                ang.sample(&mut rng)
            } else {
                len.sample(&mut rng)
            };
            (p.name(), v)
        })
        .collect()
}

/// Apply an error table to a model; unknown names are returned as an error.
pub fn apply_errors(model: &RobotModel, errors: &ErrorTable) -> Result<RobotModel, String> {
    let params: Vec<ParamId> = all_params(model.dof(), false, false);
    let mut step = vec![0.0; params.len()];
    for (name, v) in errors {
        let Some(i) = params.iter().position(|p| &p.name() == name) else {
            return Err(format!("unknown parameter `{name}`"));
        };
        if !v.is_finite() {
            return Err(format!("parameter `{name}`: not a finite number"));
        }
        step[i] = *v;
    }
    Ok(retract(model, &params, &step))
}
