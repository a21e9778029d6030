//! The synchronised trapezoidal joint move ([`MotionLimits`]): a joint move goes along the
//! straight line in joint space (as the path check assumes), every joint starting and finishing
//! together. Along that line the fraction covered follows one trapezoidal profile whose speed
//! and acceleration are the largest every joint allows: joint `j`, which covers `d_j` rad,
//! allows `v_j / d_j` and `a_j / d_j` (1/s, 1/s²). The move time is then that of a trapezoid
//! (or a triangle, when full speed is never reached) over 1.

use crate::model::RobotModel;

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
        if ramp.is_nan() || ramp <= 0.0 {
            // instant acceleration: constant speed
            return (t_s / total).clamp(0.0, 1.0);
        }
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

    /// These limits for a world whose durations are all × `scale`: speeds ÷ `scale`,
    /// accelerations ÷ `scale`² (every move takes `scale` × its time).
    pub fn time_scaled(self, scale: f64) -> MotionLimits {
        if scale == 1.0 {
            return self;
        }
        MotionLimits {
            speed_rad_s: self.speed_rad_s.iter().map(|v| v / scale).collect(),
            accel_rad_s2: self
                .accel_rad_s2
                .iter()
                .map(|a| a / (scale * scale))
                .collect(),
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
