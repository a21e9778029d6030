//! The `cellcal identify` JSON contract: [`IdentifyReport`] and its parts.
//!
//! JSON fields (contract, extend only): `model`, `identified`, `not_identifiable`
//! (`{name, reason}`; extended by `kind`: `structural` | `dependent` | `poorly_determined` and
//! `predicted_sigma`, mm or rad, null when unbounded), `parameters` (`{name, joint, kind, unit, nominal, error, std,
//! identified}`, error = identified − nominal), `base` (`{translation_mm, rotation_vector_rad}`),
//! `tool` (`{translation_mm}`), `solver` (`{iterations, converged, final_cost}`), `metrics`
//! (`{ident: {before, after}, verify: {before, after}}`). Extensions: `stage_axis`,
//! `direction_weight_mm`, `condition_number`, `sigma0_mm`, `rejected_poses`, `correlation`,
//! `solver.termination`, metric fields `position_p95_mm`, `attitude_rms_rad`,
//! `stage_axis_measured` and `stage_axis_angle_rad` (null without direction data), the
//! verdict: `quality` (`ok`|`warning`|`poor`) and `warnings` (`{code, severity, message}`), see
//! [`super::quality`], `before_base` (`setup_registration` | `fitted_to_poses` |
//! `robot_model`: the base of the "before" metrics, [`BeforeBase`]; null in results stored
//! before it), `setup_relative` (`{name, reason, kind, predicted_sigma}` like
//! `not_identifiable`: identified parameters the held setup — measured tool, stage axis,
//! registered base — would take over were it free; `predicted_sigma` their σ then, null when
//! unbounded) and the parameters' `status` (`identified` | `setup_relative` | `not_identified`;
//! `setup_relative` ones are identified too, their value and σ conditional on the setup).
//!
//! Non-geometric terms (§10; present only when terms were asked for, so a geometric result's
//! JSON is as before): `nongeometric` (the families, `compliance` | `harmonics`),
//! `nongeometric_terms` (`{name, joint, kind, value, sigma, unit, status, reason}`: every
//! candidate term, `value` its absolute coefficient in `unit` — `rad/(N·m)` or `rad` —,
//! `sigma` null when held at zero, `reason` why it is held), `metrics_geometric` (like `metrics`,
//! for the geometric model fitted to the same data; `metrics` describes the model handed
//! over), `nongeometric_kept` (`extended` | `geometric`: the model handed over), when the
//! geometric one was kept, `metrics_extended`, and the torque model's inputs: `gravity` (unit
//! vector, robot base frame) and `masses` (`{frame, at_mm, kg}`; absent when the robot has none). The terms are in `identified`,
//! `not_identifiable` and `correlation` (every parameter of the fit) but not in `parameters`,
//! whose rows are the geometric model's (`nominal + error` of an MDH, base or tool value).

use serde::{Deserialize, Serialize};

use crate::analysis::metrics::Metrics;
use crate::identify::{BeforeBase, DropKind, Dropped};
use crate::model::{Mass, RobotModel, TermFamily};

/// `{name, reason, kind, predicted_sigma}` of a parameter held at nominal.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NotIdentifiable {
    /// Parameter name.
    pub name: String,
    /// Why it cannot be identified.
    pub reason: String,
    /// `structural`, `dependent` or `poorly_determined` ([`DropKind::name`]); results stored
    /// before the practical test read as `structural`.
    #[serde(default = "structural")]
    pub kind: String,
    /// Its predicted σ had it been identified (mm or rad, the parameter's unit); null when
    /// unbounded (structural).
    #[serde(default)]
    pub predicted_sigma: Option<f64>,
}

fn structural() -> String {
    DropKind::Structural.name().to_owned()
}

impl NotIdentifiable {
    pub(super) fn of(d: &Dropped) -> NotIdentifiable {
        NotIdentifiable {
            name: d.param.name(),
            reason: d.reason.clone(),
            kind: d.kind.name().to_owned(),
            predicted_sigma: d.predicted_sigma,
        }
    }
}

