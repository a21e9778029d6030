//! How long a campaign takes: the synchronised trapezoidal joint move ([`MotionLimits`]), and
//! the planned duration of a campaign by part ([`CampaignEstimate`], walked by
//! [`estimate_campaign`] the way the engine measures).
//!
//! A joint move goes along the straight line in joint space (as the path check assumes), every
//! joint starting and finishing together. Along that line the fraction covered follows one
//! trapezoidal profile whose speed and acceleration are the largest every joint allows: joint
//! `j`, which covers `d_j` rad, allows `v_j / d_j` and `a_j / d_j` (1/s, 1/s²). The move time
//! is then that of a trapezoid (or a triangle, when full speed is never reached) over 1.

use serde::{Deserialize, Serialize};

use super::campaign::Plan;
use super::route::Router;
use crate::model::RobotModel;
use crate::units::human::fmt_estimate;

/// Joint speed at 100 % when the robot file gives none (deg/s).
pub const FALLBACK_SPEED_DEG_S: f64 = 180.0;
/// How long a joint takes to reach its speed when the robot file gives no acceleration (s):
/// the fallback acceleration is the joint's speed at 100 % divided by this.
pub const FALLBACK_RAMP_S: f64 = 0.5;

/// Per-joint speed and acceleration of a robot at a speed setting (rad/s, rad/s²).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionLimits {
    /// Joint speeds at the speed setting (rad/s).
    pub speed_rad_s: Vec<f64>,
    /// Joint accelerations (rad/s²; infinite: speed is reached at once).
    pub accel_rad_s2: Vec<f64>,
}

/// One move's timing along the straight joint line: the fraction of the line covered follows
/// a trapezoid with this peak rate and acceleration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoveProfile {
    /// Peak rate of the fraction (1/s).
    rate: f64,
    /// Acceleration of the fraction (1/s²; may be infinite).
    accel: f64,
    /// Total time (s).
    duration_s: f64,
}

impl MoveProfile {
    /// The move's duration (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Fraction of the line covered `t_s` after the start (0 before, 1 from the end on).
    pub fn fraction_at(&self, t_s: f64) -> f64 {
        let total = self.duration_s;
        if !(total > 0.0) || t_s >= total {
            return 1.0;
        }
        if t_s <= 0.0 {
            return 0.0;
        }
        let ramp = (self.rate / self.accel).min(total / 2.0);
        let peak = self.accel * ramp;
        let s = if t_s < ramp {
            0.5 * self.accel * t_s * t_s
        } else if t_s <= total - ramp {
            0.5 * self.accel * ramp * ramp + peak * (t_s - ramp)
        } else {
            let left = total - t_s;
            1.0 - 0.5 * self.accel * left * left
        };
        s.clamp(0.0, 1.0)
    }
}

impl MotionLimits {
    /// The robot file's limits at `speed_pct` (percent of full speed): the speeds scale with
    /// it, the accelerations do not (the controller's speed setting caps the velocity, as
    /// VAL3's `mdesc.vel`; acceleration and deceleration stay). A joint without
    /// `max_speed_deg_s` moves at [`FALLBACK_SPEED_DEG_S`]; without `max_accel_deg_s2` it
    /// reaches its full speed in [`FALLBACK_RAMP_S`].
    pub fn of(model: &RobotModel, speed_pct: f64) -> MotionLimits {
        let k = speed_pct / 100.0;
        let (speed, accel) = (0..model.dof())
            .map(|i| {
                let m = model.motion.get(i).copied().unwrap_or_default();
                let full = m
                    .max_speed
                    .unwrap_or_else(|| FALLBACK_SPEED_DEG_S.to_radians());
                let accel = m.max_accel.unwrap_or(full / FALLBACK_RAMP_S);
                (full * k, accel)
            })
            .unzip();
        MotionLimits {
            speed_rad_s: speed,
            accel_rad_s2: accel,
        }
    }

    /// Every one of `dof` joints at `speed_rad_s` with infinite acceleration (a constant-speed
    /// move, as the fast simulated cell moves).
    pub fn uniform(dof: usize, speed_rad_s: f64) -> MotionLimits {
        MotionLimits {
            speed_rad_s: vec![speed_rad_s; dof],
            accel_rad_s2: vec![f64::INFINITY; dof],
        }
    }

