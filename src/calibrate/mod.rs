//! The calibration: the `cellcal identify` pipeline (rows → identification → metrics →
//! verdict, [`calibrate`]), its JSON contract ([`identify_json`]), the verdict ([`quality`]),
//! the typed result a campaign stores once and every view renders ([`result`]: the contract
//! plus the per-pose residuals and the corrected model) and the cell setup it is given
//! ([`setup`]). Below `report/` (which renders it) and `campaign/` (which stores it); knows no
//! files, no store, no devices.

pub mod campaign_time;
pub mod identify_json;
pub mod quality;
pub mod result;
pub mod setup;

pub use campaign_time::CampaignTime;
pub use identify_json::{
    IdentCheck, IdentStop, IdentifyReport, KeptModel, MassJson, ParamStatus, StopReason, TermJson,
};
pub use quality::{Quality, QualityWarning};
pub use result::{
    corrected_model, BaseSource, CalibrationResult, CorrectedModel, ModelFileError, ParamValue,
    PoseError, PoseErrors, SetErrors,
};
pub use setup::{BaseResult, SetupResult, ToolFrameResult};

use crate::analysis::metrics::evaluate_pair;
use crate::dataset::{split_measured, ConvertError, Observation, PoseSet};
use crate::identify::observation::{predict, Measured};
use crate::identify::{
    identify_with, Identification, IdentifyError, IdentifyOptions, JointTrig, Nongeometric,
    NongeometricKeep,
};
use crate::measure::rigid::fit_rigid;
use crate::model::rotation::log_so3;
use crate::model::RobotModel;
use identify_json::{
    BaseJson, BeforeAfter, CorrelationJson, MetricsJson, NotIdentifiable, ParameterJson,
    SolverJson, ToolJson,
};
use nalgebra::Vector3;
use quality::{stage_axis_check, QualityBounds};

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
    /// The measured positions are in a frame far from the robot base (the tracker's), and the
    /// base is neither identified nor given: checked before the stage axis, which would be
    /// blamed for it.
    #[error(
        "the data is in another frame than the robot base (the tracker's): the measured \
         positions lie {raw_rms_mm:.0} mm (rms) from where the robot model puts the ball, but a \
         rigid move of {translation_mm:.0} mm, turned {angle_deg:.1}°, brings them within \
         {fitted_rms_mm:.1} mm. Add --identify-base (the base is then identified with the rest), \
         or give the base in the data's header (`# base_translation_mm = X,Y,Z`, \
         `# base_rotation_vector_rad = X,Y,Z`; `cellcal export` writes them)"
    )]
    FrameFarFromBase {
        /// RMS distance of the measured positions from the model's (mm).
        raw_rms_mm: f64,
        /// Translation of the rigid fit (mm): the robot base origin in the data's frame.
        translation_mm: f64,
        /// Rotation angle of the rigid fit (deg).
        angle_deg: f64,
        /// RMS distance after the rigid fit (mm).
        fitted_rms_mm: f64,
    },
    /// The measured P2 − P1 directions contradict the stage axis (or the model) in use.
    #[error("the stage axis in use ({}) contradicts the data: the measured P2 − P1 directions in the flange frame average ({}), {:.1}° away, scattering {:.1}° (limit {:.0}°). Give the stage axis the stage is mounted along (`--stage-axis X,Y,Z`; the np model assumes +x, op +y)", show3(used), show3(measured), angle_deg, scatter_deg, limit_deg)]
    StageAxisContradiction {
        /// Stage axis in use (flange frame).
        used: [f64; 3],
        /// Mean measured direction (flange frame of the initial model).
        measured: [f64; 3],
        /// Angle between them (deg).
        angle_deg: f64,
        /// RMS scatter of the single directions (deg).
        scatter_deg: f64,
        /// The refusal limit (deg).
        limit_deg: f64,
    },
}

fn show3(v: &[f64; 3]) -> String {
    format!("{:.3}, {:.3}, {:.3}", v[0], v[1], v[2])
}

/// Positions this far (rms, mm) from the model's are not robot errors (a few mm at most)...
const FRAME_FAR_MM: f64 = 50.0;
/// ...when a rigid move brings them within this fraction of it: a frame, not the robot.
const FRAME_FIT_FRACTION: f64 = 0.2;
/// Poses the frame check looks at (spread over the set).
const FRAME_CHECK_POSES: usize = 200;

