//! [`SimpleBackend`]: a joint-space-only simulated arm (no kinematics).
//!
//! Motion is a linear interpolation in joint space; its duration is the largest joint
//! distance divided by `max_joint_speed_deg_s * vel_pct / 100`. The arm reports settled
//! `settle_time` after the motion ends. `pose()` uses a pluggable function (default: a
//! placeholder that echoes the joints; the integrator supplies real kinematics).

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::codec::{ErrorCode, Identity, Pose};
use crate::server::{BackendError, RobotBackend};

/// Pose function: joints (degrees) → pose.
pub type PoseFn = Arc<dyn Fn([f64; 6]) -> Pose + Send + Sync>;

/// Configuration of [`SimpleBackend`].
#[derive(Clone)]
pub struct SimpleConfig {
    /// Joint limits `(min, max)` in degrees.
    pub limits_deg: [(f64, f64); 6],
    /// Joint speed at 100 % velocity, degrees per second.
    pub max_joint_speed_deg_s: f64,
    /// Time from end of motion to settled.
    pub settle_time: Duration,
    /// Initial joints in degrees.
    pub initial_deg: [f64; 6],
    /// Initial power state.
    pub power_on: bool,
    /// Forward "kinematics" used by `pose()`; `None` = placeholder (x,y,z,rx,ry,rz = j1..j6).
    pub pose_fn: Option<PoseFn>,
}

impl std::fmt::Debug for SimpleConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimpleConfig")
            .field("limits_deg", &self.limits_deg)
            .field("max_joint_speed_deg_s", &self.max_joint_speed_deg_s)
            .field("settle_time", &self.settle_time)
            .field("initial_deg", &self.initial_deg)
            .field("power_on", &self.power_on)
            .finish_non_exhaustive()
    }
}

impl Default for SimpleConfig {
    fn default() -> Self {
        Self {
            limits_deg: [
                (-180.0, 180.0),
                (-130.0, 147.5),
                (-145.0, 145.0),
                (-270.0, 270.0),
                (-115.0, 140.0),
                (-270.0, 270.0),
            ],
            max_joint_speed_deg_s: 180.0,
            settle_time: Duration::from_millis(20),
            initial_deg: [0.0; 6],
            power_on: false,
            pose_fn: None,
        }
    }
}

#[derive(Debug)]
struct Motion {
    from: [f64; 6],
    to: [f64; 6],
    start: Instant,
    duration: Duration,
}

#[derive(Debug)]
struct SimState {
    rest: [f64; 6],
    motion: Option<Motion>,
    settled_at: Instant,
    power: bool,
    estop: bool,
}

/// Simple simulated arm usable as a [`RobotBackend`].
pub struct SimpleBackend {
    cfg: SimpleConfig,
    st: Mutex<SimState>,
}

impl std::fmt::Debug for SimpleBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimpleBackend")
            .field("cfg", &self.cfg)
            .finish_non_exhaustive()
    }
}

fn interp(m: &Motion, now: Instant) -> ([f64; 6], bool) {
    let t = if m.duration.is_zero() {
        1.0
    } else {
        (now.saturating_duration_since(m.start).as_secs_f64() / m.duration.as_secs_f64()).min(1.0)
    };
    let mut q = [0.0; 6];
    for (i, v) in q.iter_mut().enumerate() {
        *v = m.from[i] + (m.to[i] - m.from[i]) * t;
    }
    (q, t >= 1.0)
}

