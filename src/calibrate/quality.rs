//! The verdict on an identification: `quality` (`ok`, `warning`, `poor`) and the `warnings`
//! that led to it, each `{code, severity, message}`; and the stage-axis check that refuses data
//! contradicting the stage axis in use.
//!
//! The verdict answers the question a metrologist asks before loading parameters into a
//! controller: are these numbers determined by the data, and do they describe the robot rather
//! than the identification poses? Worst severity wins; no warning = `ok`.
//!
//! | code | warning when | poor when | why |
//! |---|---|---|---|
//! | `not_converged` | — | the solver stopped without converging | the parameters are not the least-squares estimate, so nothing about them is known |
//! | `verify_worse` | — | verify-set position RMS after > before (by more than 1 nm: rounding) | the "calibration" makes the robot less accurate where it was checked |
//! | `condition_number` | > 1 000 | > 100 000 | scaled Jacobian (lengths in mm, angles at a 1 m lever arm): good designs sit at 9–150 (simulated TX60 campaigns, every model); above 1 000 some parameter combination is 1 000× less determined than the best one; above 1e5 the normal equations lose 10 of 16 digits |
//! | `parameter_sigma` | an identified parameter's σ > its bound | σ > 10 × bound | bounds 0.05 mm and 0.5 mrad (the identification's practical bounds, `--max-sigma-mm` / `--max-sigma-mrad`; [`QualityBounds`] defaults for a stored report): a parameter known only to ±0.5 mm or ±5 mrad is not a measured value; the verification may still look fine inside the sampled box because correlated parameters cancel there, not outside it |
//! | `too_few_poses` | parameters > 1/3 of the equations | > 1/2 | equations = poses used × independent values per pose (position 3, a unit direction 2 more, a rotation 3 more); the mean leverage k/n: above 1/2 every residual is mostly fitted, σ0 rests on fewer degrees of freedom than there are parameters and outliers cannot show |
//! | `overfit` | verify RMS / ident RMS (after) > 1.5 | > 3 | with enough poses both are at the noise floor (ratio 1.0–1.3 measured); a verification error several times the fit residual means the parameters describe the identification poses, not the robot |
//! | `outliers_rejected` | any pose rejected by `--robust` | > 10 % of the poses | a few gross errors happen (a bumped nest, a beam break); more than one pose in ten means the cell or the data is faulty |
//! | `stage_axis` | measured P2 − P1 axis > 1° from the axis in use | (error above 5°) | stage mounting and the nominal model's own orientation error are a few mrad; between 1° and 5° the identification absorbs an axis error into the wrist parameters; above 5° the axis (or the model, np/op) is simply wrong and the identification is refused ([`StageAxisCheck`]) |
//! | `no_verify_set` | no verification poses | — | nothing checks the result on poses it was not fitted to |
//! | `nongeometric_unverified` | terms asked for (§10), no verification poses | — | only poses the terms were not fitted to say whether they describe the robot: the identification RMS always falls with more parameters |
//! | `nongeometric_not_better` | the extended model's verification position RMS ≥ the geometric model's (fitted to the same data) | — | the terms do not make the robot more accurate where it was checked (`nongeometric_findings`) |
//! | `nongeometric_too_large` | the extended model's k parameters from n poses: √(1 + k/3n) > 1.05 | — | the noise alone keeps its verification error above 1.05 × the floor (`nongeometric_findings`) |
//!
//! Checks that need a figure the report lacks (no verify set, no direction data) are skipped.

use nalgebra::Vector3;

use super::identify_json::{IdentifyReport, KeptModel, MetricsJson, ParamStatus};
pub use super::identify_json::{Quality, QualityWarning};
use crate::identify::{predict, Measured, ObsConfig, ObsModel};
use crate::model::RobotModel;
use crate::units::human::fmt_mm;