/// [`CalibrateError::FrameFarFromBase`] when the measured positions of `poses` are far from
/// `robot`'s prediction (its base, tool) and a rigid move explains most of it.
fn frame_far_from_base(robot: &RobotModel, poses: &[Measured]) -> Option<CalibrateError> {
    let step = poses.len().div_ceil(FRAME_CHECK_POSES).max(1);
    let (a, b): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = poses
        .iter()
        .step_by(step)
        .map(|m| (predict(robot, &m.q).p, m.p1))
        .unzip();
    // rms distance of the points `a` moved by `f` from `b`
    let rms = |f: &dyn Fn(&Vector3<f64>) -> Vector3<f64>| {
        let sum: f64 = a
            .iter()
            .zip(&b)
            .map(|(a, b)| (f(a) - b).norm_squared())
            .sum();
        (sum / a.len() as f64).sqrt()
    };
    let raw = rms(&|a| *a);
    if raw.is_nan() || raw <= FRAME_FAR_MM {
        return None;
    }
    let fit = fit_rigid(&a, &b).ok()?;
    let fitted = rms(&|a| fit.transform_point(a));
    (fitted < FRAME_FIT_FRACTION * raw).then(|| CalibrateError::FrameFarFromBase {
        raw_rms_mm: raw,
        translation_mm: fit.p.norm(),
        angle_deg: fit.rotation_angle().to_degrees(),
        fitted_rms_mm: fitted,
    })
}

/// The pose ids of the identification rows at `indices` (into the identification rows).
fn ident_ids(rows: &[Observation], indices: &[usize]) -> Vec<String> {
    if indices.is_empty() {
        return Vec::new();
    }
    let ident: Vec<&Observation> = rows.iter().filter(|o| o.set == PoseSet::Ident).collect();
    indices.iter().map(|&i| ident[i].id.clone()).collect()
}

/// The verdict's bounds of an identification with `opts`: σ judged by the bounds the
/// identification kept its set within.
fn quality_bounds(opts: &IdentifyOptions) -> QualityBounds {
    QualityBounds {
        sigma_mm: opts.practical.max_sigma_mm,
        sigma_rad: opts.practical.max_sigma_rad,
        ..QualityBounds::default()
    }
}

/// Run the identify pipeline on data-set rows. With non-geometric terms
/// (`opts.nongeometric`), the geometric model is identified too, on the same data with the same
/// options otherwise: the report gains the terms and the geometric fit's metrics, and hands
/// over the extended model — or, with [`NongeometricKeep::Better`], the one with the lower
/// verification position RMS.
pub fn calibrate(
    robot: &RobotModel,
    rows: &[Observation],
    opts: &IdentifyOptions,
    stage_travel_mm: f64,
) -> Result<(IdentifyReport, Identification), CalibrateError> {
    if !rows.iter().any(|o| o.set == PoseSet::Ident) {
        return Err(CalibrateError::NoIdentRows);
    }
    let (ident, verify) = split_measured(rows, opts.obs.model, stage_travel_mm)?;
    // one joint table for both fits, the analysis, every linearisation and the ident metrics
    let trig = if opts.nongeometric.compliance {
        JointTrig::of(&ident).with_torques(&ident, robot)
    } else {
        JointTrig::of(&ident)
    };
    let data = Sets {
        rows,
        ident: &ident,
        verify: &verify,
        trig: &trig,
    };
    if opts.nongeometric.is_empty() {
        return calibrate_one(robot, &data, opts);
    }
    let (extended, ext_id) = calibrate_one(robot, &data, opts)?;
    let geometric_opts = IdentifyOptions {
        nongeometric: Nongeometric::default(),
        ..*opts
    };
    let (geometric, geo_id) = calibrate_one(robot, &data, &geometric_opts)?;
    let terms = term_rows(&ext_id);
    let verify_rms =
        |r: &IdentifyReport| r.metrics.verify.as_ref().map(|v| v.after.position_rms_mm);
    let keep_geometric = opts.nongeometric.keep == NongeometricKeep::Better
        && matches!(
            (verify_rms(&geometric), verify_rms(&extended)),
            (Some(g), Some(e)) if g <= e
        );
    let metrics_geometric = geometric.metrics.clone();
    let (mut report, id, metrics_extended) = if keep_geometric {
        let m = extended.metrics.clone();
        (geometric, geo_id, Some(m))
    } else {
        (extended, ext_id, None)
    };
    report.nongeometric = opts.nongeometric.families();
    report.nongeometric_terms = terms;
    report.metrics_geometric = Some(metrics_geometric);
    report.nongeometric_kept = Some(if keep_geometric {
        KeptModel::Geometric
    } else {
        KeptModel::Extended
    });
    report.metrics_extended = metrics_extended;
    report.set_torque_model(robot);
    report.judge(&quality_bounds(opts));
    Ok((report, id))
}

/// `nongeometric_terms` of identification `id`: every candidate term, in candidate order.
fn term_rows(id: &Identification) -> Vec<TermJson> {
    id.estimates
        .iter()
        .filter(|e| e.param.is_term())
        .map(|e| TermJson {
            name: e.param.name(),
            joint: e.param.joint_number().unwrap_or(0),
            kind: e.param.kind_name().to_owned(),
            value: e.nominal + e.error,
            sigma: e.std,
            unit: e.param.unit().to_owned(),
            status: status_of(id, e),
            reason: id
                .identifiability
                .dropped
                .iter()
                .find(|d| d.param == e.param)
                .map(|d| d.reason.clone()),
        })
        .collect()
}

