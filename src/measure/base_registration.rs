//! Base registration for the cell setup: the rigid transform tracker ← robot base from a few
//! poses (nominal ball positions vs measured ones, [`fit_rigid`]), a one-pose estimate from the
//! tool frame, and the choice of well-spread registration poses.
//!
//! The registration is only as good as the nominal model: with MDH errors of the size of
//! docs/method.md §7 (paper Table 3) the residuals are of the order of the nominal model's position error
//! (~0.5–1 mm), and the transform absorbs part of it. That is expected; the identification
//! refines the base afterwards.

use nalgebra::Vector3;

use super::rigid::{fit_rigid, RigidFitError};
use super::tool_frame::ToolFrame;
use crate::model::kinematics::{forward, Pose};
use crate::model::RobotModel;

/// A fitted base transform with its residuals.
#[derive(Debug, Clone, PartialEq)]
pub struct BaseRegistration {
    /// The robot base in the tracker frame (tracker ← robot base).
    pub base: Pose,
    /// Per-point residual `measured − R·nominal − t` (mm, tracker frame), in input order.
    pub residuals_mm: Vec<Vector3<f64>>,
    /// RMS of the residual norms (mm).
    pub rms_mm: f64,
    /// Largest residual norm (mm).
    pub max_mm: f64,
}

impl BaseRegistration {
    /// The transform as a pose (tracker ← base).
    pub fn pose(&self) -> Pose {
        self.base
    }

    /// The model with this base transform.
    pub fn apply_to(&self, model: &RobotModel) -> RobotModel {
        let mut m = model.clone();
        m.set_base(self.base);
        m
    }
}

/// Why a base registration failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BaseRegistrationError {
    /// A joint vector has the wrong length.
    #[error("base registration: pose {index} has {got} joint values, the model has {expected}")]
    DofMismatch {
        /// Index of the pair.
        index: usize,
        /// Joints of the model.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// A joint value or a point is not finite.
    #[error("base registration: pose {0} is not finite")]
    NotFinite(usize),
    /// Too few or collinear points.
    #[error("base registration: {0}")]
    Rigid(RigidFitError),
}

from_cause!(RigidFitError => BaseRegistrationError::Rigid);

/// Nominal ball position (robot base frame: flange · tool, base not applied).
fn nominal_ball(model: &RobotModel, q: &[f64]) -> Vector3<f64> {
    forward(model, q).flange().transform_point(&model.tool)
}

/// Fit tracker ← base from `(q, measured ball in the tracker frame)` pairs on `model` (its
/// tool is used, its base ignored); needs ≥ 3 non-collinear ball positions.
pub fn register_base(
    model: &RobotModel,
    pairs: &[(Vec<f64>, Vector3<f64>)],
) -> Result<BaseRegistration, BaseRegistrationError> {
    for (index, (q, p)) in pairs.iter().enumerate() {
        if q.len() != model.dof() {
            return Err(BaseRegistrationError::DofMismatch {
                index,
                expected: model.dof(),
                got: q.len(),
            });
        }
        if q.iter().chain(p.iter()).any(|v| !v.is_finite()) {
            return Err(BaseRegistrationError::NotFinite(index));
        }
    }
    let a: Vec<Vector3<f64>> = pairs.iter().map(|(q, _)| nominal_ball(model, q)).collect();
    let b: Vec<Vector3<f64>> = pairs.iter().map(|(_, p)| *p).collect();
    let base = fit_rigid(&a, &b)?;
    let residuals_mm: Vec<Vector3<f64>> = a
        .iter()
        .zip(&b)
        .map(|(x, y)| y - base.transform_point(x))
        .collect();
    let n = residuals_mm.len() as f64;
    let rms_mm = (residuals_mm.iter().map(|r| r.norm_squared()).sum::<f64>() / n).sqrt();
    let max_mm = residuals_mm.iter().fold(0.0, |m: f64, r| m.max(r.norm()));
    Ok(BaseRegistration {
        base,
        residuals_mm,
        rms_mm,
        max_mm,
    })
}

/// One-pose base estimate from the tool frame measured at home `q0`:
/// `T_base = T_flange(tracker) · T_flange(base)⁻¹`.
pub fn base_from_tool_frame(model: &RobotModel, q0: &[f64], frame: &ToolFrame) -> Pose {
    frame
        .flange_pose()
        .compose(&forward(model, q0).flange().inverse())
}

