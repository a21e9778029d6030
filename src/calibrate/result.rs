//! The typed calibration result: what an identification leaves for every view of it.
//!
//! [`CalibrationResult`] is the `cellcal identify` JSON contract ([`IdentifyReport`]: the
//! estimates with σ, the parameters held back with their reasons, base and tool, solver,
//! metrics, verdict and warnings) plus the per-pose residuals of both sets ([`PoseErrors`]) and
//! the corrected model ([`CorrectedModel`]: absolute values keyed by [`ParamId`], base, tool).
//! A campaign stores it once (`campaign::engine::identify_stored`); the REST result and model
//! routes, `run`, `report`, `export` and the HTML report render the stored one and never
//! identify again.
//!
//! Stored as one JSON object: the contract's fields, then `result_layout` ([`RESULT_LAYOUT`]),
//! `residuals`, `corrected` and, for a campaign's result, `campaign_time` ([`CampaignTime`]).
//! A result stored before this layout (layout 0: the contract alone) reads with `residuals`
//! missing (the report says so) and its corrected model derived once, on reading, from the
//! contract's parameter names and values ([`CorrectedModel::from_report`]).
//!
//! Room to grow: a new model term (joint compliance, per-joint harmonics) is a new [`ParamId`]
//! variant whose estimates and values flow through the same lists; a robot kind other than a
//! serial MDH chain adds a variant where [`CorrectedModel::model`] applies the values.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::campaign_time::CampaignTime;
use super::identify_json::{IdentifyReport, KeptModel};
use crate::analysis::metrics::pose_errors;
use crate::dataset::{split, to_measured, ConvertError, Observation};
use crate::identify::params::ParamId;
use crate::identify::{
    initial_model, BeforeBase, Identification, IdentifyOptions, Measured, ObsConfig,
};
use crate::model::rotation::from_rotation_vector;
use crate::model::{ParamKind, RobotModel, TermKind};

/// The stored layout this code writes: 1 = contract + residuals + corrected model (0: a result
/// stored before, the contract alone).
pub const RESULT_LAYOUT: u32 = 1;

/// One identification, typed: the contract, the per-pose residuals and the corrected model.
#[derive(Debug, Clone)]
pub struct CalibrationResult {
    /// The `cellcal identify` JSON contract (what `--json`, `GET …/result` and the journal's
    /// `result` event carry).
    pub report: IdentifyReport,
    /// Per-pose errors before and after of both sets; `None` for a result stored before they
    /// were kept (layout 0), or not asked for (`identify` without `--report`).
    pub residuals: Option<PoseErrors>,
    /// The corrected model's values.
    pub corrected: CorrectedModel,
    /// The layout it was stored in ([`RESULT_LAYOUT`] for a new one).
    pub layout: u32,
    /// Planned against actual duration of the campaign that measured it; `None` outside a
    /// campaign and for a result stored before it was kept.
    pub campaign_time: Option<CampaignTime>,
}

/// The stored form: the contract's fields, flattened, then the rest.
#[derive(Serialize)]
struct StoredForm<'a> {
    #[serde(flatten)]
    report: &'a IdentifyReport,
    result_layout: u32,
    residuals: &'a Option<PoseErrors>,
    corrected: &'a CorrectedModel,
    #[serde(skip_serializing_if = "Option::is_none")]
    campaign_time: &'a Option<CampaignTime>,
}

impl CalibrationResult {
    /// The result of identification `id` (its contract `report`; `base`: where the corrected
    /// model's base comes from), without per-pose errors ([`CalibrationResult::with_residuals`]
    /// adds them). The corrected model holds every MDH value and, when `id` is an extended
    /// identification (§10), every term's absolute value.
    pub fn of(report: IdentifyReport, id: &Identification, base: BaseSource) -> CalibrationResult {
        let corrected = CorrectedModel {
            values: id
                .estimates
                .iter()
                .filter(|e| matches!(e.param, ParamId::Mdh { .. } | ParamId::Term { .. }))
                .map(|e| ParamValue {
                    param: e.param,
                    value: e.nominal + e.error,
                })
                .collect(),
            base_translation_mm: report.base.translation_mm,
            base_rotation_vector_rad: report.base.rotation_vector_rad,
            tool_mm: report.tool.translation_mm,
            base_source: Some(base),
        };
        CalibrationResult {
            report,
            residuals: None,
            corrected,
            layout: RESULT_LAYOUT,
            campaign_time: None,
        }
    }