/// What the identification made of one estimate.
fn status_of(id: &Identification, e: &crate::identify::Estimate) -> ParamStatus {
    if !e.identified {
        ParamStatus::NotIdentified
    } else if id.setup_relative.iter().any(|d| d.param == e.param) {
        ParamStatus::SetupRelative
    } else {
        ParamStatus::Identified
    }
}

/// The data of one calibration, read once for every fit: the rows, their two sets as measured
/// poses and the ident set's joint table.
struct Sets<'a> {
    rows: &'a [Observation],
    ident: &'a [Measured],
    verify: &'a [Measured],
    trig: &'a JointTrig,
}

/// Run the identify pipeline on the calibration's data for one parameter set (the geometric
/// one, or it with the terms of `opts.nongeometric`).
fn calibrate_one(
    robot: &RobotModel,
    data: &Sets,
    opts: &IdentifyOptions,
) -> Result<(IdentifyReport, Identification), CalibrateError> {
    let Sets {
        rows,
        ident,
        verify,
        trig,
    } = *data;
    let model = opts.obs.model;
    if !opts.identify_base {
        if let Some(e) = frame_far_from_base(robot, ident) {
            return Err(e);
        }
    }
    let id = identify_with(robot, ident, trig, opts)?;
    let bounds = quality_bounds(opts);
    let axis = stage_axis_check(&id.initial, ident, &opts.obs);
    if let Some(c) = axis.filter(|c| {
        c.angle_rad > bounds.stage_axis_error_rad || c.scatter_rad > bounds.stage_axis_error_rad
    }) {
        return Err(CalibrateError::StageAxisContradiction {
            used: opts.obs.stage_axis.into(),
            measured: c.measured.into(),
            angle_deg: c.angle_rad.to_degrees(),
            scatter_deg: c.scatter_rad.to_degrees(),
            limit_deg: bounds.stage_axis_error_rad.to_degrees(),
        });
    }
    let m = |set: &[_], trig| {
        let (before, after) = evaluate_pair(&id.before, &id.corrected, set, trig, &opts.obs);
        BeforeAfter { before, after }
    };
    let metrics = MetricsJson {
        ident: m(ident, Some(trig)),
        verify: (!verify.is_empty()).then(|| m(verify, None)),
    };
    let names: Vec<String> = id
        .identifiability
        .identified
        .iter()
        .map(|p| p.name())
        .collect();
    let k = names.len();
    let mut report = IdentifyReport {
        model: model.name().to_owned(),
        identified: names.clone(),
        not_identifiable: id
            .identifiability
            .dropped
            .iter()
            .map(NotIdentifiable::of)
            .collect(),
        parameters: id
            .estimates
            .iter()
            .filter(|e| !e.param.is_term())
            .map(|e| ParameterJson {
                name: e.param.name(),
                joint: e.param.joint_number(),
                kind: e.param.kind_name().to_owned(),
                unit: e.param.unit().to_owned(),
                nominal: e.nominal,
                error: e.error,
                std: e.std,
                identified: e.identified,
                status: status_of(&id, e),
            })
            .collect(),
        base: BaseJson {
            translation_mm: id.corrected.base_translation.into(),
            rotation_vector_rad: log_so3(&id.corrected.base_rotation).into(),
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
        rejected_poses: ident_ids(rows, &id.rejected),
        correlation: CorrelationJson {
            names,
            matrix: (0..k)
                .map(|i| (0..k).map(|j| id.correlation[(i, j)]).collect())
                .collect(),
        },
        stage_axis_measured: axis.map(|c| c.measured.into()),
        stage_axis_angle_rad: axis.map(|c| c.angle_rad),
        quality: Quality::Ok,
        warnings: Vec::new(),
        before_base: Some(id.before_base),
        setup_relative: id.setup_relative.iter().map(NotIdentifiable::of).collect(),
        ident_stop: None,
        nongeometric: Vec::new(),
        nongeometric_terms: Vec::new(),
        metrics_geometric: None,
        nongeometric_kept: None,
        metrics_extended: None,
        gravity: None,
        masses: Vec::new(),
    };
    report.judge(&bounds);
    Ok((report, id))
}

/// [`calibrate`] and the typed result of it, as a campaign stores it: the contract, the
/// per-pose residuals of both sets and the corrected model with `base` as its base's source.
pub fn calibrate_result(
    robot: &RobotModel,
    rows: &[Observation],
    opts: &IdentifyOptions,
    stage_travel_mm: f64,
    base: BaseSource,
) -> Result<(CalibrationResult, Identification), CalibrateError> {
    let (report, id) = calibrate(robot, rows, opts, stage_travel_mm)?;
    let result =
        CalibrationResult::of(report, &id, base).with_residuals(&id, rows, stage_travel_mm)?;
    Ok((result, id))
}

#[cfg(test)]
mod terms_tests;
