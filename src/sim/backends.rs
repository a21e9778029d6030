//! The protocol servers' physics seams over the shared [`World`]: [`SimTrackerBackend`]
//! (emScon) and [`SimRobotBackend`] (robotlink).

use emscon::{BackendMeasurement, Meteo, TrackerBackend};
use robotlink::{BackendError, Identity, Pose, RobotBackend};

use super::world::{lock_world, SharedWorld};

/// emScon tracker backend: measures the world's true ball (+ drift + noise); the reflector is
/// not found while the robot or the stage moves.
#[derive(Debug, Clone)]
pub struct SimTrackerBackend {
    world: SharedWorld,
}

impl SimTrackerBackend {
    /// A backend over `world`.
    pub fn new(world: SharedWorld) -> SimTrackerBackend {
        SimTrackerBackend { world }
    }
}

impl TrackerBackend for SimTrackerBackend {
    fn measure(&self, _meas_time_ms: i32) -> BackendMeasurement {
        lock_world(&self.world).measure()
    }
    fn reflector_found(&self) -> bool {
        lock_world(&self.world).reflector_visible()
    }
    fn reflector_near(&self, xyz_mm: [f64; 3]) -> bool {
        lock_world(&self.world).reflector_near(xyz_mm)
    }
    fn meteo(&self) -> Meteo {
        Meteo::default()
    }
    fn warmed_up(&self) -> bool {
        lock_world(&self.world).warmed_up()
    }
}

/// robotlink backend: joint moves with speed, settle time and repeatability on the world.
#[derive(Debug, Clone)]
pub struct SimRobotBackend {
    world: SharedWorld,
    arm: String,
}

impl SimRobotBackend {
    /// A backend over `world`.
    pub fn new(world: SharedWorld) -> SimRobotBackend {
        let arm = lock_world(&world)
            .nominal_model()
            .name
            .split_whitespace()
            .collect::<Vec<_>>()
            .join("_");
        SimRobotBackend {
            world,
            arm: if arm.is_empty() { "SIM6".into() } else { arm },
        }
    }
}

fn rad(q: &[f64; 6]) -> Vec<f64> {
    q.iter().map(|d| d.to_radians()).collect()
}

impl RobotBackend for SimRobotBackend {
    fn identity(&self) -> Identity {
        Identity {
            ctrl: "CELLCAL-SIM".into(),
            arm: self.arm.clone(),
            sw: env!("CARGO_PKG_VERSION").into(),
        }
    }
    fn check_target(&self, joints_deg: &[f64; 6]) -> Result<(), BackendError> {
        lock_world(&self.world).check_target(&rad(joints_deg))
    }
    fn start_move(&self, joints_deg: [f64; 6], vel_pct: f64) -> Result<(), BackendError> {
        lock_world(&self.world).start_move(rad(&joints_deg), vel_pct)
    }
    fn joints_deg(&self) -> [f64; 6] {
        let q = lock_world(&self.world).readback_joints_rad();
        let mut out = [0.0; 6];
        for (o, v) in out.iter_mut().zip(q) {
            *o = v.to_degrees();
        }
        out
    }
    fn pose(&self) -> Result<Pose, BackendError> {
        Ok(lock_world(&self.world).controller_pose())
    }
    fn is_moving(&self) -> bool {
        lock_world(&self.world).is_moving()
    }
    fn is_settled(&self) -> bool {
        lock_world(&self.world).is_settled()
    }
    fn stop(&self) {
        lock_world(&self.world).stop();
    }
    fn set_power(&self, on: bool) -> Result<(), BackendError> {
        lock_world(&self.world).set_power(on)
    }
    fn power(&self) -> bool {
        lock_world(&self.world).power()
    }
    fn estop(&self) -> bool {
        lock_world(&self.world).estop()
    }
}
