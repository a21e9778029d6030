//! Turning data-set rows into observations for a given observation model.

use super::csv_format::{Observation, PoseSet};
use crate::identify::observation::{Measured, ObsModel};
use crate::identify::problem::{join_parts, split_map};
use crate::model::rotation::project_so3;

/// A row that cannot serve the chosen model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// P2 − P1 is far from the configured stage travel.
    #[error("line {line} (pose {pose}): ‖P2 − P1‖ = {measured_mm:.3} mm but the stage travel is {travel_mm} mm")]
    BadTravel {
        /// Line number.
        line: usize,
        /// Pose id.
        pose: String,
        /// Measured distance (mm).
        measured_mm: f64,
        /// Configured travel (mm).
        travel_mm: f64,
    },
    /// The rotation columns are not a rotation.
    #[error("line {line} (pose {pose}): n, o, a columns are not orthonormal (‖RᵀR − I‖ = {deviation:.3})")]
    NotRotation {
        /// Line number.
        line: usize,
        /// Pose id.
        pose: String,
        /// Frobenius deviation from orthonormality.
        deviation: f64,
    },
    /// The model needs columns this row lacks.
    #[error("line {line} (pose {pose}): the {model} model needs {what}")]
    Missing {
        /// Line number.
        line: usize,
        /// Pose id.
        pose: String,
        /// Model name.
        model: &'static str,
        /// What is missing.
        what: &'static str,
    },
}

/// Convert rows for `model`; P2 − P1 must be within 50 % of `travel_mm`. NP and OP need P2 of
/// every identification row; a verification row without it verifies the position only.
pub fn to_measured(
    rows: &[Observation],
    model: ObsModel,
    travel_mm: f64,
) -> Result<Vec<Measured>, ConvertError> {
    measured_all(rows.iter(), rows.len(), model, travel_mm)
}

/// The identification and the verification rows (file order kept), each converted as
/// [`to_measured`] does ([`split`] then [`to_measured`], without copying the rows; the first
/// unusable identification row is reported before any verification row); two halves of the
/// rows on two threads ([`split_map`]), the first half's vectors with room for all.
pub fn split_measured(
    rows: &[Observation],
    model: ObsModel,
    travel_mm: f64,
) -> Result<(Vec<Measured>, Vec<Measured>), ConvertError> {
    let halves = split_map(rows.len(), |r| {
        let part = &rows[r.clone()];
        let room = |set: PoseSet| {
            let counted = if r.start == 0 { rows } else { part };
            counted.iter().filter(|o| o.set == set).count()
        };
        let of = |set: PoseSet| {
            let these = part.iter().filter(move |o| o.set == set);
            measured_all(these, room(set), model, travel_mm)
        };
        (of(PoseSet::Ident), of(PoseSet::Verify))
    });
    let (ident, verify): (Vec<_>, Vec<_>) = halves.into_iter().unzip();
    Ok((join_parts(ident)?, join_parts(verify)?))
}

/// The rows `rows` converted for `model`, into a vector with room for `room` (no regrowth when
/// that is their number or more).
fn measured_all<'a>(
    rows: impl Iterator<Item = &'a Observation>,
    room: usize,
    model: ObsModel,
    travel_mm: f64,
) -> Result<Vec<Measured>, ConvertError> {
    let mut out = Vec::with_capacity(room);
    for o in rows {
        out.push(measured(o, model, travel_mm)?);
    }
    Ok(out)
}