    /// With the per-pose errors of identification `id` of `rows` ([`PoseErrors::compute`]).
    pub fn with_residuals(
        mut self,
        id: &Identification,
        rows: &[Observation],
        travel_mm: f64,
    ) -> Result<CalibrationResult, ConvertError> {
        self.residuals = Some(PoseErrors::compute(id, rows, travel_mm)?);
        Ok(self)
    }

    /// A stored result, of any layout (see the module doc for layout 0).
    pub fn from_stored_json(text: &str) -> Result<CalibrationResult, serde_json::Error> {
        CalibrationResult::from_stored_value(serde_json::from_str(text)?)
    }

    /// [`CalibrationResult::from_stored_json`] of a parsed document.
    fn from_stored_value(
        mut value: serde_json::Value,
    ) -> Result<CalibrationResult, serde_json::Error> {
        use serde::de::Error;
        let object = value
            .as_object_mut()
            .ok_or_else(|| serde_json::Error::custom("the result is not a JSON object"))?;
        let layout = object.remove("result_layout");
        let residuals = object.remove("residuals");
        let corrected = object.remove("corrected");
        let campaign_time = object.remove("campaign_time");
        let report = IdentifyReport::from_value(value)?;
        let layout = match layout {
            Some(v) => serde_json::from_value(v)?,
            None => 0,
        };
        let residuals = match residuals {
            Some(v) => serde_json::from_value(v)?,
            None => None,
        };
        let corrected = match corrected {
            Some(v) => serde_json::from_value(v)?,
            None => CorrectedModel::from_report(&report),
        };
        let campaign_time = match campaign_time {
            Some(v) => serde_json::from_value(v)?,
            None => None,
        };
        Ok(CalibrationResult {
            report,
            residuals,
            corrected,
            layout,
            campaign_time,
        })
    }

    /// The per-pose errors a result stored without them (layout 0) implies, evaluated from its
    /// corrected model — never by identifying again: `rows` under the "before" model (`nominal`
    /// as the campaign identified with it: with the setup's base, or its base fitted to the
    /// identification poses, as [`BeforeBase::of`] says for `opts`) and under the corrected
    /// model. Equal to the per-pose errors of the identification that stored the result up to
    /// the rounding of `nominal + error`.
    pub fn evaluate_residuals(
        &self,
        nominal: &RobotModel,
        opts: &IdentifyOptions,
        rows: &[Observation],
        travel_mm: f64,
    ) -> Result<PoseErrors, String> {
        let after = self.corrected.model(nominal).map_err(|e| e.to_string())?;
        let before = match BeforeBase::of(opts) {
            BeforeBase::SetupRegistration => nominal.clone(),
            _ => {
                let (ident, _) = split(rows);
                let poses =
                    to_measured(&ident, opts.obs.model, travel_mm).map_err(|e| e.to_string())?;
                initial_model(nominal, &poses, opts).map_err(|e| e.to_string())?
            }
        };
        PoseErrors::of_models(&before, &after, &opts.obs, rows, travel_mm)
            .map_err(|e| e.to_string())
    }

    /// The contract as `cellcal identify --json` writes it (pretty JSON).
    pub fn identify_json(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string_pretty(&self.report)
    }
}

/// The stored form (module doc): written as the contract's fields, then `result_layout`,
/// `residuals` and `corrected`.
impl Serialize for CalibrationResult {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        StoredForm {
            report: &self.report,
            result_layout: RESULT_LAYOUT,
            residuals: &self.residuals,
            corrected: &self.corrected,
            campaign_time: &self.campaign_time,
        }
        .serialize(s)
    }
}

/// Any stored layout (module doc).
impl<'de> Deserialize<'de> for CalibrationResult {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let value = serde_json::Value::deserialize(d)?;
        CalibrationResult::from_stored_value(value).map_err(serde::de::Error::custom)
    }
}

/// One parameter's absolute value in the corrected model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ParamValue {
    /// The parameter (stored by its public name).
    pub param: ParamId,
    /// Its identified absolute value (nominal + error; mm or rad).
    pub value: f64,
}

