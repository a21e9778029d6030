//! The corrected model: an identification result as a robot file (`--model-out`, `GET
//! /api/campaigns/{id}/model`) that every command takes as `--robot`.
//!
//! Built from the result JSON ([`IdentifyReport`]) and the nominal model it started from, so a
//! stored campaign result gives the same file as the run that produced it: MDH values are
//! `nominal + error` (absolute), base and tool are the result's, joint limits and the name are
//! the nominal model's. The header comments say where it comes from (deterministic provenance
//! given by the caller: file hashes, campaign id; no clock), which parameters were held at
//! nominal and which frame the base maps into.

use nalgebra::Vector3;

use super::identify_json::IdentifyReport;
use crate::model::file::write_robot;
use crate::model::rotation::from_rotation_vector;
use crate::model::{ParamKind, RobotModel};

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
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
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

    /// The header line that says what the base is and which frame poses of this model are in.
    fn describe(self) -> &'static str {
        match self {
            BaseSource::Identified => {
                "Base: identified from the measurements, so this model's frame is the measurement \
                 (laser tracker) frame: its poses are tracker coordinates, not robot-base coordinates."
            }
            BaseSource::Registered => {
                "Base: the registered base (the cell's base registration, held during the \
                 identification), so this model's frame is the measurement (laser tracker) frame: \
                 its poses are tracker coordinates, not robot-base coordinates."
            }
            BaseSource::Nominal => {
                "Base: the nominal model's (neither identified nor registered): this model's frame \
                 is the nominal model's base frame."
            }
        }
    }
}

/// The corrected model of `report`: `nominal` with the result's absolute MDH values, base
/// and tool (limits and name kept).
pub fn corrected_model(
    report: &IdentifyReport,
    nominal: &RobotModel,
) -> Result<RobotModel, ModelFileError> {
    let result_dof = report
        .parameters
        .iter()
        .filter_map(|p| p.joint)
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
            let name = format!("{}{}", kind.stem(), joint + 1);
            let mut rows = report
                .parameters
                .iter()
                .filter(|p| p.joint == Some(joint + 1) && p.kind == kind.stem());
            let (Some(p), None) = (rows.next(), rows.next()) else {
                return Err(ModelFileError::Parameter(name));
            };
            let value = p.nominal + p.error;
            if !value.is_finite() {
                return Err(ModelFileError::NotFinite(name));
            }
            *mdh.get_mut(kind) = value;
        }
    }
    let finite = |name: &str, v: &[f64; 3]| {
        if v.iter().all(|x| x.is_finite()) {
            Ok(Vector3::from(*v))
        } else {
            Err(ModelFileError::NotFinite(name.to_owned()))
        }
    };
    m.base_translation = finite("base.translation_mm", &report.base.translation_mm)?;
    m.base_rotation = from_rotation_vector(&finite(
        "base.rotation_vector_rad",
        &report.base.rotation_vector_rad,
    )?);
    m.tool = finite("tool.translation_mm", &report.tool.translation_mm)?;
    if !m.name.ends_with("(identified)") {
        m.name = format!("{} (identified)", m.name);
    }
    Ok(m)
}

/// The header comment lines of a corrected model file: what it is, `provenance` (the
/// caller's deterministic source lines), the fit, what was held at nominal, base and tool.
fn header(report: &IdentifyReport, provenance: &[String], base: BaseSource) -> Vec<String> {
    let mut h = vec![
        format!(
            "Corrected robot model: the identified (absolute) MDH parameters, written by cellcal {}.",
            env!("CARGO_PKG_VERSION")
        ),
        "Load it as `--robot FILE` with any command; `cellcal compensate --identified FILE`."
            .to_owned(),
    ];
    h.extend(provenance.iter().cloned());
    let m = &report.metrics;
    let verify = m.verify.as_ref().map_or(String::new(), |v| {
        format!(
            ", verification {:.4} -> {:.4} mm",
            v.before.position_mean_mm, v.after.position_mean_mm
        )
    });
    h.push(format!(
        "Observation model {}; {} parameters identified; quality {}; mean position error: \
         identification {:.4} -> {:.4} mm{verify}.",
        report.model,
        report.identified.len(),
        report.quality.as_str(),
        m.ident.before.position_mean_mm,
        m.ident.after.position_mean_mm,
    ));
    let held: Vec<String> = report
        .parameters
        .iter()
        .filter(|p| !p.identified)
        .map(|p| {
            let kind = report
                .not_identifiable
                .iter()
                .find(|d| d.name == p.name)
                .map_or("not a candidate", |d| d.kind.as_str());
            format!("{} ({kind})", p.name)
        })
        .collect();
    h.push(if held.is_empty() {
        "Held at nominal: none.".to_owned()
    } else {
        format!("Held at nominal (not identified): {}.", held.join(", "))
    });
    h.push(base.describe().to_owned());
    let tool_identified = report
        .parameters
        .iter()
        .any(|p| p.kind == "tool_translation" && p.identified);
    h.push(
        if tool_identified {
            "Tool: the ball position in the flange frame, identified."
        } else {
            "Tool: the ball position in the flange frame the identification used (held)."
        }
        .to_owned(),
    );
    h.push(
        "Angles in rad (degrees in the comments), lengths in mm; joint limits kept from the \
         nominal model."
            .to_owned(),
    );
    h
}

/// The corrected model of `report` as robot-file TOML with its header (see the module doc).
pub fn corrected_model_toml(
    report: &IdentifyReport,
    nominal: &RobotModel,
    provenance: &[String],
    base: BaseSource,
) -> Result<String, ModelFileError> {
    let m = corrected_model(report, nominal)?;
    Ok(write_robot(&m, &header(report, provenance, base)))
}

/// SHA-256 of `text` as 64 lowercase hexadecimal digits (file provenance in headers).
pub fn sha256_hex(text: &[u8]) -> String {
    use sha2::Digest;
    format!("{:x}", sha2::Sha256::digest(text))
}