impl SimpleBackend {
    /// New simulated arm.
    pub fn new(cfg: SimpleConfig) -> Self {
        let st = SimState {
            rest: cfg.initial_deg,
            motion: None,
            settled_at: Instant::now(),
            power: cfg.power_on,
            estop: false,
        };
        Self {
            cfg,
            st: Mutex::new(st),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, SimState> {
        self.st.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Advance the internal state to `now` (finishes a completed motion).
    fn update(&self, st: &mut SimState) {
        let now = Instant::now();
        if let Some(m) = &st.motion {
            let (q, done) = interp(m, now);
            if done {
                st.rest = q;
                st.settled_at = m.start + m.duration + self.cfg.settle_time;
                st.motion = None;
            }
        }
    }

    fn halt(&self, st: &mut SimState) {
        if let Some(m) = st.motion.take() {
            let (q, _) = interp(&m, Instant::now());
            st.rest = q;
            st.settled_at = Instant::now() + self.cfg.settle_time;
        }
    }

    /// Set or clear the hardware emergency stop (E-stop also removes arm power and halts motion).
    pub fn set_estop(&self, active: bool) {
        let mut st = self.lock();
        st.estop = active;
        if active {
            self.halt(&mut st);
            st.power = false;
        }
    }

    /// Drop arm power without a request (simulates a power loss).
    pub fn drop_power(&self) {
        let mut st = self.lock();
        self.halt(&mut st);
        st.power = false;
    }

    /// Motion target, if a motion is executing.
    pub fn target_deg(&self) -> Option<[f64; 6]> {
        let mut st = self.lock();
        self.update(&mut st);
        st.motion.as_ref().map(|m| m.to)
    }
}

impl RobotBackend for SimpleBackend {
    fn identity(&self) -> Identity {
        Identity {
            ctrl: "SIM".into(),
            arm: "SIMPLE6".into(),
            sw: env!("CARGO_PKG_VERSION").into(),
        }
    }

    fn check_target(&self, joints_deg: &[f64; 6]) -> Result<(), BackendError> {
        for (i, (q, (lo, hi))) in joints_deg.iter().zip(self.cfg.limits_deg).enumerate() {
            if !q.is_finite() || *q < lo || *q > hi {
                return Err(BackendError::new(
                    ErrorCode::Limit,
                    format!("joint {} = {q} outside [{lo}, {hi}]", i + 1),
                ));
            }
        }
        Ok(())
    }

    fn start_move(&self, joints_deg: [f64; 6], vel_pct: f64) -> Result<(), BackendError> {
        self.check_target(&joints_deg)?;
        let mut st = self.lock();
        self.update(&mut st);
        if st.estop {
            return Err(BackendError::new(ErrorCode::EStop, "emergency stop active"));
        }
        if !st.power {
            return Err(BackendError::new(ErrorCode::Power, "arm power is off"));
        }
        if st.motion.is_some() {
            return Err(BackendError::new(ErrorCode::Busy, "motion in progress"));
        }
        let speed = self.cfg.max_joint_speed_deg_s * (vel_pct / 100.0).clamp(0.001, 1.0);
        let dist = st
            .rest
            .iter()
            .zip(joints_deg)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let duration = Duration::from_secs_f64((dist / speed).min(3600.0));
        st.motion = Some(Motion {
            from: st.rest,
            to: joints_deg,
            start: Instant::now(),
            duration,
        });
        Ok(())
    }

    fn joints_deg(&self) -> [f64; 6] {
        let mut st = self.lock();
        self.update(&mut st);
        match &st.motion {
            Some(m) => interp(m, Instant::now()).0,
            None => st.rest,
        }
    }

    fn pose(&self) -> Result<Pose, BackendError> {
        let q = self.joints_deg();
        Ok(match &self.cfg.pose_fn {
            Some(f) => f(q),
            None => Pose {
                xyz_mm: [q[0], q[1], q[2]],
                rxyz_deg: [q[3], q[4], q[5]],
            },
        })
    }

    fn is_moving(&self) -> bool {
        let mut st = self.lock();
        self.update(&mut st);
        st.motion.is_some()
    }

    fn is_settled(&self) -> bool {
        let mut st = self.lock();
        self.update(&mut st);
        st.motion.is_none() && Instant::now() >= st.settled_at
    }

    fn stop(&self) {
        let mut st = self.lock();
        self.halt(&mut st);
    }

    fn set_power(&self, on: bool) -> Result<(), BackendError> {
        let mut st = self.lock();
        if on && st.estop {
            return Err(BackendError::new(ErrorCode::EStop, "emergency stop active"));
        }
        if !on {
            self.halt(&mut st);
        }
        st.power = on;
        Ok(())
    }

    fn power(&self) -> bool {
        self.lock().power
    }

    fn estop(&self) -> bool {
        self.lock().estop
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_and_settles() {
        let b = SimpleBackend::new(SimpleConfig {
            max_joint_speed_deg_s: 1000.0,
            settle_time: Duration::from_millis(5),
            power_on: true,
            ..Default::default()
        });
        assert!(b.check_target(&[0.0, 200.0, 0.0, 0.0, 0.0, 0.0]).is_err());
        b.start_move([10.0, 0.0, 0.0, 0.0, 0.0, 0.0], 100.0)
            .unwrap();
        assert!(b.is_moving());
        std::thread::sleep(Duration::from_millis(30));
        assert!(!b.is_moving());
        assert!(b.is_settled());
        assert_eq!(b.joints_deg()[0], 10.0);
    }

    #[test]
    fn estop_halts() {
        let b = SimpleBackend::new(SimpleConfig {
            max_joint_speed_deg_s: 10.0,
            power_on: true,
            ..Default::default()
        });
        b.start_move([10.0, 0.0, 0.0, 0.0, 0.0, 0.0], 100.0)
            .unwrap();
        b.set_estop(true);
        assert!(!b.is_moving());
        assert!(!b.power());
        assert!(b.set_power(true).is_err());
    }
}