/// What an identification made of a parameter.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ParamStatus {
    /// Identified; its value is the robot's.
    Identified,
    /// Identified relative to the setup: the held setup would take it over were it free, so
    /// its value and σ hold given the measured tool, stage axis (and registered base).
    SetupRelative,
    /// Held at nominal (`not_identifiable` says why).
    #[default]
    NotIdentified,
}

impl ParamStatus {
    /// Contract name: `identified`, `setup_relative`, `not_identified`.
    pub fn name(self) -> &'static str {
        match self {
            ParamStatus::Identified => "identified",
            ParamStatus::SetupRelative => "setup_relative",
            ParamStatus::NotIdentified => "not_identified",
        }
    }
}

/// One parameter row.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ParameterJson {
    /// Name (`theta1`, `base_tx`, `tool_y`, …).
    pub name: String,
    /// Joint number (1-based), null for base/tool.
    pub joint: Option<usize>,
    /// Kind (`theta`, `d`, `a`, `alpha`, `beta`, `base_translation`, …).
    pub kind: String,
    /// `mm` or `rad`.
    pub unit: String,
    /// Value before identification.
    pub nominal: f64,
    /// Identified − nominal.
    pub error: f64,
    /// Standard deviation of `error` (null when not identified).
    pub std: Option<f64>,
    /// Whether identified.
    pub identified: bool,
    /// `identified`, `setup_relative` (identified, conditional on the setup) or
    /// `not_identified`; results stored before it get it from `identified` and
    /// `setup_relative` when read ([`IdentifyReport::from_json`]).
    #[serde(default)]
    pub status: ParamStatus,
}

/// One non-geometric term of an identification with terms (`nongeometric_terms`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TermJson {
    /// Public name (`compliance2`, `sin_q3`, `cos_2q6`).
    pub name: String,
    /// Joint number (1-based).
    pub joint: usize,
    /// `compliance`, `sin_q`, `cos_q`, `sin_2q` or `cos_2q`.
    pub kind: String,
    /// The identified coefficient (absolute; 0 when held), in `unit`.
    pub value: f64,
    /// Its standard deviation (null when not identified).
    pub sigma: Option<f64>,
    /// `rad/(N·m)` (compliance) or `rad` (harmonic).
    pub unit: String,
    /// `identified`, `setup_relative` or `not_identified` (held at zero).
    pub status: ParamStatus,
    /// Why it is held at zero (null when identified).
    #[serde(default)]
    pub reason: Option<String>,
}

/// One lumped mass of the torque model an identification with terms used (`masses`, §10).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MassJson {
    /// The MDH frame it is fixed in (1…n).
    pub frame: usize,
    /// Its centre of mass in that frame (mm).
    pub at_mm: [f64; 3],
    /// Its mass (kg).
    pub kg: f64,
}

impl MassJson {
    /// The JSON row of mass `m`.
    pub fn of(m: &Mass) -> MassJson {
        MassJson {
            frame: m.frame,
            at_mm: m.at.into(),
            kg: m.kg,
        }
    }
}

/// Which model a calibration with non-geometric terms handed over.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum KeptModel {
    /// The geometric model with the terms.
    Extended,
    /// The geometric model alone (`nongeometric_keep = "better"` and it verified better).
    Geometric,
}

impl KeptModel {
    /// Contract name: `extended`, `geometric`.
    pub fn name(self) -> &'static str {
        match self {
            KeptModel::Extended => "extended",
            KeptModel::Geometric => "geometric",
        }
    }
}

/// Base transform (robot base → measurement frame).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BaseJson {
    /// Translation (mm).
    pub translation_mm: [f64; 3],
    /// Rotation vector (rad).
    pub rotation_vector_rad: [f64; 3],
}

/// Tool (ball in the flange frame).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ToolJson {
    /// Translation (mm).
    pub translation_mm: [f64; 3],
}