/// The verdict thresholds (defaults: the module table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityBounds {
    /// Plausibility bound of a length parameter's σ (mm).
    pub sigma_mm: f64,
    /// Plausibility bound of an angle parameter's σ (rad).
    pub sigma_rad: f64,
    /// σ above this many bounds is poor.
    pub sigma_poor_factor: f64,
    /// Condition number above which to warn.
    pub condition_warning: f64,
    /// Condition number above which the result is poor.
    pub condition_poor: f64,
    /// Parameters / equations above which to warn.
    pub leverage_warning: f64,
    /// Parameters / equations above which the result is poor.
    pub leverage_poor: f64,
    /// Verify/ident RMS ratio above which to warn.
    pub overfit_warning: f64,
    /// Verify/ident RMS ratio above which the result is poor.
    pub overfit_poor: f64,
    /// Fraction of rejected poses above which the result is poor.
    pub outliers_poor_fraction: f64,
    /// Stage-axis angle above which to warn (rad).
    pub stage_axis_warning_rad: f64,
    /// Stage-axis angle (or scatter) above which the data is refused (rad).
    pub stage_axis_error_rad: f64,
    /// The extended model's predicted verification error over the noise floor,
    /// `√(1 + k/3n)`, above which its term set is too large for the poses
    /// (`nongeometric_too_large`).
    pub nongeometric_inflation_warning: f64,
}

impl Default for QualityBounds {
    fn default() -> QualityBounds {
        QualityBounds {
            sigma_mm: 0.05,
            sigma_rad: 0.5e-3,
            sigma_poor_factor: 10.0,
            condition_warning: 1e3,
            condition_poor: 1e5,
            leverage_warning: 1.0 / 3.0,
            leverage_poor: 0.5,
            overfit_warning: 1.5,
            overfit_poor: 3.0,
            outliers_poor_fraction: 0.10,
            stage_axis_warning_rad: 1f64.to_radians(),
            stage_axis_error_rad: 5f64.to_radians(),
            nongeometric_inflation_warning: 1.05,
        }
    }
}

/// RMS values below this (mm) are beyond any tracker: ratios of them are not compared.
const RMS_FLOOR_MM: f64 = 1e-3;

/// A verification RMS worse by less than this (mm) is rounding, not a worse robot: identifying
/// the data again from its own corrected model ends where it starts.
const VERIFY_WORSE_MARGIN_MM: f64 = 1e-6;

/// `quality` and `warnings` of a report.
#[derive(Debug, Clone, PartialEq)]
pub struct Verdict {
    /// Worst severity of the warnings (`ok` without any).
    pub quality: Quality,
    /// The findings, in the module table's order.
    pub warnings: Vec<QualityWarning>,
}

/// Independent measured values per pose: position 3, a unit direction 2 more, a rotation 3 more.
fn values_per_pose(model: &str) -> usize {
    match ObsModel::parse(model) {
        Ok(ObsModel::Position) => 3,
        Ok(ObsModel::Np | ObsModel::Op) => 5,
        Ok(ObsModel::Full) => 6,
        Err(_) => 3,
    }
}

struct Findings(Vec<QualityWarning>);

impl Findings {
    fn add(&mut self, code: &str, severity: Quality, message: String) {
        self.0.push(QualityWarning {
            code: code.to_owned(),
            severity,
            message,
        });
    }

    /// Warn above `warn`, poor above `poor`.
    fn graded(&mut self, code: &str, value: f64, warn: f64, poor: f64, message: String) {
        if value > poor || value.is_nan() {
            self.add(code, Quality::Poor, message);
        } else if value > warn {
            self.add(code, Quality::Warning, message);
        }
    }
}

