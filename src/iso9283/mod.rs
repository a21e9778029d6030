//! ISO 9283:1998 pose accuracy (AP) and pose repeatability (RP) from measured cycles. Pure.
//!
//! Position (§7.2.1, §7.2.2), for one pose with commanded position `x_c` and `n` attained
//! positions `x_j`:
//! - `AP_P = ‖x̄ − x_c‖`, its components `AP_x, AP_y, AP_z = x̄ − x_c`;
//! - `RP_l = l̄ + 3·S_l`, `l_j = ‖x_j − x̄‖`, `S_l = √(Σ(l_j − l̄)² / (n − 1))`.
//!
//! Orientation: the cell observes one flange axis per visit (the stage axis, P2 − P1), not a
//! whole orientation, so rotation about that axis is not observable and the standard's
//! `AP_a, AP_b, AP_c` cannot be given. What is given is the angular form for that axis:
//! `AP_dir` = angle between the mean attained unit direction (normalised sum of the unit
//! directions `d_j`) and the commanded one; `RP_dir = ±3·√(Σθ_j² / (n − 1))` with `θ_j` the
//! angle of `d_j` from the mean direction (reported as the positive half-width).
//!
//! Units inside: mm and rad; the JSON names say their unit (`ap_p_mm`, `ap_dir_deg`).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::units::human::{fmt_mm, fmt_mrad};

/// The order in which each ISO 9283 cycle visits the five poses (§7.2.1: "P1, P5, P4, P3, P2");
/// the next cycle starts again at P1.
pub const CYCLE_ORDER: [usize; 5] = [1, 5, 4, 3, 2];

/// Why the figures of a pose cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IsoError {
    /// Repeatability needs a spread: at least two cycles.
    #[error("pose P{pose}: {n} attained position(s); ISO 9283 needs at least 2 cycles")]
    TooFewCycles {
        /// Pose number (1–5).
        pose: usize,
        /// Attained positions given.
        n: usize,
    },
    /// A NaN or infinity among the inputs.
    #[error("pose P{pose}: {what} is not finite")]
    NotFinite {
        /// Pose number (1–5).
        pose: usize,
        /// Which input.
        what: String,
    },
    /// Directions were given for some visits only, or one has zero length.
    #[error("pose P{pose}: {reason}")]
    Direction {
        /// Pose number (1–5).
        pose: usize,
        /// What is wrong.
        reason: DirectionProblem,
    },
}

/// What is wrong with the direction input of a pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DirectionProblem {
    /// The number of directions is neither 0 nor the number of positions.
    #[error("{directions} directions for {positions} positions")]
    Count {
        /// Directions given.
        directions: usize,
        /// Positions given.
        positions: usize,
    },
    /// A zero (or near-zero) vector cannot be a direction.
    #[error("a direction has zero length")]
    ZeroLength,
}

/// The measured visits of one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseVisits {
    /// Pose number (1–5).
    pub pose: usize,
    /// Commanded position (mm).
    pub commanded_mm: Vector3<f64>,
    /// Commanded direction of the observed flange axis (any length > 0), if observed.
    pub commanded_dir: Option<Vector3<f64>>,
    /// Attained positions, one per cycle (mm).
    pub attained_mm: Vec<Vector3<f64>>,
    /// Attained directions of the observed axis, one per cycle (any length > 0), or none.
    pub attained_dir: Vec<Vector3<f64>>,
}

/// ISO 9283 figures of one pose (mm, deg at this edge).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseFigures {
    /// Pose number (1–5).
    pub pose: usize,
    /// Cycles (attained positions) used.
    pub n: usize,
    /// Commanded position (mm).
    pub commanded_mm: [f64; 3],
    /// Mean attained position x̄ (mm).
    pub mean_mm: [f64; 3],
    /// Position accuracy ‖x̄ − x_c‖ (mm).
    pub ap_p_mm: f64,
    /// x component of x̄ − x_c (mm).
    pub ap_x_mm: f64,
    /// y component of x̄ − x_c (mm).
    pub ap_y_mm: f64,
    /// z component of x̄ − x_c (mm).
    pub ap_z_mm: f64,
    /// Mean distance l̄ of the attained positions from x̄ (mm).
    pub l_mean_mm: f64,
    /// Standard deviation S_l of those distances (mm).
    pub s_l_mm: f64,
    /// Position repeatability l̄ + 3·S_l (mm).
    pub rp_l_mm: f64,
    /// Angle between the mean attained and the commanded axis direction (deg); `None` when the
    /// axis was not measured.
    pub ap_dir_deg: Option<f64>,
    /// Axis direction repeatability ±3·√(Σθ²/(n−1)) (deg, the half-width); `None` when the axis
    /// was not measured.
    pub rp_dir_deg: Option<f64>,
}

