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
        if total.is_nan() || total <= 0.0 || t_s >= total {
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
            if d.is_nan() || d <= 0.0 {
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