/// The verdict on `r` under `b`.
pub fn assess(r: &IdentifyReport, b: &QualityBounds) -> Verdict {
    let mut f = Findings(Vec::new());
    if !r.solver.converged {
        f.add(
            "not_converged",
            Quality::Poor,
            format!(
                "the solver did not converge ({} after {} iterations): the parameters are not the least-squares estimate",
                r.solver.termination, r.solver.iterations
            ),
        );
    }
    if let Some(v) = &r.metrics.verify {
        let (before, after) = (v.before.position_rms_mm, v.after.position_rms_mm);
        if after > before + VERIFY_WORSE_MARGIN_MM && before > RMS_FLOOR_MM {
            f.add(
                "verify_worse",
                Quality::Poor,
                format!("verification position RMS {} mm after identification, {} mm before: the result makes the robot less accurate", fmt_mm(after), fmt_mm(before)),
            );
        }
    }
    f.graded(
        "condition_number",
        r.condition_number,
        b.condition_warning,
        b.condition_poor,
        format!(
            "condition number {:.0} of the scaled Jacobian (warning above {:.0}, poor above {:.0}): some parameter combination is barely determined by these poses",
            r.condition_number, b.condition_warning, b.condition_poor
        ),
    );
    sigma_finding(&mut f, r, b);
    poses_finding(&mut f, r, b);
    if let Some(v) = &r.metrics.verify {
        let (ident, verify) = (
            r.metrics.ident.after.position_rms_mm,
            v.after.position_rms_mm,
        );
        if verify > RMS_FLOOR_MM {
            let ratio = verify / ident.max(f64::MIN_POSITIVE);
            f.graded(
                "overfit",
                ratio,
                b.overfit_warning,
                b.overfit_poor,
                format!("verification position RMS {} mm is {ratio:.2}× the identification RMS {} mm (warning above {}×, poor above {}×): the parameters fit the identification poses better than the robot", fmt_mm(verify), fmt_mm(ident), b.overfit_warning, b.overfit_poor),
            );
        }
    }
    if !r.rejected_poses.is_empty() {
        let poses = r.metrics.ident.after.poses.max(1);
        let share = r.rejected_poses.len() as f64 / poses as f64;
        let severity = if share > b.outliers_poor_fraction {
            Quality::Poor
        } else {
            Quality::Warning
        };
        f.add(
            "outliers_rejected",
            severity,
            format!(
                "{} of {poses} identification poses rejected as outliers ({:.0} %, poor above {:.0} %): {}",
                r.rejected_poses.len(),
                100.0 * share,
                100.0 * b.outliers_poor_fraction,
                r.rejected_poses.join(", ")
            ),
        );
    }
    if let (Some(angle), Some(m)) = (r.stage_axis_angle_rad, r.stage_axis_measured) {
        if angle > b.stage_axis_warning_rad {
            f.add(
                "stage_axis",
                Quality::Warning,
                format!(
                    "the measured P2 − P1 axis in the flange frame ({}) is {:.2}° from the stage axis in use ({}) (warning above {:.0}°): the identification absorbs the difference into the wrist parameters; give the measured axis",
                    show(&m), angle.to_degrees(), show(&r.stage_axis), b.stage_axis_warning_rad.to_degrees()
                ),
            );
        }
    }
    if r.metrics.verify.is_none() {
        f.add(
            "no_verify_set",
            Quality::Warning,
            "no verification poses: nothing checks the result on poses it was not fitted to"
                .to_owned(),
        );
    }
    nongeometric_findings(&mut f, r, b);
    let quality = f.0.iter().map(|w| w.severity).max().unwrap_or(Quality::Ok);
    Verdict {
        quality,
        warnings: f.0,
    }
}

fn show(v: &[f64; 3]) -> String {
    format!("{:.4}, {:.4}, {:.4}", v[0], v[1], v[2])
}

/// `parameter_sigma`: every identified parameter whose σ exceeds its bound, worst first.
fn sigma_finding(f: &mut Findings, r: &IdentifyReport, b: &QualityBounds) {
    let mut over: Vec<(f64, String)> = r
        .parameters
        .iter()
        .filter(|p| p.identified)
        .filter_map(|p| {
            let bound = if p.unit == "rad" {
                b.sigma_rad
            } else {
                b.sigma_mm
            };
            let sigma = p.std.unwrap_or(f64::NAN);
            // an undetermined σ (singular normal matrix) is as bad as it gets
            let ratio = if sigma.is_finite() {
                sigma / bound
            } else {
                f64::INFINITY
            };
            (ratio > 1.0).then(|| {
                let text = if !sigma.is_finite() {
                    format!("{} σ undetermined", p.name)
                } else if p.unit == "rad" {
                    format!("{} σ {:.3} mrad", p.name, sigma * 1e3)
                } else {
                    format!("{} σ {:.3} mm", p.name, sigma)
                };
                (ratio, text)
            })
        })
        .collect();
    if over.is_empty() {
        return;
    }
    over.sort_by(|a, b| b.0.total_cmp(&a.0));
    let worst = over[0].0;
    let names: Vec<&str> = over.iter().map(|(_, t)| t.as_str()).collect();
    f.graded(
        "parameter_sigma",
        worst,
        1.0,
        b.sigma_poor_factor,
        format!(
            "{} identified parameter(s) above the plausibility bound {} mm / {} mrad (poor above {}×): {}",
            over.len(),
            b.sigma_mm,
            b.sigma_rad * 1e3,
            b.sigma_poor_factor,
            names.join(", ")
        ),
    );
}

