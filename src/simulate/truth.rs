//! True parameter errors for simulations: the paper's Table 3 values, seeded random ones, or a
//! table given by name.

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

use crate::identify::params::{all_params, retract, term_params, ParamId};
use crate::model::{gravity_levers, JointTerms, RobotModel, TermFamily, TermKind};

/// Parameter errors by name (`theta1` … `beta6`; rad or mm), and non-geometric terms
/// (`compliance2`, `sin_q3`, …; rad/(N·m) or rad).
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

/// Apply an error table to a model: MDH errors and non-geometric terms (added to the model's
/// own); unknown names are returned as an error.
pub fn apply_errors(model: &RobotModel, errors: &ErrorTable) -> Result<RobotModel, String> {
    let dof = model.dof();
    let known_params: Vec<ParamId> = all_params(dof, false, false)
        .into_iter()
        .chain(term_params(dof, &TermFamily::ALL))
        .collect();
    let mut params = Vec::with_capacity(errors.len());
    let mut step = Vec::with_capacity(errors.len());
    for (name, v) in errors {
        let Some(p) = known_params.iter().find(|p| &p.name() == name) else {
            return Err(format!("unknown parameter `{name}`"));
        };
        if !v.is_finite() {
            return Err(format!("parameter `{name}`: not a finite number"));
        }
        params.push(*p);
        step.push(*v);
    }
    if params.iter().any(|p| {
        matches!(
            p,
            ParamId::Term {
                kind: TermKind::Compliance,
                ..
            }
        )
    }) && model.masses.is_empty()
    {
        return Err(NO_MASSES.into());
    }
    Ok(retract(model, &params, &step))
}

/// Why a compliance cannot act on a model without masses.
const NO_MASSES: &str =
    "a compliance needs the robot file's [[masses]]: without them no gravity torque acts on it";

/// Range of the compliance [`typical_terms`] draws for a joint with a gravity lever
/// (rad/(N·m)): 2–6 µrad/(N·m), a small arm's joint stiffness of 170–500 kN·m/rad.
pub const TYPICAL_COMPLIANCE_RAD_PER_NM: (f64, f64) = (2e-6, 6e-6);
/// σ of each harmonic coefficient [`typical_terms`] draws (rad): 30 µrad, a gear's
/// transmission error after the reduction.
pub const TYPICAL_HARMONIC_SIGMA_RAD: f64 = 30e-6;

/// Non-geometric errors of a simulated robot ([`apply_terms`]): explicit values and/or the
/// seeded typical ones; what is not given is zero.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TermErrors {
    /// Compliance per joint (rad/(N·m), ≥ 0; one per joint).
    pub compliance_rad_per_nm: Option<Vec<f64>>,
    /// Harmonic coefficients per joint (rad), `[sin q, cos q, sin 2q, cos 2q]` (one row per joint).
    pub harmonics_rad: Option<Vec<[f64; 4]>>,
    /// Seed of [`typical_terms`]: generate them (not with explicit values).
    pub typical_seed: Option<u64>,
}

impl TermErrors {
    /// No non-geometric error at all.
    pub fn is_none(&self) -> bool {
        self.compliance_rad_per_nm.is_none()
            && self.harmonics_rad.is_none()
            && self.typical_seed.is_none()
    }
}

/// Seeded typical non-geometric errors of `model`: every joint with a gravity lever
/// ([`gravity_levers`], from the model's masses) a compliance uniform in
/// [`TYPICAL_COMPLIANCE_RAD_PER_NM`], every joint four harmonic coefficients of σ
/// [`TYPICAL_HARMONIC_SIGMA_RAD`].
pub fn typical_terms(model: &RobotModel, seed: u64) -> Vec<JointTerms> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x6e6f_6e67_656f_6d21);
    let levers = gravity_levers(model);
    let harmonic =
        Normal::new(0.0, TYPICAL_HARMONIC_SIGMA_RAD).unwrap_or_else(|_| unreachable!("valid σ"));
    let (lo, hi) = TYPICAL_COMPLIANCE_RAD_PER_NM;
    levers
        .iter()
        .map(|&lever| {
            let u: f64 = rng.random();
            JointTerms {
                compliance: if lever { lo + (hi - lo) * u } else { 0.0 },
                harmonics: std::array::from_fn(|_| harmonic.sample(&mut rng)),
            }
        })
        .collect()
}

/// `model` with the non-geometric errors `t` added to its terms (none: zero): explicit values
/// checked (one per joint, finite, compliance ≥ 0, a compliance needs the model's masses), the
/// typical ones drawn. Errors name the key.
pub fn apply_terms(model: &RobotModel, t: &TermErrors) -> Result<RobotModel, String> {
    let dof = model.dof();
    let mut m = model.clone();
    if t.is_none() {
        return Ok(m);
    }
    if t.typical_seed.is_some() && (t.compliance_rad_per_nm.is_some() || t.harmonics_rad.is_some())
    {
        return Err("typical non-geometric errors or explicit values, not both".into());
    }
    let mut add = match t.typical_seed {
        Some(seed) => typical_terms(model, seed),
        None => vec![JointTerms::default(); dof],
    };
    if let Some(c) = &t.compliance_rad_per_nm {
        if c.len() != dof {
            return Err(format!("compliance: {} values for {dof} joints", c.len()));
        }
        for (j, v) in c.iter().enumerate() {
            if !(v.is_finite() && *v >= 0.0) {
                return Err(format!(
                    "compliance: joint {}: {v} is not a compliance (finite, ≥ 0)",
                    j + 1
                ));
            }
            add[j].compliance = *v;
        }
        if c.iter().any(|v| *v > 0.0) && model.masses.is_empty() {
            return Err(NO_MASSES.into());
        }
    }
    if let Some(h) = &t.harmonics_rad {
        if h.len() != dof {
            return Err(format!("harmonics: {} rows for {dof} joints", h.len()));
        }
        for (j, row) in h.iter().enumerate() {
            if row.iter().any(|v| !v.is_finite()) {
                return Err(format!("harmonics: joint {}: not a finite number", j + 1));
            }
            add[j].harmonics = *row;
        }
    }
    if m.terms.is_empty() {
        m.terms = vec![JointTerms::default(); dof];
    }
    for (have, more) in m.terms.iter_mut().zip(&add) {
        have.compliance += more.compliance;
        for (h, a) in have.harmonics.iter_mut().zip(&more.harmonics) {
            *h += a;
        }
    }
    Ok(m)
}