/// Solver summary.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SolverJson {
    /// Accepted iterations.
    pub iterations: usize,
    /// Whether it converged.
    pub converged: bool,
    /// Final cost ½Σr² (mm²).
    pub final_cost: f64,
    /// Termination reason.
    pub termination: String,
}

/// Before/after metrics of one set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BeforeAfter {
    /// Nominal (initial) model.
    pub before: Metrics,
    /// Identified model.
    pub after: Metrics,
}

/// Metrics of both sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsJson {
    /// Identification set.
    pub ident: BeforeAfter,
    /// Verification set (null when the data has none).
    pub verify: Option<BeforeAfter>,
}

/// Correlation matrix of the identified parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CorrelationJson {
    /// Parameter names (row/column order).
    pub names: Vec<String>,
    /// Row-major matrix.
    pub matrix: Vec<Vec<f64>>,
}

/// The whole `cellcal identify` JSON document.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct IdentifyReport {
    /// `position`, `np`, `op` or `full`.
    pub model: String,
    /// Identified parameter names.
    pub identified: Vec<String>,
    /// Dropped parameters and why.
    pub not_identifiable: Vec<NotIdentifiable>,
    /// Every candidate parameter.
    pub parameters: Vec<ParameterJson>,
    /// Base transform after identification.
    pub base: BaseJson,
    /// Tool after identification.
    pub tool: ToolJson,
    /// Solver summary.
    pub solver: SolverJson,
    /// Accuracy before/after.
    pub metrics: MetricsJson,
    /// Stage axis `u` in the flange frame.
    pub stage_axis: [f64; 3],
    /// Weight of direction rows (mm).
    pub direction_weight_mm: f64,
    /// Condition number of the scaled identified Jacobian.
    pub condition_number: f64,
    /// A-posteriori σ of unit weight (mm).
    pub sigma0_mm: f64,
    /// Pose ids rejected by `--robust`.
    pub rejected_poses: Vec<String>,
    /// Correlations of the identified parameters.
    pub correlation: CorrelationJson,
    /// Mean measured P2 − P1 direction in the flange frame of the initial model (null without
    /// direction data).
    #[serde(default)]
    pub stage_axis_measured: Option<[f64; 3]>,
    /// Angle between `stage_axis_measured` and `stage_axis` (rad).
    #[serde(default)]
    pub stage_axis_angle_rad: Option<f64>,
    /// The verdict: `ok`, `warning` or `poor` (the worst of `warnings`).
    #[serde(default)]
    pub quality: Quality,
    /// What the verdict found.
    #[serde(default)]
    pub warnings: Vec<QualityWarning>,
    /// The base of the "before" metrics (null in results stored before it was named).
    #[serde(default)]
    pub before_base: Option<BeforeBase>,
    /// Identified parameters relative to the setup, and why.
    #[serde(default)]
    pub setup_relative: Vec<NotIdentifiable>,
    /// A campaign with `stop_when = "predicted"`: when and why it stopped measuring
    /// identification poses (absent otherwise, and from `cellcal identify`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ident_stop: Option<IdentStop>,
    /// The families of non-geometric terms asked for (absent: a geometric identification).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nongeometric: Vec<TermFamily>,
    /// Every candidate non-geometric term of the extended fit (absent without terms).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nongeometric_terms: Vec<TermJson>,
    /// The metrics of the geometric model fitted to the same data with the same options
    /// (absent without terms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics_geometric: Option<MetricsJson>,
    /// Which model was handed over (absent without terms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nongeometric_kept: Option<KeptModel>,
    /// The extended model's metrics when the geometric one was kept (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics_extended: Option<MetricsJson>,
    /// The torque model's direction of gravity (unit vector, robot base frame) of an
    /// identification with terms (absent without terms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity: Option<[f64; 3]>,
    /// The torque model's lumped masses of an identification with terms (absent without terms,
    /// or when the robot model has none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub masses: Vec<MassJson>,
}