    /// These limits with the speeds scaled by `speed_pct` / 100 (accelerations kept).
    pub fn at_speed_pct(&self, speed_pct: f64) -> MotionLimits {
        MotionLimits {
            speed_rad_s: self
                .speed_rad_s
                .iter()
                .map(|v| v * speed_pct / 100.0)
                .collect(),
            accel_rad_s2: self.accel_rad_s2.clone(),
        }
    }

    /// The synchronised trapezoidal profile of the straight joint move `from` → `to` (rad).
    pub fn profile(&self, from: &[f64], to: &[f64]) -> MoveProfile {
        let mut rate = f64::INFINITY;
        let mut accel = f64::INFINITY;
        for (j, (a, b)) in from.iter().zip(to).enumerate() {
            let d = (b - a).abs();
            if !(d > 0.0) {
                continue;
            }
            let v = self.speed_rad_s.get(j).copied().unwrap_or(f64::NAN);
            let acc = self.accel_rad_s2.get(j).copied().unwrap_or(f64::INFINITY);
            rate = rate.min(v / d);
            accel = accel.min(acc / d);
        }
        let duration_s = if rate.is_infinite() {
            0.0
        } else if rate * rate >= accel {
            // triangle: full speed is never reached
            2.0 / accel.sqrt()
        } else {
            1.0 / rate + rate / accel
        };
        MoveProfile {
            rate,
            accel,
            duration_s,
        }
    }

    /// Time of the synchronised trapezoidal joint move `from` → `to` (rad): every joint
    /// finishes together, the time set by the joints whose speed and acceleration limit the
    /// move (s).
    pub fn move_time_s(&self, from: &[f64], to: &[f64]) -> f64 {
        self.profile(from, to).duration_s()
    }
}

/// The planned duration of a campaign by part (s); stored, shown, compared with the actual.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignEstimate {
    /// Planned poses.
    pub poses: usize,
    /// Tracker readings at the planned poses (P1 and P2 of each).
    pub readings: usize,
    /// Setup steps: preparing the devices, the tool frame, the base registration (s).
    pub setup_s: f64,
    /// Robot motion of the poses and drift checks, via points and pre-poses included (s).
    pub motion_s: f64,
    /// Robot settling after every move of the poses and drift checks (s).
    pub settle_s: f64,
    /// Tracker measuring of the poses and drift checks (s).
    pub measure_s: f64,
    /// Stage moves, or the technician's readings of a manual stage, of the poses and drift
    /// checks (s).
    pub stage_s: f64,
    /// The whole campaign (s): the sum of the parts.
    pub total_s: f64,
    /// Stage positions a technician sets and reads over the whole campaign (0 with a
    /// motorised stage).
    #[serde(default)]
    pub technician_readings: usize,
    /// Robot moves (legs, via points and pre-poses included) over the whole campaign.
    #[serde(default)]
    pub moves: usize,
}

impl CampaignEstimate {
    /// One line for people: `300 poses, 600 readings, about 3 h 10 min` (minutes from 10 min
    /// on, else to 10 s).
    pub fn summary(&self) -> String {
        format!(
            "{} poses, {} readings, about {}",
            self.poses,
            self.readings,
            fmt_estimate(self.total_s)
        )
    }
}

/// How the stage gets from one position to the next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StageTimes {
    /// A motorised stage: `per_move_s` (start, settling, the driver's polling) plus the
    /// distance at `speed_mm_s`.
    Motorised {
        /// Speed (mm/s).
        speed_mm_s: f64,
        /// Time added to every move (s).
        per_move_s: f64,
    },
    /// A micrometer set by a technician: `per_reading_s` for every position they set and
    /// read (confirming the cell clear included).
    Manual {
        /// Time per reading (s).
        per_reading_s: f64,
    },
}

/// How long the cell's devices take (s): from the configuration for real devices, from the
/// simulated cell's effective timings for simulated ones.
#[derive(Debug, Clone, PartialEq)]
pub struct CellTimes {
    /// Joint limits at the campaign's speed.
    pub motion: MotionLimits,
    /// Settling after every move (every via point and pre-pose too) (s).
    pub settle_s: f64,
    /// One tracker reading: the measuring time plus its overhead (s).
    pub reading_s: f64,
    /// The stage.
    pub stage: StageTimes,
    /// Preparing the devices before the first move: power, tracker initialisation, stage
    /// homing (s).
    pub prepare_s: f64,
}

/// Where a stage's moves go, in order: `None` for "forget where it is" (after the devices
/// are prepared, the next move is made even to where it stands), `Some(mm)` for a move the
/// engine asks for (skipped when the last one already put it there).
pub type StageSequence = Vec<Option<f64>>;