/// Choose up to `n` well-spread poses from `candidates` (farthest-point selection on the
/// nominal ball positions, starting with the one farthest from their centroid); returns
/// indices in selection order. Candidates with the wrong number of joints are never chosen.
pub fn select_spread(model: &RobotModel, candidates: &[Vec<f64>], n: usize) -> Vec<usize> {
    let pts: Vec<(usize, Vector3<f64>)> = candidates
        .iter()
        .enumerate()
        .filter(|(_, q)| q.len() == model.dof())
        .map(|(i, q)| (i, nominal_ball(model, q)))
        .collect();
    if pts.is_empty() || n == 0 {
        return Vec::new();
    }
    let centroid = pts.iter().map(|(_, p)| p).sum::<Vector3<f64>>() / pts.len() as f64;
    let mut first = 0;
    for (k, (_, p)) in pts.iter().enumerate() {
        if (p - centroid).norm() > (pts[first].1 - centroid).norm() {
            first = k;
        }
    }
    let mut chosen = vec![first];
    let mut dist: Vec<f64> = pts.iter().map(|(_, p)| (p - pts[first].1).norm()).collect();
    while chosen.len() < n.min(pts.len()) {
        let mut best = None;
        for (k, d) in dist.iter().enumerate() {
            if chosen.contains(&k) {
                continue;
            }
            if best.is_none_or(|b: usize| *d > dist[b]) {
                best = Some(k);
            }
        }
        let Some(b) = best else { break };
        chosen.push(b);
        for (k, (_, p)) in pts.iter().enumerate() {
            dist[k] = dist[k].min((p - pts[b].1).norm());
        }
    }
    chosen.into_iter().map(|k| pts[k].0).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::kinematics::measured_point;
    use crate::model::rotation::from_rotation_vector;

    fn cell() -> RobotModel {
        let mut m = crate::model::tx60();
        m.base_rotation = from_rotation_vector(&Vector3::new(0.05, -0.03, 2.9));
        m.base_translation = Vector3::new(2400.0, 300.0, -500.0);
        m.tool = Vector3::new(8.0, -25.0, 45.0);
        m
    }

    fn poses() -> Vec<Vec<f64>> {
        (0..12)
            .map(|i| {
                let t = i as f64;
                vec![
                    0.6 * (0.7 * t).sin(),
                    0.3 + 0.3 * (1.1 * t).cos(),
                    1.5 + 0.3 * (0.9 * t).sin(),
                    0.5 * (1.3 * t).cos(),
                    -0.7 + 0.3 * (0.5 * t).sin(),
                    0.4 * t.sin(),
                ]
            })
            .collect()
    }

    #[test]
    fn exact_points_give_the_exact_base() {
        let m = cell();
        let pairs: Vec<_> = poses()
            .into_iter()
            .map(|q| {
                let p = measured_point(&m, &q);
                (q, p)
            })
            .collect();
        let reg = register_base(&m, &pairs).expect("registers");
        assert!((reg.base.r - m.base_rotation).norm() < 1e-12);
        assert!((reg.base.p - m.base_translation).norm() < 1e-9);
        assert!(reg.rms_mm < 1e-9 && reg.max_mm < 1e-9);
        assert_eq!(reg.residuals_mm.len(), 12);
        let applied = reg.apply_to(&m);
        assert!((measured_point(&applied, &pairs[3].0) - pairs[3].1).norm() < 1e-9);
    }

    #[test]
    fn errors_are_typed() {
        let m = cell();
        let q = poses();
        let p = measured_point(&m, &q[0]);
        assert!(matches!(
            register_base(&m, &[(q[0].clone(), p), (q[1].clone(), p)]),
            Err(BaseRegistrationError::Rigid(RigidFitError::TooFewPoints(2)))
        ));
        assert_eq!(
            register_base(&m, &[(vec![0.0; 5], p)]),
            Err(BaseRegistrationError::DofMismatch {
                index: 0,
                expected: 6,
                got: 5
            })
        );
        assert_eq!(
            register_base(&m, &[(q[0].clone(), Vector3::new(f64::NAN, 0.0, 0.0))]),
            Err(BaseRegistrationError::NotFinite(0))
        );
        let same: Vec<_> = (0..4).map(|_| (q[0].clone(), p)).collect();
        assert!(matches!(
            register_base(&m, &same),
            Err(BaseRegistrationError::Rigid(RigidFitError::Degenerate))
        ));
    }

    #[test]
    fn spread_selection_is_deterministic_and_spread() {
        let m = cell();
        let qs = poses();
        let sel = select_spread(&m, &qs, 4);
        assert_eq!(sel.len(), 4);
        assert_eq!(sel, select_spread(&m, &qs, 4));
        let mut uniq = sel.clone();
        uniq.sort_unstable();
        uniq.dedup();
        assert_eq!(uniq.len(), 4);
        // the chosen set is at least as spread (minimum pairwise distance) as the first four
        let min_pair = |idx: &[usize]| {
            let pts: Vec<_> = idx.iter().map(|&i| nominal_ball(&m, &qs[i])).collect();
            let mut d = f64::INFINITY;
            for i in 0..pts.len() {
                for j in 0..i {
                    d = d.min((pts[i] - pts[j]).norm());
                }
            }
            d
        };
        assert!(min_pair(&sel) >= min_pair(&[0, 1, 2, 3]));
        assert_eq!(select_spread(&m, &qs, 50).len(), 12);
        assert!(select_spread(&m, &qs, 0).is_empty());
        let mut with_bad = qs.clone();
        with_bad.insert(0, vec![0.0; 3]);
        assert!(!select_spread(&m, &with_bad, 13).contains(&0));
    }
}