/// Angle between two vectors (rad), accurate for small angles (atan2 of cross and dot).
fn angle_between(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.cross(b).norm().atan2(a.dot(b))
}

/// The unit vector of `v`, or `ZeroLength`.
fn unit(v: &Vector3<f64>) -> Result<Vector3<f64>, DirectionProblem> {
    let n = v.norm();
    if n > 1e-12 {
        Ok(v / n)
    } else {
        Err(DirectionProblem::ZeroLength)
    }
}

/// Whether every component is finite.
fn finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// Refuse NaN/inf among a pose's inputs.
fn check_finite(v: &PoseVisits) -> Result<(), IsoError> {
    let bad = |what: String| IsoError::NotFinite { pose: v.pose, what };
    if !finite(&v.commanded_mm) {
        return Err(bad("the commanded position".into()));
    }
    if v.commanded_dir.as_ref().is_some_and(|d| !finite(d)) {
        return Err(bad("the commanded direction".into()));
    }
    if let Some(j) = v.attained_mm.iter().position(|p| !finite(p)) {
        return Err(bad(format!("attained position {}", j + 1)));
    }
    if let Some(j) = v.attained_dir.iter().position(|d| !finite(d)) {
        return Err(bad(format!("attained direction {}", j + 1)));
    }
    Ok(())
}

/// Mean of the vectors (at least one).
fn mean(v: &[Vector3<f64>]) -> Vector3<f64> {
    v.iter().sum::<Vector3<f64>>() / v.len() as f64
}

