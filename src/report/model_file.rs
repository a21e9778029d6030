//! The corrected model: an identification result as a robot file (`--model-out`, `GET
//! /api/campaigns/{id}/model`) that every command takes as `--robot`.
//!
//! Built from the typed result's corrected model ([`CalibrationResult::corrected`]) and the
//! nominal model it started from, so a stored campaign result gives the same file as the run
//! that produced it: MDH values are `nominal + error` (absolute), base and tool are the
//! result's, joint limits and the name are the nominal model's. The header comments say where it comes from (deterministic provenance
//! given by the caller: file hashes, campaign id; no clock), which parameters were held at
//! nominal and which frame the base maps into. A result with non-geometric terms (§10) adds them
//! per joint (`compliance_rad_per_nm`, `harmonics_rad`) and a header line naming them; the
//! masses and gravity are the nominal model's, those the identification used.

use crate::calibrate::result::{corrected_model, BaseSource, CalibrationResult, ModelFileError};
use crate::calibrate::IdentifyReport;
use crate::model::file::write_robot;
use crate::model::{JointTerms, RobotModel};

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
    h.push(describe(base).to_owned());
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

/// The header line naming the terms a model carries (none: no line, so a geometric model's
/// file is as before).
fn terms_line(m: &RobotModel) -> Option<String> {
    if !m.has_terms() {
        return None;
    }
    let joints = |f: &dyn Fn(&JointTerms) -> bool| -> String {
        let j: Vec<String> = (m.terms.iter().enumerate())
            .filter(|(_, t)| f(t))
            .map(|(i, _)| (i + 1).to_string())
            .collect();
        if j.is_empty() {
            "none".to_owned()
        } else {
            j.join(", ")
        }
    };
    Some(format!(
        "Non-geometric terms (docs/method.md §10): compliance_rad_per_nm on joints {}, \
         harmonics_rad on joints {}; gravity torques from the {} [[masses]] and the gravity \
         direction the identification used{}.",
        joints(&|t| t.compliance != 0.0),
        joints(&|t| t.harmonics.iter().any(|h| *h != 0.0)),
        m.masses.len(),
        if m.torque_chain.is_some() {
            ", on the chain it started from ([[torque_chain]])"
        } else {
            ""
        }
    ))
}

/// The corrected model of `result` as robot-file TOML with its header (see the module doc).
pub fn corrected_model_toml(
    result: &CalibrationResult,
    nominal: &RobotModel,
    provenance: &[String],
    base: BaseSource,
) -> Result<String, ModelFileError> {
    let m = corrected_model(result, nominal)?;
    let mut h = header(&result.report, provenance, base);
    if let Some(line) = terms_line(&m) {
        let at = h.len() - 1;
        h.insert(at, line);
    }
    Ok(write_robot(&m, &h))
}

/// The header line that says what the base is and which frame poses of this model are in.
fn describe(base: BaseSource) -> &'static str {
    match base {
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

/// SHA-256 of `text` as 64 lowercase hexadecimal digits (file provenance in headers).
pub fn sha256_hex(text: &[u8]) -> String {
    use sha2::Digest;
    format!("{:x}", sha2::Sha256::digest(text))
}