/// The corrected model: every model parameter's identified absolute value, base and tool. The
/// nominal model gives what an identification does not touch (name, joint limits, masses,
/// gravity).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CorrectedModel {
    /// Absolute values of the model's parameters (every MDH parameter of every joint; with the
    /// extended model handed over, every non-geometric term too, §10).
    pub values: Vec<ParamValue>,
    /// Base translation (mm), robot base → measurement frame.
    pub base_translation_mm: [f64; 3],
    /// Base rotation vector (rad), robot base → measurement frame.
    pub base_rotation_vector_rad: [f64; 3],
    /// Ball position in the flange frame (mm).
    pub tool_mm: [f64; 3],
    /// Which frame the base maps into; `None` in a result stored before it was kept.
    pub base_source: Option<BaseSource>,
}

impl CorrectedModel {
    /// The corrected model of a contract alone (a result stored before the typed result): each
    /// MDH row's `nominal + error` under the parameter its name names, and each term's value
    /// when the extended model was handed over; rows whose name names none are left out (and
    /// [`CorrectedModel::model`] then says which is missing).
    pub fn from_report(report: &IdentifyReport) -> CorrectedModel {
        let extended = report.nongeometric_kept == Some(KeptModel::Extended);
        let terms = report
            .nongeometric_terms
            .iter()
            .filter(|_| extended)
            .filter_map(|t| {
                let param = ParamId::from_name(&t.name)?;
                matches!(param, ParamId::Term { .. }).then_some(ParamValue {
                    param,
                    value: t.value,
                })
            });
        CorrectedModel {
            values: report
                .parameters
                .iter()
                .filter_map(|p| {
                    let param = ParamId::from_name(&p.name)?;
                    matches!(param, ParamId::Mdh { .. }).then_some(ParamValue {
                        param,
                        value: p.nominal + p.error,
                    })
                })
                .chain(terms)
                .collect(),
            base_translation_mm: report.base.translation_mm,
            base_rotation_vector_rad: report.base.rotation_vector_rad,
            tool_mm: report.tool.translation_mm,
            base_source: None,
        }
    }

    /// `nominal` with these values, base and tool (limits, masses and gravity kept; the name
    /// marked identified). Term values (§10) replace the nominal model's; a model whose terms
    /// are all zero has none (its model file is a geometric one, byte for byte).
    pub fn model(&self, nominal: &RobotModel) -> Result<RobotModel, ModelFileError> {
        let result_dof = self
            .values
            .iter()
            .filter_map(|v| v.param.joint_number())
            .max()
            .unwrap_or(0);
        if result_dof != nominal.dof() {
            return Err(ModelFileError::DofMismatch {
                result: result_dof,
                nominal: nominal.dof(),
            });
        }
        let mut m = nominal.clone();
        for (joint, mdh) in m.joints.iter_mut().enumerate() {
            for kind in ParamKind::ALL {
                let param = ParamId::Mdh { joint, kind };
                let mut given = self.values.iter().filter(|v| v.param == param);
                let (Some(v), None) = (given.next(), given.next()) else {
                    return Err(ModelFileError::Parameter(param.name()));
                };
                if !v.value.is_finite() {
                    return Err(ModelFileError::NotFinite(param.name()));
                }
                *mdh.get_mut(kind) = v.value;
            }
        }
        for v in &self.values {
            if let ParamId::Term { joint, kind } = v.param {
                if !v.value.is_finite() {
                    return Err(ModelFileError::NotFinite(v.param.name()));
                }
                *m.term_mut(joint, kind) = v.value;
            }
        }
        if !m.has_terms() {
            m.terms.clear();
        }
        // compliances were identified on the nominal's torque chain: they keep it (§10)
        let compliance = self.values.iter().any(|v| {
            matches!(
                v.param,
                ParamId::Term {
                    kind: TermKind::Compliance,
                    ..
                }
            )
        });
        if compliance {
            m.torque_chain = Some(nominal.torque_joints().to_vec());
        }
        let finite = |name: &str, v: &[f64; 3]| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(Vector3::from(*v))
            } else {
                Err(ModelFileError::NotFinite(name.to_owned()))
            }
        };
        m.base_translation = finite("base.translation_mm", &self.base_translation_mm)?;
        m.base_rotation = from_rotation_vector(&finite(
            "base.rotation_vector_rad",
            &self.base_rotation_vector_rad,
        )?);
        m.tool = finite("tool.translation_mm", &self.tool_mm)?;
        if !m.name.ends_with("(identified)") {
            m.name = format!("{} (identified)", m.name);
        }
        Ok(m)
    }
}