/// The stage positions one pose is measured at (P1, P2 and back to P1, as the engine
/// measures today; P1 only without the axis), given where the stage is.
pub fn pose_stage_targets(_at: Option<f64>, p1_mm: f64, p2_mm: f64, axis: bool) -> Vec<f64> {
    if axis {
        vec![p1_mm, p2_mm, p1_mm]
    } else {
        vec![p1_mm]
    }
}

/// Time (s) and technician readings of a sequence of stage moves from a stage at `home_mm`
/// (a move within `tolerance_mm` of the last known position is skipped, as the engine skips
/// it).
pub fn stage_time_s(
    sequence: &[Option<f64>],
    home_mm: f64,
    tolerance_mm: f64,
    times: &StageTimes,
) -> (f64, usize) {
    let mut known: Option<f64> = None;
    let mut at = home_mm;
    let (mut secs, mut readings) = (0.0, 0);
    for step in sequence {
        let Some(mm) = *step else {
            known = None;
            continue;
        };
        if known.is_some_and(|k| (k - mm).abs() <= tolerance_mm) {
            continue;
        }
        match *times {
            StageTimes::Motorised {
                speed_mm_s,
                per_move_s,
            } => secs += per_move_s + (mm - at).abs() / speed_mm_s,
            StageTimes::Manual { per_reading_s } => {
                secs += per_reading_s;
                readings += 1;
            }
        }
        at = mm;
        known = Some(mm);
    }
    (secs, readings)
}

/// One place the engine moves the robot to and measures at: its joints, an optional
/// pre-pose it comes in through, and the stage positions it reads at.
#[derive(Debug, Clone, PartialEq)]
pub struct Visit {
    /// Joints (rad).
    pub q_rad: Vec<f64>,
    /// Pre-pose (the last via point), if any.
    pub approach: Option<Vec<f64>>,
    /// Stage positions, each with one tracker reading (mm).
    pub stage_mm: Vec<f64>,
}

/// What a campaign does, in the engine's order, for [`estimate_campaign`].
#[derive(Debug, Clone, PartialEq)]
pub struct CampaignWalk {
    /// Where the robot stands at the start (rad); `None`: at the first measured visit (the
    /// drift reference).
    pub start_q: Option<Vec<f64>>,
    /// The setup's visits (tool frame, base registration), in order.
    pub setup: Vec<Visit>,
    /// The measured part: frame reference, poses, drift checks, in order.
    pub measured: Vec<Visit>,
    /// Planned poses and their tracker readings.
    pub poses: usize,
    /// Tracker readings at the planned poses.
    pub readings: usize,
    /// Stage position after the devices are prepared (mm).
    pub stage_home_mm: f64,
    /// Stage positions closer than this count as reached (mm).
    pub stage_tolerance_mm: f64,
}

/// The campaign a fresh [`Plan`] measures, visit by visit as the engine does (setup visits
/// given): the frame reference at the drift reference, every pose (P1, P2, P1), a drift check
/// after every `drift_every` poses (not after the last) and at the end.
pub fn campaign_walk(
    plan: &Plan,
    drift_every: usize,
    setup: Vec<Visit>,
    start_q: Option<Vec<f64>>,
    stage: (f64, f64, f64),
    axis: bool,
) -> CampaignWalk {
    let (p1, travel, tolerance) = stage;
    let drift = || Visit {
        q_rad: plan.drift_reference.clone(),
        approach: None,
        stage_mm: vec![p1],
    };
    let mut measured = vec![drift()];
    let mut stage_at = Some(p1);
    let total = plan.poses.len();
    for (done, p) in plan.poses.iter().enumerate().map(|(i, p)| (i + 1, p)) {
        let stage_mm = pose_stage_targets(stage_at, p1, p1 + travel, axis);
        stage_at = stage_mm.last().copied();
        measured.push(Visit {
            q_rad: p.q_rad.clone(),
            approach: plan.approach.get(&p.index).cloned(),
            stage_mm,
        });
        if drift_every > 0 && done % drift_every == 0 && done < total {
            measured.push(drift());
        }
    }
    measured.push(drift());
    CampaignWalk {
        start_q,
        setup,
        measured,
        poses: total,
        readings: total * if axis { 2 } else { 1 },
        stage_home_mm: 0.0,
        stage_tolerance_mm: tolerance,
    }
}