/// `too_few_poses`: identified parameters against the independent measured values.
fn poses_finding(f: &mut Findings, r: &IdentifyReport, b: &QualityBounds) {
    let poses = r
        .metrics
        .ident
        .after
        .poses
        .saturating_sub(r.rejected_poses.len());
    let equations = poses * values_per_pose(&r.model);
    let k = r.identified.len();
    let share = k as f64 / equations.max(1) as f64;
    f.graded(
        "too_few_poses",
        share,
        b.leverage_warning,
        b.leverage_poor,
        format!(
            "{k} parameters from {poses} poses ({equations} independent values): {:.0} % of the equations go into the parameters (warning above {:.0} %, poor above {:.0} %); measure more poses",
            100.0 * share,
            100.0 * b.leverage_warning,
            100.0 * b.leverage_poor
        ),
    );
}

/// The verdict on the non-geometric terms of an identification with terms (§10); none without.
///
/// - `nongeometric_unverified`: no verification set, so nothing judges the terms out of
///   sample (the identification RMS falls with every added parameter, noise or not).
/// - `nongeometric_not_better`: the extended model's verification position RMS is not below
///   the geometric model's fitted to the same data (exactly when `nongeometric_keep =
///   "better"` keeps the geometric one).
/// - `nongeometric_too_large`: rated from the counts, not from the fit, because the effect to
///   see (a few % of the floor) is below what 100–200 verification poses resolve (the RMS of
///   n·3 values scatters by about 1/√(6n), 3–4 %): a least-squares fit of k parameters to m
///   independent position values predicts new poses with the noise's variance times
///   (1 + k/m) on average, so its verification RMS stays near `√(1 + k/m)` × the noise floor
///   however true the model. With m = 3 × the identification poses (the verification error is
///   positional; direction rows add little to it) the extended model is too large for the poses
///   once that exceeds 1.05 (the figure of a model at the floor). Measured on the
///   simulated TX60 with typical terms (op, both families, 50 parameters): 100 poses 1.099×
///   the floor (predicted 1.080), 300 poses 1.032× (predicted 1.027)
///   (`tests/it/nongeometric.rs::the_verdict_says_when_the_term_set_is_too_large_for_the_poses`).
fn nongeometric_findings(f: &mut Findings, r: &IdentifyReport, b: &QualityBounds) {
    if r.nongeometric.is_empty() {
        return;
    }
    let families: Vec<&str> = r.nongeometric.iter().map(|t| t.name()).collect();
    let families = families.join(", ");
    let handed_over = match r.nongeometric_kept {
        Some(KeptModel::Geometric) => "the geometric model was handed over",
        _ => "the extended model was handed over",
    };
    let extended = match r.nongeometric_kept {
        Some(KeptModel::Geometric) => r.metrics_extended.as_ref(),
        _ => Some(&r.metrics),
    };
    let verify = |m: Option<&MetricsJson>| {
        m.and_then(|m| m.verify.as_ref())
            .map(|v| v.after.position_rms_mm)
    };
    match (
        verify(extended),
        verify(r.metrics_geometric.as_ref()),
    ) {
        (Some(e), Some(g)) if e >= g => f.add(
            "nongeometric_not_better",
            Quality::Warning,
            format!(
                "the extended model (geometric + {families}) verifies at {} mm rms, the geometric model fitted to the same data at {} mm: the terms do not make the robot more accurate where it was checked; {handed_over}",
                fmt_mm(e),
                fmt_mm(g)
            ),
        ),
        (Some(_), Some(_)) => {}
        _ => f.add(
            "nongeometric_unverified",
            Quality::Warning,
            format!(
                "non-geometric terms ({families}) without verification poses: nothing says whether the extended model beats the geometric one; {handed_over}"
            ),
        ),
    }
    // the extended model's identified parameters: the geometric ones of `identified` and the
    // identified terms (`identified` lists the terms only when the extended model was kept)
    let is_term = |n: &String| r.nongeometric_terms.iter().any(|t| &t.name == n);
    let terms = r
        .nongeometric_terms
        .iter()
        .filter(|t| t.status != ParamStatus::NotIdentified)
        .count();
    let k = r.identified.iter().filter(|n| !is_term(n)).count() + terms;
    let poses = r
        .metrics
        .ident
        .after
        .poses
        .saturating_sub(r.rejected_poses.len());
    let values = 3 * poses.max(1);
    let inflation = (1.0 + k as f64 / values as f64).sqrt();
    if inflation > b.nongeometric_inflation_warning {
        let needed = (k as f64 / (3.0 * (b.nongeometric_inflation_warning.powi(2) - 1.0))).ceil();
        f.add(
            "nongeometric_too_large",
            Quality::Warning,
            format!(
                "the extended model fits {k} parameters ({terms} of them terms: {families}) to {poses} poses: the noise alone keeps its verification error at about √(1 + {k}/(3 × {poses})) = {inflation:.3}× the noise floor (warning above {}×); measure at least {needed:.0} identification poses for this term set, or ask for fewer terms",
                b.nongeometric_inflation_warning
            ),
        );
    }
}