/// The corrected model of `result`: `nominal` with the result's absolute values, base and
/// tool (limits and name kept).
pub fn corrected_model(
    result: &CalibrationResult,
    nominal: &RobotModel,
) -> Result<RobotModel, ModelFileError> {
    result.corrected.model(nominal)
}

/// Why a result cannot be turned into a robot model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelFileError {
    /// The result's joints and the nominal model's differ in number.
    #[error("the result has parameters of {result} joints, the nominal model has {nominal}")]
    DofMismatch {
        /// Joints in the result.
        result: usize,
        /// Joints of the nominal model.
        nominal: usize,
    },
    /// An MDH parameter is missing from the result, or given twice.
    #[error("the result does not give `{0}` exactly once")]
    Parameter(String),
    /// A value of the result is not a finite number.
    #[error("the result's `{0}` is not a finite number")]
    NotFinite(String),
}

/// Which frame the corrected model's base maps the robot into.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BaseSource {
    /// The base was identified with the MDH errors (from data in the tracker frame).
    Identified,
    /// The base was registered by the cell (or given by the data's setup header) and held.
    Registered,
    /// The nominal model's own base (neither identified nor registered).
    Nominal,
}

impl BaseSource {
    /// Identified when the identification identified it, else registered when a registered
    /// base was held, else the nominal model's.
    pub fn of(identified: bool, registered: bool) -> BaseSource {
        match (identified, registered) {
            (true, _) => BaseSource::Identified,
            (false, true) => BaseSource::Registered,
            (false, false) => BaseSource::Nominal,
        }
    }
}

/// The position error `P1 − p_model` (mm) and attitude error (rad; `None` where not measured)
/// of one pose under one model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseError {
    /// Position error x, y, z (mm, measurement frame).
    pub position_mm: [f64; 3],
    /// Attitude error (rad): stage-axis angle (NP/OP) or rotation angle (full).
    pub attitude_rad: Option<f64>,
}

impl PoseError {
    /// The comprehensive position error ‖e‖ (mm).
    pub fn norm_mm(&self) -> f64 {
        Vector3::from(self.position_mm).norm()
    }
}

/// One set's per-pose errors under the nominal (before) and identified (after) model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetErrors {
    /// Pose ids, in data order.
    pub ids: Vec<String>,
    /// Errors of the nominal model with the "before" base (`Identification::before`).
    pub before: Vec<PoseError>,
    /// Errors of the identified model.
    pub after: Vec<PoseError>,
}

/// Per-pose errors of the identification and the verification set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseErrors {
    /// Identification set.
    pub ident: SetErrors,
    /// Verification set (`None` when the data has none).
    pub verify: Option<SetErrors>,
}

impl PoseErrors {
    /// The per-pose errors behind the metrics of an identification of `rows` (the same
    /// initial and identified model, observation settings and stage travel).
    pub fn compute(
        id: &Identification,
        rows: &[Observation],
        travel_mm: f64,
    ) -> Result<PoseErrors, ConvertError> {
        PoseErrors::of_models(&id.before, &id.corrected, &id.options.obs, rows, travel_mm)
    }

    /// The per-pose errors of `rows` under `before` and `after` (observations as `obs` and the
    /// stage travel say).
    pub fn of_models(
        before: &RobotModel,
        after: &RobotModel,
        obs: &ObsConfig,
        rows: &[Observation],
        travel_mm: f64,
    ) -> Result<PoseErrors, ConvertError> {
        let (ident, verify) = split(rows);
        let set = |rows: &[Observation]| -> Result<SetErrors, ConvertError> {
            let m = to_measured(rows, obs.model, travel_mm)?;
            Ok(SetErrors {
                ids: rows.iter().map(|r| r.id.clone()).collect(),
                before: errors_of(before, &m, obs),
                after: errors_of(after, &m, obs),
            })
        };
        Ok(PoseErrors {
            ident: set(&ident)?,
            verify: if verify.is_empty() {
                None
            } else {
                Some(set(&verify)?)
            },
        })
    }
}