/// Robot motion, settling, readings and stage of a run of visits.
#[derive(Debug, Default)]
struct Parts {
    motion_s: f64,
    settle_s: f64,
    measure_s: f64,
    moves: usize,
}

/// The planned duration of `walk` on a cell with `times`: each leg along the route the engine
/// takes (`router`: the campaign's, through the drift reference; a leg it cannot route is
/// timed as the direct move), a pre-pose's last leg direct, settling after every leg, one
/// reading per stage position, the stage's moves followed through the whole sequence
/// ([`stage_time_s`]).
pub fn estimate_campaign(
    walk: &CampaignWalk,
    times: &CellTimes,
    mut router: Option<&mut Router>,
) -> CampaignEstimate {
    let drift_reference = walk.measured.first().map(|v| v.q_rad.clone());
    let mut at = walk.start_q.clone().or(drift_reference).unwrap_or_default();
    let mut legs = |visits: &[Visit], parts: &mut Parts, at: &mut Vec<f64>| {
        for v in visits {
            let mut points = Vec::new();
            let first = v.approach.as_deref().unwrap_or(&v.q_rad);
            if let Some(r) = router.as_deref_mut() {
                points.extend(r.route(at, first).unwrap_or_default());
            }
            if let Some(pre) = &v.approach {
                if pre.as_slice() != at.as_slice() {
                    points.push(pre.clone());
                }
            }
            points.push(v.q_rad.clone());
            for p in points {
                parts.motion_s += times.motion.move_time_s(at, &p);
                parts.settle_s += times.settle_s;
                parts.moves += 1;
                *at = p;
            }
            parts.measure_s += times.reading_s * v.stage_mm.len() as f64;
        }
    };
    let (mut setup, mut measured) = (Parts::default(), Parts::default());
    legs(&walk.setup, &mut setup, &mut at);
    legs(&walk.measured, &mut measured, &mut at);
    let stage = |visits: &[Visit], reset: bool| -> StageSequence {
        let mut seq: StageSequence = if reset { vec![None] } else { Vec::new() };
        seq.extend(
            visits
                .iter()
                .flat_map(|v| v.stage_mm.iter().map(|m| Some(*m))),
        );
        seq
    };
    let home = walk.stage_home_mm;
    let tol = walk.stage_tolerance_mm;
    let setup_seq = stage(&walk.setup, true);
    let (setup_stage_s, _) = stage_time_s(&setup_seq, home, tol, &times.stage);
    let mut all = setup_seq;
    all.extend(stage(&walk.measured, false));
    let (all_stage_s, all_readings) = stage_time_s(&all, home, tol, &times.stage);
    let setup_s =
        times.prepare_s + setup.motion_s + setup.settle_s + setup.measure_s + setup_stage_s;
    let stage_s = all_stage_s - setup_stage_s;
    let total_s = setup_s + measured.motion_s + measured.settle_s + measured.measure_s + stage_s;
    CampaignEstimate {
        poses: walk.poses,
        readings: walk.readings,
        setup_s,
        motion_s: measured.motion_s,
        settle_s: measured.settle_s,
        measure_s: measured.measure_s,
        stage_s,
        total_s,
        technician_readings: all_readings,
        moves: setup.moves + measured.moves,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(speed: &[f64], accel: &[f64]) -> MotionLimits {
        MotionLimits {
            speed_rad_s: speed.to_vec(),
            accel_rad_s2: accel.to_vec(),
        }
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12 * b.abs().max(1.0)
    }

    #[test]
    fn a_long_move_is_a_trapezoid_and_a_short_one_a_triangle() {
        let l = limits(&[1.0], &[2.0]);
        // trapezoid: d = 3 rad, v = 1, a = 2: ramps of 0.5 s cover 0.25 rad each,
        // 2.5 rad at full speed: 0.5 + 2.5 + 0.5 s
        assert!(close(l.move_time_s(&[0.0], &[3.0]), 3.5));
        assert!(
            close(l.move_time_s(&[3.0], &[0.0]), 3.5),
            "direction does not matter"
        );
        // exactly reaching full speed: d = v²/a = 0.5 rad, 2·v/a = 1 s
        assert!(close(l.move_time_s(&[0.0], &[0.5]), 1.0));
        // triangle: d = 0.125 rad, 2·√(d/a) = 0.5 s (peak 0.5 rad/s, below the limit)
        assert!(close(l.move_time_s(&[0.0], &[0.125]), 0.5));
        // no move, no time
        assert_eq!(l.move_time_s(&[1.0], &[1.0]), 0.0);
        // infinite acceleration: distance over speed
        let c = MotionLimits::uniform(1, 2.0);
        assert!(close(c.move_time_s(&[0.0], &[3.0]), 1.5));
    }

    #[test]
    fn every_joint_finishes_with_the_one_that_limits_the_move() {
        // joint 1: 1 rad at 1 rad/s, 10 rad/s²; joint 2: 2 rad at 4 rad/s, 1 rad/s²
        let l = limits(&[1.0, 4.0], &[10.0, 1.0]);
        let alone = |j: usize, d: f64| {
            let mut from = vec![0.0, 0.0];
            let mut to = from.clone();
            to[j] = d;
            from[1 - j] = 0.0;
            l.move_time_s(&from, &to)
        };
        // joint 2 alone: triangle 2·√(2/1) = 2.828 s; joint 1 alone: 1 + 0.1 = 1.1 s
        assert!(close(alone(1, 2.0), 2.0 * 2f64.sqrt()));
        assert!(close(alone(0, 1.0), 1.1));
        let both = l.move_time_s(&[0.0, 0.0], &[1.0, 2.0]);
        // along the line: rate ≤ min(1/1, 4/2) = 1, accel ≤ min(10/1, 1/2) = 0.5: a triangle
        // (1² ≥ 0.5) of 2/√0.5 = 2.828 s, the slowest joint's time
        assert!(close(both, 2.0 * 2f64.sqrt()), "{both}");
        // a joint limited by speed and another by acceleration: the line takes longer than
        // either alone (rate ≤ 1/4, accel ≤ 1/1: 4 + 0.25/1 = 4.25 s)
        let l2 = limits(&[1.0, 100.0], &[100.0, 1.0]);
        let sync = l2.move_time_s(&[0.0, 0.0], &[4.0, 1.0]);
        assert!(close(sync, 4.0 + 0.25), "{sync}");
        // the profile covers the line from 0 to 1, monotonically, ending at the duration
        let p = l2.profile(&[0.0, 0.0], &[4.0, 1.0]);
        let mut last = 0.0;
        for k in 0..=100 {
            let s = p.fraction_at(p.duration_s() * f64::from(k) / 100.0);
            assert!(s >= last - 1e-15, "monotone");
            last = s;
        }
        assert_eq!(p.fraction_at(p.duration_s()), 1.0);
        assert_eq!(p.fraction_at(0.0), 0.0);
        assert!(close(p.fraction_at(p.duration_s() / 2.0), 0.5), "symmetric");
    }

    #[test]
    fn the_robot_file_limits_scale_their_speed_with_speed_pct_and_fall_back_when_absent() {
        let tx60 = crate::model::tx60();
        let l = MotionLimits::of(&tx60, 20.0);
        assert!(close(l.speed_rad_s[0], 435f64.to_radians() * 0.2));
        assert!(close(l.accel_rad_s2[0], 870f64.to_radians()), "not scaled");
        let mut bare = tx60.clone();
        bare.motion.clear();
        let f = MotionLimits::of(&bare, 50.0);
        assert!(close(f.speed_rad_s[5], 90f64.to_radians()));
        assert!(close(f.accel_rad_s2[5], 360f64.to_radians()));
    }

    #[test]
    fn the_summary_gives_minutes_from_ten_minutes_on_else_tens_of_seconds() {
        let e = |total_s: f64| CampaignEstimate {
            poses: 300,
            readings: 600,
            setup_s: 0.0,
            motion_s: 0.0,
            settle_s: 0.0,
            measure_s: 0.0,
            stage_s: 0.0,
            total_s,
            technician_readings: 0,
            moves: 0,
        };
        assert_eq!(
            e(3.0 * 3600.0 + 10.0 * 60.0 + 20.0).summary(),
            "300 poses, 600 readings, about 3 h 10 min"
        );
        assert_eq!(
            e(42.0 * 60.0 + 31.0).summary(),
            "300 poses, 600 readings, about 43 min"
        );
        assert_eq!(
            e(254.0).summary(),
            "300 poses, 600 readings, about 4 min 10 s"
        );
        assert_eq!(e(56.0).summary(), "300 poses, 600 readings, about 1 min");
        assert_eq!(e(44.0).summary(), "300 poses, 600 readings, about 40 s");
    }
}