/// The measured stage axis against the one in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageAxisCheck {
    /// Mean measured unit direction (P2 − P1) in the flange frame of the initial model.
    pub measured: Vector3<f64>,
    /// Angle between `measured` and the stage axis in use (rad).
    pub angle_rad: f64,
    /// RMS angle of the single directions about `measured` (rad).
    pub scatter_rad: f64,
}

/// Poses the stage-axis check looks at (evenly spread over the data; deterministic).
const STAGE_CHECK_POSES: usize = 256;

/// The measured P2 − P1 directions expressed in the flange frame of `initial` (the initial
/// model of the identification: nominal, with the registered base when the base is
/// identified), against `obs`' stage axis. `None` when the model uses no direction.
pub fn stage_axis_check(
    initial: &RobotModel,
    poses: &[Measured],
    obs: &ObsConfig,
) -> Option<StageAxisCheck> {
    if !matches!(obs.model, ObsModel::Np | ObsModel::Op) {
        return None;
    }
    let step = poses.len().div_ceil(STAGE_CHECK_POSES).max(1);
    let local: Vec<Vector3<f64>> = poses
        .iter()
        .step_by(step)
        .filter_map(|m| Some(predict(initial, &m.q).r.transpose() * m.direction?))
        .collect();
    let sum: Vector3<f64> = local.iter().sum();
    let measured = sum.try_normalize(1e-12)?;
    let angle = |a: &Vector3<f64>, b: &Vector3<f64>| a.cross(b).norm().atan2(a.dot(b));
    let scatter = (local
        .iter()
        .map(|d| angle(d, &measured).powi(2))
        .sum::<f64>()
        / local.len() as f64)
        .sqrt();
    Some(StageAxisCheck {
        measured,
        angle_rad: angle(&measured, &obs.stage_axis),
        scatter_rad: scatter,
    })
}

/// Reading a stored contract, and judging it: here, beside the verdict, so the contract's
/// types name nothing of the verdict's rules.
impl IdentifyReport {
    /// A stored report; one stored before the verdict existed is assessed now.
    pub fn from_json(text: &str) -> Result<IdentifyReport, serde_json::Error> {
        IdentifyReport::from_value(serde_json::from_str(text)?)
    }