/// `(l̄, S_l)` of the distances of `xs` from their mean `m` (n ≥ 2).
fn distance_spread(xs: &[Vector3<f64>], m: &Vector3<f64>) -> (f64, f64) {
    let n = xs.len() as f64;
    let l: Vec<f64> = xs.iter().map(|x| (x - m).norm()).collect();
    let l_mean = l.iter().sum::<f64>() / n;
    let s = (l.iter().map(|v| (v - l_mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (l_mean, s)
}

/// `(AP_dir, RP_dir)` in rad for the observed axis: angle of the mean unit direction from the
/// commanded one, and 3·√(Σθ_j²/(n−1)) of the directions' angles from their mean.
fn direction_figures(
    commanded: &Vector3<f64>,
    dirs: &[Vector3<f64>],
) -> Result<(f64, f64), DirectionProblem> {
    let units = dirs.iter().map(unit).collect::<Result<Vec<_>, _>>()?;
    let m = unit(&units.iter().sum::<Vector3<f64>>())?;
    let c = unit(commanded)?;
    let n = units.len() as f64;
    let sum_sq: f64 = units.iter().map(|d| angle_between(d, &m).powi(2)).sum();
    Ok((angle_between(&m, &c), 3.0 * (sum_sq / (n - 1.0)).sqrt()))
}

/// The ISO 9283 figures of one pose. Needs n ≥ 2 attained positions, all inputs finite, and
/// either no directions or one per position (then a commanded direction too, else the
/// direction figures are `None`).
pub fn pose_figures(v: &PoseVisits) -> Result<PoseFigures, IsoError> {
    let n = v.attained_mm.len();
    if n < 2 {
        return Err(IsoError::TooFewCycles { pose: v.pose, n });
    }
    check_finite(v)?;
    let dir_err = |reason| IsoError::Direction {
        pose: v.pose,
        reason,
    };
    if !v.attained_dir.is_empty() && v.attained_dir.len() != n {
        return Err(dir_err(DirectionProblem::Count {
            directions: v.attained_dir.len(),
            positions: n,
        }));
    }
    let m = mean(&v.attained_mm);
    let ap = m - v.commanded_mm;
    let (l_mean, s_l) = distance_spread(&v.attained_mm, &m);
    let dir = match (&v.commanded_dir, v.attained_dir.is_empty()) {
        (Some(c), false) => Some(direction_figures(c, &v.attained_dir).map_err(dir_err)?),
        _ => None,
    };
    Ok(PoseFigures {
        pose: v.pose,
        n,
        commanded_mm: v.commanded_mm.into(),
        mean_mm: m.into(),
        ap_p_mm: ap.norm(),
        ap_x_mm: ap.x,
        ap_y_mm: ap.y,
        ap_z_mm: ap.z,
        l_mean_mm: l_mean,
        s_l_mm: s_l,
        rp_l_mm: l_mean + 3.0 * s_l,
        ap_dir_deg: dir.map(|d| d.0.to_degrees()),
        rp_dir_deg: dir.map(|d| d.1.to_degrees()),
    })
}

/// The stored result of an ISO 9283 campaign (`"kind": "iso9283"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoReport {
    /// Always `iso9283`.
    pub kind: String,
    /// The frame of every position and component (the robot base frame, and how it was
    /// realised).
    pub frame: String,
    /// What the direction figures observe, and what they cannot.
    pub orientation_note: String,
    /// Cycles planned.
    pub cycles_planned: usize,
    /// Complete cycles (every pose measured) the figures use.
    pub cycles_complete: usize,
    /// Whether the campaign was measured only in part (figures over its complete cycles).
    pub partial: bool,
    /// Whether the joints were compensated by a corrected model.
    pub compensated: bool,
    /// The corrected model file of compensated targets, as configured.
    pub compensated_model: Option<String>,
    /// The figures of P1…P5.
    pub poses: Vec<PoseFigures>,
}

/// What [`IsoReport::orientation_note`] says.
pub const ORIENTATION_NOTE: &str = "one flange axis is observed per visit (the stage axis, \
    P2 - P1): ap_dir/rp_dir are angles of that axis; rotation about it is not observable";

/// A `(visit order position, P1, P2 or None)` per measured visit.
#[derive(Debug, Clone, PartialEq)]
pub struct Visit {
    /// Visit index in plan order (cycle = index / 5, pose = [`CYCLE_ORDER`]`[index % 5]`).
    pub index: usize,
    /// Ball at stage P1 (mm, in the report's frame).
    pub p1_mm: Vector3<f64>,
    /// Ball at stage P2 (mm, same frame), when measured.
    pub p2_mm: Option<Vector3<f64>>,
}

/// Cycle and pose number (1–5) of visit `index`.
pub fn visit_pose(index: usize) -> (usize, usize) {
    (index / 5, CYCLE_ORDER[index % 5])
}

/// How many cycles have all five visits among the measured visit `indices`.
pub fn complete_cycles(indices: impl IntoIterator<Item = usize>) -> usize {
    let mut per_cycle = std::collections::BTreeMap::<usize, usize>::new();
    for i in indices {
        *per_cycle.entry(i / 5).or_default() += 1;
    }
    per_cycle.values().filter(|&&n| n == 5).count()
}

/// The visits of complete cycles only, grouped per pose: `(complete cycles, per-pose visits)`
/// where pose `k` (1–5) is at `[k − 1]` with its commanded position and direction.
pub fn group_complete_cycles(
    visits: &[Visit],
    commanded_mm: &[Vector3<f64>; 5],
    commanded_dir: &[Vector3<f64>; 5],
) -> (usize, Vec<PoseVisits>) {
    let cycles = visits.iter().map(|v| v.index / 5 + 1).max().unwrap_or(0);
    let mut per_cycle = vec![0usize; cycles];
    for v in visits {
        per_cycle[v.index / 5] += 1;
    }
    let complete = |c: usize| per_cycle[c] == 5;
    let mut out: Vec<PoseVisits> = (0..5)
        .map(|k| PoseVisits {
            pose: k + 1,
            commanded_mm: commanded_mm[k],
            commanded_dir: Some(commanded_dir[k]),
            attained_mm: Vec::new(),
            attained_dir: Vec::new(),
        })
        .collect();
    let all_axes = visits.iter().all(|v| v.p2_mm.is_some());
    for v in visits {
        let (cycle, pose) = visit_pose(v.index);
        if !complete(cycle) {
            continue;
        }
        let slot = &mut out[pose - 1];
        slot.attained_mm.push(v.p1_mm);
        if let (Some(p2), true) = (v.p2_mm, all_axes) {
            slot.attained_dir.push(p2 - v.p1_mm);
        }
    }
    if !all_axes {
        out.iter_mut().for_each(|p| p.commanded_dir = None);
    }
    (per_cycle.iter().filter(|&&n| n == 5).count(), out)
}

/// The printed table: one row per pose (mm, deg).
pub fn format_table(r: &IsoReport) -> String {
    let mut s = format!(
        "ISO 9283 pose accuracy / repeatability ({} of {} cycles{}; {}{})\n",
        r.cycles_complete,
        r.cycles_planned,
        if r.partial { ", PARTIAL" } else { "" },
        r.frame,
        if r.compensated { "; compensated" } else { "" },
    );
    s.push_str(
        "pose   n   AP_P mm   AP_x mm   AP_y mm   AP_z mm   RP_l mm AP_dir mrad RP_dir mrad\n",
    );
    // the JSON keeps degrees; people read orientation deviations in mrad
    let mrad = |v: Option<f64>| v.map_or_else(|| "-".to_owned(), |d| fmt_mrad(d.to_radians()));
    for p in &r.poses {
        s.push_str(&format!(
            "P{:<3} {:>3} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} {:>11}\n",
            p.pose,
            p.n,
            fmt_mm(p.ap_p_mm),
            fmt_mm(p.ap_x_mm),
            fmt_mm(p.ap_y_mm),
            fmt_mm(p.ap_z_mm),
            fmt_mm(p.rp_l_mm),
            mrad(p.ap_dir_deg),
            mrad(p.rp_dir_deg)
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
        Vector3::new(x, y, z)
    }

    /// Hand-computed case. Attained (0,0,0), (1,0,0), (5,0,0): x̄ = (6/3, 0, 0) = (2, 0, 0).
    /// Commanded (2, −3, 4): x̄ − x_c = (0, 3, −4), AP_P = √(0 + 9 + 16) = 5.
    /// l_j = |x_j − x̄| = 2, 1, 3: l̄ = 6/3 = 2; S_l = √(((2−2)² + (1−2)² + (3−2)²)/(3−1))
    /// = √(2/2) = 1; RP_l = 2 + 3·1 = 5.
    /// Directions: d_1 = (cos a, sin a, 0), d_2 = (cos a, −sin a, 0), d_3 = (1, 0, 0), a = 0.01:
    /// their sum lies on +x, so the mean direction is (1, 0, 0); θ = a, a, 0:
    /// RP_dir = 3·√((a² + a² + 0)/2) = 3a = 0.03 rad. Commanded (cos b, 0, sin b), b = 0.02:
    /// AP_dir = b = 0.02 rad.
    #[test]
    fn hand_computed_case() {
        let (a, b) = (0.01_f64, 0.02_f64);
        let f = pose_figures(&PoseVisits {
            pose: 3,
            commanded_mm: v(2.0, -3.0, 4.0),
            commanded_dir: Some(v(b.cos(), 0.0, b.sin())),
            attained_mm: vec![v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(5.0, 0.0, 0.0)],
            attained_dir: vec![
                v(a.cos(), a.sin(), 0.0),
                v(a.cos(), -a.sin(), 0.0),
                v(1.0, 0.0, 0.0),
            ],
        })
        .unwrap();
        let close = |x: f64, y: f64| (x - y).abs() < 1e-12;
        assert_eq!((f.pose, f.n), (3, 3));
        assert_eq!(f.mean_mm, [2.0, 0.0, 0.0]);
        assert!(close(f.ap_p_mm, 5.0), "{f:?}");
        assert!(close(f.ap_x_mm, 0.0) && close(f.ap_y_mm, 3.0) && close(f.ap_z_mm, -4.0));
        assert!(close(f.l_mean_mm, 2.0) && close(f.s_l_mm, 1.0) && close(f.rp_l_mm, 5.0));
        assert!(close(f.ap_dir_deg.unwrap(), 0.02f64.to_degrees()), "{f:?}");
        assert!(close(f.rp_dir_deg.unwrap(), 0.03f64.to_degrees()), "{f:?}");
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let ok = PoseVisits {
            pose: 1,
            commanded_mm: v(0.0, 0.0, 0.0),
            commanded_dir: None,
            attained_mm: vec![v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0)],
            attained_dir: vec![],
        };
        assert!(pose_figures(&ok).unwrap().ap_dir_deg.is_none());
        let mut one = ok.clone();
        one.attained_mm.truncate(1);
        assert_eq!(
            pose_figures(&one),
            Err(IsoError::TooFewCycles { pose: 1, n: 1 })
        );
        let mut nan = ok.clone();
        nan.attained_mm[1].y = f64::NAN;
        assert!(matches!(
            pose_figures(&nan),
            Err(IsoError::NotFinite { .. })
        ));
        let mut inf = ok.clone();
        inf.commanded_mm.z = f64::INFINITY;
        assert!(matches!(
            pose_figures(&inf),
            Err(IsoError::NotFinite { .. })
        ));
        let mut count = ok.clone();
        count.commanded_dir = Some(v(1.0, 0.0, 0.0));
        count.attained_dir = vec![v(1.0, 0.0, 0.0)];
        assert!(matches!(
            pose_figures(&count),
            Err(IsoError::Direction { .. })
        ));
        let mut zero = count;
        zero.attained_dir = vec![v(1.0, 0.0, 0.0), v(0.0, 0.0, 0.0)];
        assert!(matches!(
            pose_figures(&zero),
            Err(IsoError::Direction {
                reason: DirectionProblem::ZeroLength,
                ..
            })
        ));
    }

    #[test]
    fn only_complete_cycles_count() {
        let cmd = [v(0.0, 0.0, 0.0); 5];
        let dir = [v(0.0, 1.0, 0.0); 5];
        // cycles 0 and 1 complete, cycle 2 has two visits
        let visits: Vec<Visit> = (0..12)
            .map(|i| Visit {
                index: i,
                p1_mm: v(i as f64, 0.0, 0.0),
                p2_mm: Some(v(i as f64, 10.0, 0.0)),
            })
            .collect();
        let (complete, per) = group_complete_cycles(&visits, &cmd, &dir);
        assert_eq!(complete, 2);
        assert!(per.iter().all(|p| p.attained_mm.len() == 2));
        // visit 1 of each cycle is P5
        assert_eq!(per[4].attained_mm, vec![v(1.0, 0.0, 0.0), v(6.0, 0.0, 0.0)]);
        assert_eq!(visit_pose(7), (1, 4));
    }

    proptest::proptest! {
        /// A rigid translation moves AP by it and leaves RP; RP ≥ l̄ ≥ 0.
        #[test]
        fn translation_moves_ap_not_rp(
            pts in proptest::collection::vec((-5.0..5.0f64, -5.0..5.0f64, -5.0..5.0f64), 2..8),
            t in (-3.0..3.0f64, -3.0..3.0f64, -3.0..3.0f64),
        ) {
            let xs: Vec<_> = pts.iter().map(|p| v(p.0, p.1, p.2)).collect();
            let t = v(t.0, t.1, t.2);
            let base = PoseVisits {
                pose: 1,
                commanded_mm: v(0.0, 0.0, 0.0),
                commanded_dir: None,
                attained_mm: xs.clone(),
                attained_dir: vec![],
            };
            let moved = PoseVisits {
                attained_mm: xs.iter().map(|x| x + t).collect(),
                ..base.clone()
            };
            let (a, b) = (pose_figures(&base).unwrap(), pose_figures(&moved).unwrap());
            proptest::prop_assert!((a.rp_l_mm - b.rp_l_mm).abs() < 1e-9);
            let ap_shift = v(b.ap_x_mm - a.ap_x_mm, b.ap_y_mm - a.ap_y_mm, b.ap_z_mm - a.ap_z_mm);
            proptest::prop_assert!((ap_shift - t).norm() < 1e-9);
            proptest::prop_assert!(a.rp_l_mm >= a.l_mean_mm && a.l_mean_mm >= 0.0);
        }
    }
}