impl IdentifyReport {
    /// Name the torque model of `robot` (`gravity`, `masses`): the inputs of the gravity
    /// torques an identification with terms computed its compliance with.
    pub fn set_torque_model(&mut self, robot: &RobotModel) {
        self.gravity = Some(robot.gravity.into());
        self.masses = robot.masses.iter().map(MassJson::of).collect();
    }
}

/// Why a campaign stopped measuring identification poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// A block improved the predicted verification error by less than `stop_min_gain`.
    MinGain,
    /// The predicted verification error reached `target_verify_mm`.
    Target,
    /// Every identification pose still planned would improve the predicted verification error
    /// by less than `stop_remaining_gain`.
    RemainingGain,
    /// Every planned identification pose was measured before the rule stopped them.
    Planned,
}

impl StopReason {
    /// Its JSON spelling (`min_gain`, `target`, `remaining_gain`, `planned`).
    pub fn as_str(self) -> &'static str {
        match self {
            StopReason::MinGain => "min_gain",
            StopReason::Target => "target",
            StopReason::RemainingGain => "remaining_gain",
            StopReason::Planned => "planned",
        }
    }
}

/// The stop rule's check after a block of identification poses: an identification on the
/// measured poses and its predicted verification error at the planned verification poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IdentCheck {
    /// Identification poses measured when it was made.
    pub after_poses: usize,
    /// Predicted mean verification error of that identification (mm).
    pub predicted_mm: f64,
    /// The part of it the tracker's noise alone makes (mm).
    pub noise_floor_mm: f64,
    /// Relative improvement the last block bought, `(without − with) / without`, both
    /// predicted from this check's identification (null for the first check; in checks stored
    /// before 2026-11-26 evening: on the previous check's prediction).
    pub gain: Option<f64>,
    /// Why this check stopped the identification poses (null: measuring on).
    pub stopped: Option<StopReason>,
    /// The same prediction had every planned identification pose been measured (mm; null in
    /// checks stored before it was made).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_all_mm: Option<f64>,
    /// Relative improvement the identification poses still planned would buy,
    /// `(this − all) / this` (null in checks stored before it was made).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remaining_gain: Option<f64>,
    /// Parameters the whole plan identifies that this check's identification held back (their
    /// error is in no prediction: the rule does not stop while there are any).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub held_back: Vec<String>,
}

/// `ident_stop` of a result: how the stop rule ended the identification poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IdentStop {
    /// Why the identification poses ended.
    pub reason: StopReason,
    /// Identification poses measured (the identification uses these).
    pub ident_measured: usize,
    /// Identification poses planned (the rest were skipped, never measured).
    pub ident_planned: usize,
    /// The predicted verification error of the check that stopped them, else of the last
    /// check (mm; null without a check).
    pub predicted_mm: Option<f64>,
    /// The rule's fraction (`campaign.stop_min_gain`).
    pub stop_min_gain: f64,
    /// The rule's fraction for the poses still planned (`campaign.stop_remaining_gain`; null
    /// in results stored before it was made).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stop_remaining_gain: Option<f64>,
    /// The rule's target (`campaign.target_verify_mm`, mm).
    pub target_verify_mm: Option<f64>,
    /// Every check, in order.
    pub history: Vec<IdentCheck>,
}

/// The verdict's three levels, ordered by severity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Quality {
    /// Nothing found that argues against using the result.
    #[default]
    Ok,
    /// Usable, with a caveat the user must read.
    Warning,
    /// Do not load these parameters without fixing the cause (`identify` and `run` exit 3).
    Poor,
}

impl Quality {
    /// Contract spelling (`ok`, `warning`, `poor`).
    pub fn as_str(self) -> &'static str {
        match self {
            Quality::Ok => "ok",
            Quality::Warning => "warning",
            Quality::Poor => "poor",
        }
    }
}

/// One finding of the verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QualityWarning {
    /// Stable code (`not_converged`, `condition_number`, …; see the module table).
    pub code: String,
    /// What this finding alone makes of the result (`warning` or `poor`).
    pub severity: Quality,
    /// Human explanation with the figures.
    pub message: String,
}