/// One row converted for `model` (see [`to_measured`]).
fn measured(o: &Observation, model: ObsModel, travel_mm: f64) -> Result<Measured, ConvertError> {
    let mut m = Measured {
        q: o.q.clone(),
        p1: o.p1,
        direction: None,
        rotation: None,
        weight: 1.0,
    };
    if let Some(p2) = o.p2 {
        let d = p2 - o.p1;
        let n = d.norm();
        if matches!(model, ObsModel::Np | ObsModel::Op) && (n - travel_mm).abs() > 0.5 * travel_mm {
            return Err(ConvertError::BadTravel {
                line: o.line,
                pose: o.id.clone(),
                measured_mm: n,
                travel_mm,
            });
        }
        if n > 0.0 {
            m.direction = Some(d / n);
        }
    }
    // only the full model uses the rotation: spare the others its projection (an SVD)
    if let Some(r) = o.rotation.as_deref().filter(|_| model == ObsModel::Full) {
        let dev = (r.transpose() * r - nalgebra::Matrix3::identity()).norm();
        if dev > 0.1 {
            return Err(ConvertError::NotRotation {
                line: o.line,
                pose: o.id.clone(),
                deviation: dev,
            });
        }
        m.rotation = Some(Box::new(project_so3(r)));
    }
    // a verification row without P2 verifies the position only (`verify_readings = "p1"`)
    let missing = match model {
        ObsModel::Np | ObsModel::Op if m.direction.is_none() && o.set == PoseSet::Ident => {
            Some("p2_x, p2_y, p2_z")
        }
        ObsModel::Full if m.rotation.is_none() => Some("n_x … a_z"),
        _ => None,
    };
    if let Some(what) = missing {
        return Err(ConvertError::Missing {
            line: o.line,
            pose: o.id.clone(),
            model: model.name(),
            what,
        });
    }
    Ok(m)
}

/// Split rows into identification and verification sets (file order kept).
pub fn split(rows: &[Observation]) -> (Vec<Observation>, Vec<Observation>) {
    rows.iter().cloned().partition(|o| o.set == PoseSet::Ident)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn row(i: usize, set: PoseSet, travel_mm: f64) -> Observation {
        let p1 = Vector3::new(i as f64, 2.0, 3.0);
        Observation {
            line: i + 2,
            id: i.to_string(),
            set,
            q: vec![0.1 * i as f64; 6],
            p1,
            p2: Some(p1 + Vector3::new(0.0, travel_mm, 0.0)),
            rotation: None,
        }
    }

    #[test]
    fn split_measured_is_split_then_to_measured() {
        let sets = [
            PoseSet::Verify,
            PoseSet::Ident,
            PoseSet::Ident,
            PoseSet::Verify,
        ];
        // one part, and two halves on two threads
        for n in [12, 600] {
            let mut rows: Vec<Observation> = (0..n).map(|i| row(i, sets[i % 4], 10.0)).collect();
            let (i, v) = split(&rows);
            let want = (
                to_measured(&i, ObsModel::Op, 10.0).unwrap(),
                to_measured(&v, ObsModel::Op, 10.0).unwrap(),
            );
            assert_eq!(split_measured(&rows, ObsModel::Op, 10.0).unwrap(), want);
            // an unusable identification row is reported before an earlier verification row
            let late = n - 6;
            rows[0] = row(0, PoseSet::Verify, 30.0);
            rows[late] = row(late, PoseSet::Ident, 30.0);
            let e = split_measured(&rows, ObsModel::Op, 10.0).unwrap_err();
            let line = late + 2;
            assert!(
                matches!(e, ConvertError::BadTravel { line: l, .. } if l == line),
                "{e:?}"
            );
            // and the first of two in file order
            rows[5] = row(5, PoseSet::Ident, 30.0);
            let e = split_measured(&rows, ObsModel::Op, 10.0).unwrap_err();
            assert!(
                matches!(e, ConvertError::BadTravel { line: 7, .. }),
                "{e:?}"
            );
        }
    }

    #[test]
    fn a_verification_row_without_p2_verifies_the_position_and_an_identification_row_needs_it() {
        let mut verify = row(3, PoseSet::Verify, 10.0);
        verify.p2 = None;
        for model in [ObsModel::Np, ObsModel::Op] {
            let m = to_measured(std::slice::from_ref(&verify), model, 10.0).unwrap();
            assert_eq!((m[0].p1, m[0].direction), (verify.p1, None));
        }
        let ident = Observation {
            set: PoseSet::Ident,
            ..verify.clone()
        };
        let e = to_measured(&[ident], ObsModel::Op, 10.0).unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 5 (pose 3): the op model needs p2_x, p2_y, p2_z"
        );
        // the full model reads the rotation of every row
        let e = to_measured(&[verify], ObsModel::Full, 10.0).unwrap_err();
        assert!(matches!(e, ConvertError::Missing { .. }), "{e:?}");
    }
}
