//! How long a campaign takes: the planned duration of a campaign by part
//! ([`CampaignEstimate`], walked by [`estimate_campaign`] the way the engine measures), its
//! moves timed by [`MotionLimits`] (`plan::motion`).

use serde::{Deserialize, Serialize};

use super::campaign::Plan;
pub use super::motion::{MotionLimits, MoveProfile, FALLBACK_RAMP_S, FALLBACK_SPEED_DEG_S};
use super::route::Router;
use crate::dataset::PoseSet;
use crate::units::human::{fmt_estimate, UNDER_TEN_S};

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
    /// on, else to 10 s; `…, under 10 s` below 5 s).
    pub fn summary(&self) -> String {
        let total = fmt_estimate(self.total_s);
        let about = if total == UNDER_TEN_S { "" } else { "about " };
        format!(
            "{} poses, {} readings, {about}{total}",
            self.poses, self.readings
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

/// The stage positions one pose is measured at, given where the stage is: where it stands
/// first (P2 then P1 after a pose that ended at P2, else P1 then P2), as the engine measures;
/// P1 only without the axis.
pub fn pose_stage_targets(at: Option<f64>, p1_mm: f64, p2_mm: f64, axis: bool) -> Vec<f64> {
    match (axis, at) {
        (false, _) => vec![p1_mm],
        (true, Some(mm)) if mm == p2_mm => vec![p2_mm, p1_mm],
        (true, _) => vec![p1_mm, p2_mm],
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
/// pre-pose it comes in through, the stage moves made there and the tracker readings taken.
#[derive(Debug, Clone, PartialEq)]
pub struct Visit {
    /// Joints (rad).
    pub q_rad: Vec<f64>,
    /// Pre-pose (the last via point), if any.
    pub approach: Option<Vec<f64>>,
    /// Stage positions the engine asks for there, in order (mm).
    pub stage_mm: Vec<f64>,
    /// Tracker readings taken there.
    pub readings: usize,
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

/// Which planned poses are measured at P2 too (a flange axis besides the position), by set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisReadings {
    /// Identification poses.
    pub ident: bool,
    /// Verification poses.
    pub verify: bool,
}

impl AxisReadings {
    /// P2 at every pose (`true`) or at none.
    pub fn all(axis: bool) -> AxisReadings {
        AxisReadings {
            ident: axis,
            verify: axis,
        }
    }

    /// Whether a pose of `set` is measured at P2.
    pub fn at(self, set: PoseSet) -> bool {
        match set {
            PoseSet::Ident => self.ident,
            PoseSet::Verify => self.verify,
        }
    }
}

/// The campaign a fresh [`Plan`] measures, visit by visit as the engine does (setup visits
/// given): the frame reference at the drift reference, every pose (P1, and P2 where `axis`
/// says, from where the stage stands), a drift check after every `drift_every` poses (not
/// after the last) and at the end.
pub fn campaign_walk(
    plan: &Plan,
    drift_every: usize,
    setup: Vec<Visit>,
    start_q: Option<Vec<f64>>,
    stage: (f64, f64, f64),
    axis: AxisReadings,
) -> CampaignWalk {
    let (p1, travel, tolerance) = stage;
    let drift = || Visit {
        q_rad: plan.drift_reference.clone(),
        approach: None,
        stage_mm: vec![p1],
        readings: 1,
    };
    let mut measured = vec![drift()];
    let mut stage_at = Some(p1);
    let total = plan.poses.len();
    let mut readings = 0;
    for (done, p) in plan.poses.iter().enumerate().map(|(i, p)| (i + 1, p)) {
        let stage_mm = pose_stage_targets(stage_at, p1, p1 + travel, axis.at(p.set));
        stage_at = stage_mm.last().copied();
        readings += stage_mm.len();
        measured.push(Visit {
            q_rad: p.q_rad.clone(),
            approach: plan.approach.get(&p.index).cloned(),
            readings: stage_mm.len(),
            stage_mm,
        });
        if drift_every > 0 && done % drift_every == 0 && done < total {
            measured.push(drift());
            stage_at = Some(p1);
        }
    }
    measured.push(drift());
    CampaignWalk {
        start_q,
        setup,
        measured,
        poses: total,
        readings,
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
            parts.measure_s += times.reading_s * v.readings as f64;
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
        let p = c.profile(&[0.0], &[3.0]);
        assert!(close(p.fraction_at(0.375), 0.25), "constant speed");
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
        assert_eq!(e(3.0).summary(), "300 poses, 600 readings, under 10 s");
    }
    #[test]
    fn the_stage_is_followed_through_the_sequence_and_a_move_to_where_it_is_is_skipped() {
        let motor = StageTimes::Motorised {
            speed_mm_s: 5.0,
            per_move_s: 0.1,
        };
        // after preparation the first move is made even to where it stands; P1 again skipped
        let seq = [None, Some(0.0), Some(0.0), Some(10.0), Some(0.0)];
        let (s, n) = stage_time_s(&seq, 0.0, 0.02, &motor);
        assert!(close(s, 0.1 + (0.1 + 2.0) * 2.0), "{s}");
        assert_eq!(n, 0);
        let manual = StageTimes::Manual {
            per_reading_s: 20.0,
        };
        let (s, n) = stage_time_s(&seq, 0.0, 0.02, &manual);
        assert_eq!((s, n), (60.0, 3));
        // forgetting the position makes the next move count again
        let (_, n) = stage_time_s(&[None, Some(0.0), None, Some(0.0)], 0.0, 0.02, &manual);
        assert_eq!(n, 2);
    }

    #[test]
    fn the_walk_measures_each_pose_at_p1_and_p2_with_drift_checks_between_and_at_the_end() {
        let q = |v: f64| vec![v; 6];
        let plan = Plan {
            poses: (0..5)
                .map(|i| crate::plan::PlanEntry {
                    index: i,
                    set: crate::dataset::PoseSet::Ident,
                    q_rad: q(0.1 * (i + 1) as f64),
                })
                .collect(),
            drift_reference: q(0.0),
            via_points: 0,
            approach: Default::default(),
            sampling_order_s: 0.0,
            planned_order_s: 0.0,
        };
        let walk = campaign_walk(
            &plan,
            2,
            Vec::new(),
            None,
            (0.0, 10.0, 0.02),
            AxisReadings::all(true),
        );
        // reference, p, p, drift, p, p, drift, p, final drift
        let drift_at: Vec<usize> = walk
            .measured
            .iter()
            .enumerate()
            .filter(|(_, v)| v.q_rad == q(0.0))
            .map(|(i, _)| i)
            .collect();
        assert_eq!(drift_at, vec![0, 3, 6, 8]);
        assert_eq!((walk.poses, walk.readings), (5, 10));
        let times = CellTimes {
            motion: MotionLimits::uniform(6, 1.0),
            settle_s: 1.0,
            reading_s: 0.5,
            stage: StageTimes::Motorised {
                speed_mm_s: 10.0,
                per_move_s: 0.0,
            },
            prepare_s: 3.0,
        };
        let e = estimate_campaign(&walk, &times, None);
        // moves: 0 → 0.1 → 0.2 → 0 → 0.3 → 0.4 → 0 → 0.5 → 0 (rad, every joint)
        let motion = 0.1 + 0.1 + 0.2 + 0.3 + 0.1 + 0.4 + 0.5 + 0.5;
        assert!(close(e.motion_s, motion), "{e:?}");
        assert_eq!(
            e.moves, 9,
            "the engine moves to the reference where it stands too"
        );
        assert!(close(e.settle_s, 9.0));
        assert!(close(e.measure_s, 0.5 * (10 + 4) as f64));
        // one move per pose, where the stage stands first (P1 P2 | P2 P1 | drift at P1 |
        // P1 P2 | P2 P1 | drift | P1 P2), and back to P1 for the final drift check: 1 s each
        assert!(close(e.stage_s, 6.0), "{e:?}");
        assert!(close(e.setup_s, 3.0));
        let sum = e.setup_s + e.motion_s + e.settle_s + e.measure_s + e.stage_s;
        assert!(close(e.total_s, sum));
        // without the axis: P1 only
        let p1 = campaign_walk(
            &plan,
            0,
            Vec::new(),
            None,
            (0.0, 10.0, 0.02),
            AxisReadings::all(false),
        );
        assert_eq!((p1.readings, p1.measured.len()), (5, 7));
    }
}
