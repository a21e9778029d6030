//! The `cellcal identify` pipeline (rows → identification → metrics) and its JSON contract.
//!
//! JSON fields (contract, extend only): `model`, `identified`, `not_identifiable`
//! (`{name, reason}`), `parameters` (`{name, joint, kind, unit, nominal, error, std,
//! identified}`, error = identified − nominal), `base` (`{translation_mm, rotation_vector_rad}`),
//! `tool` (`{translation_mm}`), `solver` (`{iterations, converged, final_cost}`), `metrics`
//! (`{ident: {before, after}, verify: {before, after}}`). Extensions: `stage_axis`,
//! `direction_weight_mm`, `condition_number`, `sigma0_mm`, `rejected_poses`, `correlation`,
//! `solver.termination`, metric fields `position_p95_mm`, `attitude_rms_rad`.

use serde::{Deserialize, Serialize};

use crate::analysis::metrics::{evaluate_pair, Metrics};
use crate::dataset::{split, to_measured, ConvertError, Observation};
use crate::identify::{identify, Identification, IdentifyError, IdentifyOptions};
use crate::model::rotation::to_rotation_vector;
use crate::model::RobotModel;

/// Why the pipeline failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalibrateError {
    /// A row is unusable for the model.
    #[error(transparent)]
    Convert(#[from] ConvertError),
    /// The identification could not run.
    #[error(transparent)]
    Identify(#[from] IdentifyError),
    /// No identification rows.
    #[error("no rows with set = ident")]
    NoIdentRows,
}

/// `{name, reason}` of a dropped parameter.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NotIdentifiable {
    /// Parameter name.
    pub name: String,
    /// Why it cannot be identified.
    pub reason: String,
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
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BeforeAfter {
    /// Nominal (initial) model.
    pub before: Metrics,
    /// Identified model.
    pub after: Metrics,
}

/// Metrics of both sets.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
}

/// Run the identify pipeline on data-set rows.
pub fn calibrate(
    robot: &RobotModel,
    rows: &[Observation],
    opts: &IdentifyOptions,
    stage_travel_mm: f64,
) -> Result<(IdentifyReport, Identification), CalibrateError> {
    let (ident_rows, verify_rows) = split(rows);
    if ident_rows.is_empty() {
        return Err(CalibrateError::NoIdentRows);
    }
    let model = opts.obs.model;
    let ident = to_measured(&ident_rows, model, stage_travel_mm)?;
    let verify = to_measured(&verify_rows, model, stage_travel_mm)?;
    let id = identify(robot, &ident, opts)?;
    let m = |set: &[_]| {
        let (before, after) = evaluate_pair(&id.initial, &id.corrected, set, &opts.obs);
        BeforeAfter { before, after }
    };
    let metrics = MetricsJson {
        ident: m(&ident),
        verify: (!verify.is_empty()).then(|| m(&verify)),
    };
    let names: Vec<String> = id
        .identifiability
        .identified
        .iter()
        .map(|p| p.name())
        .collect();
    let k = names.len();
    let report = IdentifyReport {
        model: model.name().to_owned(),
        identified: names.clone(),
        not_identifiable: id
            .identifiability
            .dropped
            .iter()
            .map(|d| NotIdentifiable {
                name: d.param.name(),
                reason: d.reason.clone(),
            })
            .collect(),
        parameters: id
            .estimates
            .iter()
            .map(|e| ParameterJson {
                name: e.param.name(),
                joint: e.param.joint_number(),
                kind: e.param.kind_name().to_owned(),
                unit: e.param.unit().to_owned(),
                nominal: e.nominal,
                error: e.error,
                std: e.std,
                identified: e.identified,
            })
            .collect(),
        base: BaseJson {
            translation_mm: id.corrected.base_translation.into(),
            rotation_vector_rad: to_rotation_vector(&id.corrected.base_rotation).into(),
        },
        tool: ToolJson {
            translation_mm: id.corrected.tool.into(),
        },
        solver: SolverJson {
            iterations: id.iterations,
            converged: id.termination.converged(),
            final_cost: id.final_cost,
            termination: id.termination.describe().to_owned(),
        },
        metrics,
        stage_axis: opts.obs.stage_axis.into(),
        direction_weight_mm: opts.obs.direction_weight_mm,
        condition_number: id.identifiability.condition_number(),
        sigma0_mm: id.sigma0_mm,
        rejected_poses: id
            .rejected
            .iter()
            .map(|&i| ident_rows[i].id.clone())
            .collect(),
        correlation: CorrelationJson {
            names,
            matrix: (0..k)
                .map(|i| (0..k).map(|j| id.correlation[(i, j)]).collect())
                .collect(),
        },
    };
    Ok((report, id))
}
