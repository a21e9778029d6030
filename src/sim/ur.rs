//! The simulated Universal Robots controller of the cell: `drivers/ur`'s [`ur::SimController`]
//! and its Dashboard, RTDE and URScript servers on the standard ports of `[sim] ur_host`, with
//! the joints of the shared [`World`](super::World) ([`WorldMotion`]): the same motion, joint
//! repeatability and fault model as the simulated Stäubli.
//!
//! `[sim.faults.robot]` on this controller: `reject_move_n` (the move is refused: a protective
//! stop, as a controller does for a target beyond its joint limits), `estop_after_moves` /
//! `estop_delay_ms` (an emergency stop), `never_settle` and `slow_settle` (the program keeps
//! running: the arm has not settled), `disconnect_during_move` (every client connection drops
//! after the move started). `reject_code` means nothing here.
//!
//! Simpler than a real controller: `stopj` holds the arm where it is at once (the world has no
//! deceleration of its own); a `movej`'s `a` is not used and `v` is read as a fraction of the
//! robot file's slowest joint speed (what the adapter sends), the world then moving at that
//! speed setting by its own motion model.

use std::net::IpAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tracing::warn;
use ur::sim::JointSample;
use ur::{
    ControllerConfig, Motion, MotionFault, RobotMode, ServerConfig, SimController, UrServers,
};

use super::world::{lock_world, SharedWorld};
use super::{SimError, SimWorldConfig};
use crate::cell::UrRobotConfig;
use crate::config::sim::RobotFaults as SimRobotFaults;
use crate::config::RobotSection;
use crate::plan::MotionLimits;

/// The world's robot as the UR controller's joints.
pub struct WorldMotion {
    world: SharedWorld,
    /// The leading-axis speed `movej` means at 100 % (rad/s).
    full_speed_rad_s: f64,
    faults: SimRobotFaults,
    /// Last sample (t, q) for the joint speeds.
    last: Option<(f64, [f64; 6])>,
    qd: [f64; 6],
    /// The world's E-stop as last seen.
    estop_seen: bool,
    pending: Option<MotionFault>,
    /// Until when the current move is reported running although the world settled (s).
    hold_until: f64,
    never_settles: bool,
    disconnect: Arc<Notify>,
}

impl WorldMotion {
    /// The joints of `world`'s robot; `full_speed_rad_s` as [`UrRobotConfig::movej_speed`] at
    /// 100 %.
    pub fn new(
        world: SharedWorld,
        full_speed_rad_s: f64,
        faults: SimRobotFaults,
        disconnect: Arc<Notify>,
    ) -> WorldMotion {
        WorldMotion {
            world,
            full_speed_rad_s,
            faults,
            last: None,
            qd: [0.0; 6],
            estop_seen: false,
            pending: None,
            hold_until: 0.0,
            never_settles: false,
            disconnect,
        }
    }

    fn q(&self) -> [f64; 6] {
        let q = lock_world(&self.world).readback_joints_rad();
        let mut out = [0.0; 6];
        for (o, v) in out.iter_mut().zip(q) {
            *o = v;
        }
        out
    }
}

impl Motion for WorldMotion {
    fn sample(&mut self, t: f64) -> JointSample {
        let q = self.q();
        if let Some((t0, q0)) = self.last {
            let dt = t - t0;
            if dt > 1e-4 {
                for j in 0..6 {
                    self.qd[j] = (q[j] - q0[j]) / dt;
                }
                self.last = Some((t, q));
            }
        } else {
            self.last = Some((t, q));
        }
        // the world's readback is the controller's commanded position
        JointSample {
            q,
            qd: self.qd,
            target_q: q,
        }
    }

    fn movej(&mut self, t: f64, q: [f64; 6], _a: f64, v: f64, _min_duration: f64) {
        let pct = (100.0 * v / self.full_speed_rad_s).clamp(0.01, 100.0);
        let mut w = lock_world(&self.world);
        if w.is_moving() {
            // a new program replaces the running one: the new move starts where the arm is
            w.stop();
        }
        if let Err(e) = w.start_move(q.to_vec(), pct) {
            warn!(error = %e.text, "simulated UR: move refused, protective stop");
            self.pending = Some(MotionFault::ProtectiveStop);
            return;
        }
        self.never_settles = false;
        self.hold_until = 0.0;
        if self.faults.never_settle > 0 {
            self.faults.never_settle -= 1;
            self.never_settles = true;
        } else if self.faults.slow_settle > 0 {
            self.faults.slow_settle -= 1;
            self.hold_until = f64::INFINITY; // set once the world settled
        }
        if self.faults.disconnect_during_move > 0 {
            self.faults.disconnect_during_move -= 1;
            self.disconnect.notify_one();
        }
        let _ = t;
    }