    /// [`IdentifyReport::from_json`] of a parsed document.
    pub fn from_value(value: serde_json::Value) -> Result<IdentifyReport, serde_json::Error> {
        let assessed = value.get("quality").is_some();
        let has_status = value
            .pointer("/parameters/0")
            .is_none_or(|p| p.get("status").is_some());
        let mut report: IdentifyReport = serde_json::from_value(value)?;
        if !has_status {
            for p in &mut report.parameters {
                p.status = if !p.identified {
                    ParamStatus::NotIdentified
                } else if report.setup_relative.iter().any(|d| d.name == p.name) {
                    ParamStatus::SetupRelative
                } else {
                    ParamStatus::Identified
                };
            }
        }
        if !assessed {
            report.judge(&QualityBounds::default());
        }
        Ok(report)
    }

    /// Set `quality` and `warnings` from the rest of the report.
    pub fn judge(&mut self, bounds: &QualityBounds) {
        let v = assess(self, bounds);
        self.quality = v.quality;
        self.warnings = v.warnings;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::metrics::Metrics;
    use crate::calibrate::identify_json::{
        BaseJson, BeforeAfter, CorrelationJson, MetricsJson, ParameterJson, SolverJson, ToolJson,
    };

    fn metrics(poses: usize, rms: f64) -> Metrics {
        Metrics {
            poses,
            position_mean_mm: rms,
            position_max_mm: rms,
            position_rms_mm: rms,
            position_p95_mm: rms,
            position_axial_mean_mm: [rms; 3],
            position_axial_max_mm: [rms; 3],
            attitude_mean_rad: None,
            attitude_max_rad: None,
            attitude_rms_rad: None,
        }
    }

    fn param(name: &str, unit: &str, std: f64) -> ParameterJson {
        ParameterJson {
            name: name.into(),
            joint: Some(1),
            kind: "d".into(),
            unit: unit.into(),
            nominal: 0.0,
            error: 0.0,
            std: Some(std),
            identified: true,
            status: crate::calibrate::identify_json::ParamStatus::Identified,
        }
    }

    /// A good OP result: 100 poses, 24 parameters, verify at the noise floor.
    fn good() -> IdentifyReport {
        IdentifyReport {
            model: "op".into(),
            identified: (0..24).map(|i| format!("p{i}")).collect(),
            not_identifiable: vec![],
            parameters: vec![param("d1", "mm", 0.02), param("theta1", "rad", 2e-4)],
            base: BaseJson {
                translation_mm: [0.0; 3],
                rotation_vector_rad: [0.0; 3],
            },
            tool: ToolJson {
                translation_mm: [0.0; 3],
            },
            solver: SolverJson {
                iterations: 3,
                converged: true,
                final_cost: 0.05,
                termination: "relative cost reduction below tolerance".into(),
            },
            metrics: MetricsJson {
                ident: BeforeAfter {
                    before: metrics(100, 0.8),
                    after: metrics(100, 0.025),
                },
                verify: Some(BeforeAfter {
                    before: metrics(200, 0.8),
                    after: metrics(200, 0.026),
                }),
            },
            stage_axis: [0.0, 1.0, 0.0],
            direction_weight_mm: 7.07,
            condition_number: 9.0,
            sigma0_mm: 0.014,
            rejected_poses: vec![],
            correlation: CorrelationJson {
                names: vec![],
                matrix: vec![],
            },
            stage_axis_measured: Some([0.0, 1.0, 0.0]),
            stage_axis_angle_rad: Some(0.002),
            quality: Quality::Ok,
            warnings: vec![],
            before_base: None,
            setup_relative: vec![],
            ident_stop: None,
            nongeometric: Vec::new(),
            nongeometric_terms: Vec::new(),
            metrics_geometric: None,
            nongeometric_kept: None,
            metrics_extended: None,
            gravity: None,
            masses: Vec::new(),
        }
    }

    fn codes(r: &IdentifyReport) -> (Quality, Vec<(String, Quality)>) {
        let v = assess(r, &QualityBounds::default());
        (
            v.quality,
            v.warnings
                .into_iter()
                .map(|w| (w.code, w.severity))
                .collect(),
        )
    }

    fn one(code: &str, q: Quality) -> (Quality, Vec<(String, Quality)>) {
        (q, vec![(code.to_owned(), q)])
    }

    #[test]
    fn the_verdict_s_messages_give_lengths_in_mm_with_three_decimals() {
        let mut r = good();
        if let Some(m) = r.metrics.verify.as_mut() {
            m.after.position_rms_mm = 0.04254;
        }
        let v = assess(&r, &QualityBounds::default());
        let overfit = v
            .warnings
            .iter()
            .find(|w| w.code == "overfit")
            .expect("overfit");
        assert!(
            overfit
                .message
                .starts_with("verification position RMS 0.043 mm is "),
            "{}",
            overfit.message
        );
    }

    #[test]
    fn a_good_result_is_ok() {
        assert_eq!(codes(&good()), (Quality::Ok, vec![]));
    }

    #[test]
    fn each_rule_grades_its_finding() {
        use Quality::{Poor, Warning};
        let with = |f: &dyn Fn(&mut IdentifyReport)| {
            let mut r = good();
            f(&mut r);
            codes(&r)
        };
        assert_eq!(
            with(&|r| r.solver.converged = false),
            one("not_converged", Poor)
        );
        assert_eq!(
            with(&|r| r.condition_number = 6016.0),
            one("condition_number", Warning)
        );
        assert_eq!(
            with(&|r| r.condition_number = 2e5),
            one("condition_number", Poor)
        );
        assert_eq!(
            with(&|r| r.condition_number = f64::NAN),
            one("condition_number", Poor)
        );
        assert_eq!(
            with(&|r| r.parameters[0].std = Some(0.06)),
            one("parameter_sigma", Warning)
        );
        assert_eq!(
            with(&|r| r.parameters[1].std = Some(6e-3)),
            one("parameter_sigma", Poor)
        );
        assert_eq!(
            with(&|r| r.parameters[0].std = None),
            one("parameter_sigma", Poor)
        );
        // 24 parameters: 15 poses × 5 values = 75 → 32 % ok; 14 → 34 % warning; 9 → 53 % poor
        let poses = |n: usize| move |r: &mut IdentifyReport| r.metrics.ident.after.poses = n;
        assert_eq!(with(&poses(15)), (Quality::Ok, vec![]));
        assert_eq!(with(&poses(14)), one("too_few_poses", Warning));
        assert_eq!(with(&poses(9)), one("too_few_poses", Poor));
        let verify_after = |v: f64| {
            move |r: &mut IdentifyReport| {
                if let Some(m) = r.metrics.verify.as_mut() {
                    m.after.position_rms_mm = v;
                }
            }
        };
        assert_eq!(with(&verify_after(0.04)), one("overfit", Warning));
        assert_eq!(with(&verify_after(0.08)), one("overfit", Poor));
        let unchanged = |r: &mut IdentifyReport| {
            if let Some(m) = r.metrics.verify.as_mut() {
                m.after.position_rms_mm = m.before.position_rms_mm + 1e-12;
            }
        };
        assert!(with(&unchanged)
            .1
            .iter()
            .all(|(code, _)| code != "verify_worse"));
        let (q, c) = with(&verify_after(0.9));
        assert_eq!(q, Poor);
        assert_eq!(c[0], ("verify_worse".to_owned(), Poor));
        assert_eq!(
            with(&|r| r.rejected_poses = vec!["7".into()]),
            one("outliers_rejected", Warning)
        );
        assert_eq!(
            with(&|r| r.rejected_poses = (0..11).map(|i| i.to_string()).collect()),
            one("outliers_rejected", Poor)
        );
        assert_eq!(
            with(&|r| r.stage_axis_angle_rad = Some(0.03)),
            one("stage_axis", Warning)
        );
        assert_eq!(
            with(&|r| r.metrics.verify = None),
            one("no_verify_set", Warning)
        );
    }

    /// [`good`] as an extended identification (both families) of `poses` poses: 24 geometric
    /// parameters and `terms` identified terms (and one held), verifying at `extended` mm rms
    /// against the geometric model's `geometric` mm.
    fn extended(poses: usize, terms: usize, extended: f64, geometric: f64) -> IdentifyReport {
        use crate::calibrate::identify_json::TermJson;
        let mut r = good();
        r.metrics.ident.after.poses = poses;
        let term = |i: usize, identified: bool| TermJson {
            name: format!("sin_q{i}"),
            joint: 1,
            kind: "sin_q".into(),
            value: 0.0,
            sigma: identified.then_some(1e-5),
            unit: "rad".into(),
            status: if identified {
                ParamStatus::Identified
            } else {
                ParamStatus::NotIdentified
            },
            reason: (!identified).then(|| "not determined".to_owned()),
        };
        r.nongeometric_terms = (0..=terms).map(|i| term(i, i < terms)).collect();
        r.identified
            .extend(r.nongeometric_terms[..terms].iter().map(|t| t.name.clone()));
        r.nongeometric = crate::model::TermFamily::ALL.to_vec();
        r.nongeometric_kept = Some(KeptModel::Extended);
        let mut geo = r.metrics.clone();
        if let Some(v) = geo.verify.as_mut() {
            v.after.position_rms_mm = geometric;
        }
        if let Some(v) = r.metrics.verify.as_mut() {
            v.after.position_rms_mm = extended;
        }
        r.metrics_geometric = Some(geo);
        r
    }

    #[test]
    fn the_terms_are_judged_out_of_sample_and_by_their_number() {
        use Quality::Warning;
        // 300 poses, 24 + 25 parameters: √(1 + 49/900) = 1.027; verifies better: ok
        assert_eq!(
            codes(&extended(300, 25, 0.025, 0.03)),
            (Quality::Ok, vec![])
        );
        // not better (a tie is not better)
        assert_eq!(
            codes(&extended(300, 25, 0.026, 0.026)),
            one("nongeometric_not_better", Warning)
        );
        // the geometric one kept by `better`: judged by the extended model's metrics
        let mut kept = extended(300, 25, 0.026, 0.026);
        kept.nongeometric_kept = Some(KeptModel::Geometric);
        kept.metrics_extended = Some(kept.metrics.clone());
        if let Some(v) = kept
            .metrics_extended
            .as_mut()
            .and_then(|m| m.verify.as_mut())
        {
            v.after.position_rms_mm = 0.03;
        }
        let v = assess(&kept, &QualityBounds::default());
        assert_eq!(v.warnings.len(), 1, "{:?}", v.warnings);
        assert!(
            v.warnings[0]
                .message
                .ends_with("the geometric model was handed over"),
            "{}",
            v.warnings[0].message
        );
        // 100 poses, 24 + 25 parameters: √(1 + 49/300) = 1.079 > 1.05
        let v = assess(&extended(100, 25, 0.025, 0.03), &QualityBounds::default());
        assert_eq!(
            (v.quality, v.warnings.len(), v.warnings[0].code.as_str()),
            (Warning, 1, "nongeometric_too_large")
        );
        assert!(
            v.warnings[0].message.starts_with(
                "the extended model fits 49 parameters (25 of them terms: compliance, \
                 harmonics) to 100 poses: the noise alone keeps its verification error at \
                 about √(1 + 49/(3 × 100)) = 1.079× the noise floor (warning above 1.05×); \
                 measure at least 160 identification poses"
            ),
            "{}",
            v.warnings[0].message
        );
        // 160 poses: √(1 + 49/480) = 1.0498
        assert_eq!(
            codes(&extended(160, 25, 0.025, 0.03)),
            (Quality::Ok, vec![])
        );
        // no verification set: the terms are not judged
        let mut blind = extended(300, 25, 0.025, 0.03);
        blind.metrics.verify = None;
        if let Some(m) = blind.metrics_geometric.as_mut() {
            m.verify = None;
        }
        let (_, c) = codes(&blind);
        assert_eq!(
            c,
            vec![
                ("no_verify_set".to_owned(), Warning),
                ("nongeometric_unverified".to_owned(), Warning)
            ]
        );
        // a geometric identification has none of them
        assert_eq!(codes(&good()), (Quality::Ok, vec![]));
    }
}