fn errors_of(model: &RobotModel, poses: &[Measured], obs: &ObsConfig) -> Vec<PoseError> {
    pose_errors(model, poses, obs)
        .into_iter()
        .map(|(e, a)| PoseError {
            position_mm: e.into(),
            attitude_rad: a,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::calibrate_result;
    use crate::identify::{IdentifyOptions, ObsConfig, ObsModel};
    use crate::model::tx60;
    use crate::simulate::{simulate, truth, SimConfig};

    fn small_op() -> (CalibrationResult, RobotModel) {
        let nominal = tx60();
        let truth = truth::apply_errors(&nominal, &truth::paper_errors()).expect("paper errors");
        let cfg = SimConfig {
            poses: 60,
            ident: 40,
            ..SimConfig::default()
        };
        let rows = simulate(&nominal, &truth, &cfg)
            .expect("sampled")
            .observations;
        let opts = IdentifyOptions::new(ObsConfig::new(ObsModel::Op, 10.0));
        let (r, _) = calibrate_result(&nominal, &rows, &opts, 10.0, BaseSource::Nominal)
            .expect("identified");
        (r, nominal)
    }

    #[test]
    fn the_stored_form_reads_back_exactly_and_leads_with_the_contract() {
        let (r, nominal) = small_op();
        let text = serde_json::to_string_pretty(&r).expect("stored form");
        let contract = r.identify_json().expect("contract");
        // the contract's fields first, in the contract's order: the stored text starts with them
        let head = contract.trim_end_matches("\n}");
        assert!(
            text.starts_with(head),
            "the stored form leads with the contract"
        );
        let back = CalibrationResult::from_stored_json(&text).expect("reads");
        assert_eq!(back.layout, RESULT_LAYOUT);
        assert_eq!(back.identify_json().expect("contract"), contract);
        assert_eq!(back.residuals, r.residuals);
        assert_eq!(back.corrected, r.corrected);
        assert_eq!(
            corrected_model(&back, &nominal).expect("model"),
            corrected_model(&r, &nominal).expect("model")
        );
        // every MDH parameter of every joint, keyed by its id, nothing else
        assert_eq!(
            r.corrected.values.len(),
            nominal.dof() * ParamKind::ALL.len()
        );
        assert_eq!(r.corrected.base_source, Some(BaseSource::Nominal));
        assert_eq!(back.campaign_time, None, "outside a campaign: none");
        assert!(!text.contains("campaign_time"));
    }

    #[test]
    fn a_campaign_s_planned_against_actual_time_reads_back_after_the_contract() {
        let (mut r, _) = small_op();
        r.campaign_time = Some(CampaignTime {
            planned: Some(serde_json::json!({"poses": 20, "total_s": 600.0})),
            planned_summary: Some("20 poses, 40 readings, about 10 min".into()),
            planned_s: Some(600.0),
            measuring_s: 630.0,
            paused_s: 12.5,
            ratio: Some(1.05),
        });
        let text = serde_json::to_string_pretty(&r).expect("stored form");
        let contract = r.identify_json().expect("contract");
        assert!(text.starts_with(contract.trim_end_matches("\n}")));
        let back = CalibrationResult::from_stored_json(&text).expect("reads");
        assert_eq!(back.campaign_time, r.campaign_time);
        assert_eq!(back.identify_json().expect("contract"), contract);
    }

    #[test]
    fn a_contract_alone_reads_as_layout_0_with_the_same_corrected_model() {
        let (r, nominal) = small_op();
        let old = CalibrationResult::from_stored_json(&r.identify_json().expect("contract"))
            .expect("reads");
        assert_eq!(old.layout, 0);
        assert_eq!(old.residuals, None);
        assert_eq!(old.corrected.base_source, None);
        assert_eq!(old.corrected.values, r.corrected.values);
        assert_eq!(
            corrected_model(&old, &nominal).expect("model"),
            corrected_model(&r, &nominal).expect("model")
        );
        // a parameter row missing from an old contract is named when the model is built
        let mut gap = r.report.clone();
        gap.parameters.retain(|p| p.name != "alpha4");
        let e = CorrectedModel::from_report(&gap)
            .model(&nominal)
            .unwrap_err();
        assert_eq!(e, ModelFileError::Parameter("alpha4".into()));
    }
}