    fn stopj(&mut self, _t: f64, _a: f64) {
        lock_world(&self.world).stop();
        self.never_settles = false;
        self.hold_until = 0.0;
    }

    fn halt(&mut self, t: f64) {
        self.stopj(t, 0.0);
    }

    fn is_moving(&mut self, t: f64) -> bool {
        if self.never_settles {
            return true;
        }
        let settled = lock_world(&self.world).is_settled();
        if !settled {
            return true;
        }
        if self.hold_until.is_infinite() {
            self.hold_until = t + self.faults.slow_settle_extra_ms as f64 / 1000.0;
        }
        t < self.hold_until
    }

    fn fault(&mut self, _t: f64) -> Option<MotionFault> {
        let estop = lock_world(&self.world).estop();
        let newly = estop && !self.estop_seen;
        self.estop_seen = estop;
        if newly {
            return Some(MotionFault::EmergencyStop);
        }
        self.pending.take()
    }
}

/// The running simulated UR controller.
pub struct UrSimCell {
    /// The controller (faults: protective stop, E-stop, disconnect, remote control).
    pub controller: SimController,
    /// Its servers (dropping them stops them).
    pub servers: UrServers,
    /// The host it listens on.
    pub host: IpAddr,
    disconnect_task: JoinHandle<()>,
}

impl std::fmt::Debug for UrSimCell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UrSimCell")
            .field("host", &self.host)
            .finish_non_exhaustive()
    }
}

impl Drop for UrSimCell {
    fn drop(&mut self) {
        self.disconnect_task.abort();
    }
}

impl UrSimCell {
    /// Starts the controller over `world` on the standard ports of `cfg.ur_host`.
    /// Cancel-safe: a drop before it returns closes the listeners bound so far.
    pub async fn start(world: SharedWorld, cfg: &SimWorldConfig) -> Result<UrSimCell, SimError> {
        let (limits, model_name) = {
            let w = lock_world(&world);
            (
                MotionLimits::of(w.nominal_model(), 100.0),
                w.nominal_model().name.clone(),
            )
        };
        let (full, _) = UrRobotConfig::movej_speed_of(&limits, 100.0);
        let disconnect = Arc::new(Notify::new());
        let motion = WorldMotion::new(world, full, cfg.faults.robot.clone(), disconnect.clone());
        let delay = Duration::from_millis(if cfg.realistic { 1000 } else { 20 });
        let config = ControllerConfig {
            robot_model: if model_name.contains("UR10") {
                "UR10".into()
            } else {
                "UR5".into()
            },
            power_on_delay: delay,
            brake_release_delay: delay,
            initial_mode: if cfg.robot_power_on {
                RobotMode::Running
            } else {
                RobotMode::PowerOff
            },
            version: [cfg.ur_version[0], cfg.ur_version[1], cfg.ur_version[2], 0],
            polyscope_version: format!(
                "URSoftware {}.{}.{}.0 (simulated)",
                cfg.ur_version[0], cfg.ur_version[1], cfg.ur_version[2]
            ),
            ..ControllerConfig::default()
        };
        let controller = SimController::new(config, Box::new(motion));
        let servers = UrServers::start(controller.clone(), &ServerConfig::standard(cfg.ur_host))
            .await
            .map_err(|cause| SimError::Io {
                what: format!(
                    "simulated UR controller: cannot bind the standard ports (29999, 30001-30004) \
                     of {} (another controller there? set sim.ur_host to another loopback \
                     address)",
                    cfg.ur_host
                ),
                cause,
            })?;
        let c = controller.clone();
        let disconnect_task = tokio::spawn(async move {
            loop {
                disconnect.notified().await;
                c.disconnect_clients();
            }
        });
        Ok(UrSimCell {
            controller,
            servers,
            host: cfg.ur_host,
            disconnect_task,
        })
    }

    /// Points `ur` (the adapter built from `section`) at this controller: its host and ports,
    /// and the simulated cell's short timeouts where the section leaves them unset.
    pub fn adapter_config(&self, section: &RobotSection, ur: &mut UrRobotConfig) {
        ur.host = self.host.to_string();
        ur.dashboard_port = self.servers.dashboard.port();
        ur.rtde_port = self.servers.rtde.port();
        ur.script_port = self
            .servers
            .script
            .get(1)
            .map_or(ur::SECONDARY_PORT, |a| a.port());
        ur.connect_timeout_ms = section.connect_timeout_ms.unwrap_or(2000);
        ur.request_timeout_ms = section.request_timeout_ms.unwrap_or(2000);
        ur.power_timeout_ms = 10_000;
    }
}
