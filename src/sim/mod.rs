//! The simulated cell: one [`World`] (true robot, motion, stage, tracker noise and drift, seeded
//! ChaCha8 RNG) behind the real protocol servers of `drivers/`: an emScon tracker and a
//! robotlink robot on 127.0.0.1 TCP, a Zaber stage (and optionally an RS-232 gauge) on ptys.
//! [`start_cell`] starts everything; the adapters of [`crate::cell`] talk to it like to the
//! real devices.

pub mod backends;
pub mod config;
#[cfg(test)]
pub mod fake;
pub mod technician;
#[cfg(test)]
mod tests;
pub mod ur;
pub mod world;

use std::future::Future;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tracing::{info, warn};
use zaber::sim::{GaugeFaults, GaugeSim, StageSim, StageSimConfig};

use crate::cell::{EmsconTrackerConfig, LinkRobotConfig, ZaberStageAdapterConfig};
use crate::model::rotation::from_rotation_vector;
use crate::model::RobotModel;
use crate::simulate::truth::{self, ErrorTable};

pub use backends::{SimRobotBackend, SimTrackerBackend};
pub use config::{SimFaults, SimWorldConfig, StageMode};
pub use technician::SimTechnician;
pub use world::{lock_world, SharedWorld, StageSource, World, WorldFaults};

/// Errors of the simulated cell.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A configuration value is invalid.
    #[error("sim config: {0}")]
    Config(String),
    /// The error table could not be loaded or applied.
    #[error("errors `{spec}`: {message}")]
    Errors {
        /// The `errors` value.
        spec: String,
        /// What went wrong.
        message: String,
    },
    /// Binding a port or creating a pty failed.
    #[error("{what}: {cause}")]
    Io {
        /// What was being done.
        what: String,
        /// The I/O error.
        cause: std::io::Error,
    },
}

/// Load an error table: `paper`, `random` (seeded), `none`, or a TOML/JSON file of name = value.
pub fn load_error_table(spec: &str, dof: usize, seed: u64) -> Result<ErrorTable, SimError> {
    let fail = |message: String| SimError::Errors {
        spec: spec.to_owned(),
        message,
    };
    match spec {
        "paper" if dof == 6 => Ok(truth::paper_errors()),
        "paper" => Err(fail("the paper table needs a six-joint robot".into())),
        "random" => Ok(truth::random_errors(dof, seed)),
        "none" | "" => Ok(ErrorTable::new()),
        path => {
            let text = std::fs::read_to_string(Path::new(path))
                .map_err(|e| fail(format!("cannot read: {e}")))?;
            if path.ends_with(".json") {
                serde_json::from_str(&text).map_err(|e| fail(e.to_string()))
            } else {
                toml::from_str(&text).map_err(|e| fail(e.to_string()))
            }
        }
    }
}

/// The true robot: nominal + hidden errors (MDH and non-geometric), base and tool from the
/// config (else the file's).
pub fn true_model(nominal: &RobotModel, cfg: &SimWorldConfig) -> Result<RobotModel, SimError> {
    let errors = load_error_table(&cfg.errors, nominal.dof(), cfg.error_seed)?;
    let mut m = truth::apply_errors(nominal, &errors).map_err(|message| SimError::Errors {
        spec: cfg.errors.clone(),
        message,
    })?;
    if let Some(t) = cfg.base_translation_mm {
        m.base_translation = t.into();
    }
    if let Some(r) = cfg.base_rotation_vector_deg {
        let v: nalgebra::Vector3<f64> = r.into();
        m.base_rotation = from_rotation_vector(&v.map(f64::to_radians));
    }
    if let Some(t) = cfg.tool_mm {
        m.tool = t.into();
    }
    let terms = truth::TermErrors {
        compliance_rad_per_nm: cfg.compliance_rad_per_nm.map(|c| c.to_vec()),
        harmonics_rad: cfg
            .harmonics_urad
            .map(|h| h.iter().map(|row| row.map(|v| v * 1e-6)).collect()),
        typical_seed: (cfg.nongeometric_errors == config::NongeometricErrors::Typical)
            .then_some(cfg.error_seed),
    };
    truth::apply_terms(&m, &terms).map_err(|e| {
        SimError::Config(format!(
            "the non-geometric errors (compliance_rad_per_nm, harmonics_urad, \
             nongeometric_errors): {e}"
        ))
    })
}

/// A running simulated cell. Dropping it stops every task (as does [`RunningSimCell::stop`]).
#[derive(Debug)]
pub struct RunningSimCell {
    /// emScon tracker address (127.0.0.1).
    pub tracker_addr: SocketAddr,
    /// robotlink robot address (127.0.0.1).
    pub robot_addr: SocketAddr,
    /// Zaber stage pty slave (`/dev/pts/N`), in stage mode `zaber`.
    pub stage_path: Option<String>,
    /// Gauge pty slave, when `gauge = true`.
    pub gauge_path: Option<String>,
    /// The world: query the truth, set the manual micrometer, change world-level faults.
    pub world: SharedWorld,
    /// emScon server faults (change at runtime).
    pub tracker_faults: emscon::SharedFaults,
    /// robotlink server faults (change at runtime).
    pub robot_faults: robotlink::FaultHandle,
    /// The stage simulator (its `faults()` can be changed at runtime), in stage mode `zaber`.
    pub stage_sim: Option<StageSim>,
    /// Gauge faults, when `gauge = true`.
    pub gauge_faults: Option<Arc<Mutex<GaugeFaults>>>,
    /// The simulated UR controller, when `robot_protocol = "ur"` (then no robotlink server
    /// runs and `robot_addr` is 127.0.0.1:0, where nothing listens).
    pub ur: Option<ur::UrSimCell>,
    /// The configuration the cell runs with.
    pub config: SimWorldConfig,
    /// The secret the simulated controller's clients must prove (never shown).
    robot_secret: robotlink::SharedSecret,
    stop_tx: watch::Sender<bool>,
    tasks: Vec<JoinHandle<()>>,
}

impl RunningSimCell {
    /// Tracker adapter settings for this cell (address, measuring time, short timeouts).
    pub fn tracker_config(&self) -> EmsconTrackerConfig {
        let meas = i32::try_from(self.config.effective_measure_ms()).unwrap_or(i32::MAX);
        EmsconTrackerConfig::simulated(self.tracker_addr.to_string(), meas)
    }

    /// Robot adapter settings for this cell.
    pub fn robot_config(&self) -> LinkRobotConfig {
        LinkRobotConfig {
            address: self.robot_addr.to_string(),
            connect_timeout_ms: 2000,
            request_timeout_ms: 2000,
            wait_margin_ms: 2000,
            secret: Some(self.robot_secret.clone()),
        }
    }

    /// Points the UR adapter `ur` (built from `section`) at this cell's simulated UR
    /// controller; an error when the cell simulates a robotlink controller.
    pub fn ur_robot_config(
        &self,
        section: &crate::config::RobotSection,
        ur: &mut crate::cell::UrRobotConfig,
    ) -> Result<(), SimError> {
        let sim = self.ur.as_ref().ok_or_else(|| {
            SimError::Config(
                "the simulated cell runs a robotlink controller, not a UR one (sim.robot_protocol)"
                    .into(),
            )
        })?;
        sim.adapter_config(section, ur);
        Ok(())
    }

    /// Stage adapter settings for this cell (stage mode `zaber`): its pty, the simulated
    /// device's address, scale and range, timeouts from its stage speed.
    pub fn stage_config(&self) -> Option<ZaberStageAdapterConfig> {
        let port = self.stage_path.clone()?;
        let speed = self.config.stage_speed_scaled_mm_s().max(1e-3);
        let travel_s = self.config.stage_max_mm / speed;
        let move_ms = (travel_s * 1000.0 * 2.0) as u64 + 2000;
        Some(ZaberStageAdapterConfig {
            port,
            device: self.config.stage_address.0,
            axis: self.config.stage_address.1,
            // A cross-check: the adapter derives the scale from the simulated device.
            microsteps_per_mm: Some(self.config.stage_microsteps_per_mm),
            min_mm: 0.0,
            max_mm: self.config.stage_max_mm,
            tolerance_mm: 2.0 / self.config.stage_microsteps_per_mm,
            move_timeout_ms: move_ms,
            home_timeout_ms: move_ms,
            poll_interval_ms: if self.config.realistic { 20 } else { 1 },
            ..ZaberStageAdapterConfig::default()
        })
    }

    /// Gauge client settings for this cell (`gauge = true`).
    pub fn gauge_config(&self) -> zaber::GaugeConfig {
        zaber::GaugeConfig::default()
    }

    /// A receiver that turns true once the cell is stopping.
    pub fn stopping(&self) -> watch::Receiver<bool> {
        self.stop_tx.subscribe()
    }

    /// Stop every server and pty and wait (bounded) for the tasks to end.
    /// Cancel-safe: the stop signal goes out before the first await (and again when the handle
    /// drops), so a dropped call only stops waiting for the tasks to end.
    pub async fn stop(mut self) {
        let _ = self.stop_tx.send(true);
        let tasks = std::mem::take(&mut self.tasks);
        for t in tasks {
            let abort = t.abort_handle();
            if tokio::time::timeout(Duration::from_secs(3), t)
                .await
                .is_err()
            {
                warn!("sim task did not end in time; aborting it");
                abort.abort();
            }
        }
        info!("simulated cell stopped");
    }
}

impl Drop for RunningSimCell {
    fn drop(&mut self) {
        let _ = self.stop_tx.send(true);
    }
}

/// Cancel-safe: it only waits.
async fn stopped(mut rx: watch::Receiver<bool>) {
    let _ = rx.wait_for(|v| *v).await;
}

/// Cancel-safe: a drop before it returns leaves no listener.
async fn bind(port: u16, what: &str) -> Result<TcpListener, SimError> {
    TcpListener::bind(("127.0.0.1", port))
        .await
        .map_err(|cause| SimError::Io {
            what: format!("{what}: cannot bind 127.0.0.1:{port}"),
            cause,
        })
}

/// Microstep resolution that gives the simulated Zaber product `microsteps_per_mm`: the device
/// reports a whole number of microsteps per full step, so k × full step must be one.
fn sim_stage_resolution(microsteps_per_mm: f64) -> Result<u32, SimError> {
    let full_step_mm = zaber::product::SIM_PRODUCT.full_step_mm;
    let r = (microsteps_per_mm * full_step_mm).round();
    if r < 1.0
        || r > f64::from(u16::MAX)
        || ((r / full_step_mm - microsteps_per_mm) / microsteps_per_mm).abs() > 1e-9
    {
        return Err(SimError::Config(format!(
            "stage_microsteps_per_mm {microsteps_per_mm} is not a whole resolution of the simulated \
             Zaber stage (resolution / {full_step_mm} mm, e.g. 64 → {})",
            64.0 / full_step_mm
        )));
    }
    Ok(r as u32)
}

/// [`start_cell_with`] and a fresh random robotlink secret, which only the returned handle's
/// [`RunningSimCell::robot_config`] knows. Cancel-safe as [`start_cell_with`].
pub async fn start_cell(
    robot: RobotModel,
    cfg: SimWorldConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<RunningSimCell, SimError> {
    let secret =
        robotlink::SharedSecret::generate().map_err(|e| SimError::Config(e.to_string()))?;
    start_cell_with(robot, cfg, secret, shutdown).await
}

/// Start the simulated cell for `robot` (the nominal model): binds the tracker and robot
/// listeners on 127.0.0.1 (the robot's serves `cfg.robot_allow` clients that prove they hold
/// `robot_secret`), opens the ptys, and runs until `shutdown` completes or the returned handle
/// is stopped or dropped. Must be called inside a Tokio runtime.
/// Cancel-safe: a drop before it returns drops the listeners and ptys opened so far; the servers
/// are spawned only after the last await.
pub async fn start_cell_with(
    robot: RobotModel,
    cfg: SimWorldConfig,
    robot_secret: robotlink::SharedSecret,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<RunningSimCell, SimError> {
    check_world_config(&robot, &cfg)?;
    let truth = true_model(&robot, &cfg)?;
    let stage_sim = stage_simulator(&cfg)?;
    let source = match &stage_sim {
        Some(sim) => StageSource::Zaber {
            sim: sim.clone(),
            microsteps_per_mm: cfg.stage_microsteps_per_mm,
        },
        None => StageSource::Manual { position_mm: 0.0 },
    };
    let world: SharedWorld = Arc::new(Mutex::new(World::new(robot, truth, &cfg, source)?));
    let tracker_faults = tracker_faults(&cfg);
    lock_world(&world).attach_tracker_faults(tracker_faults.clone());
    let robot_faults = robot_faults(&cfg);

    let tracker_listener = bind(cfg.tracker_port, "tracker").await?;
    let tracker_addr = local_addr(&tracker_listener, "tracker")?;
    let (robot_listener, robot_addr, ur) =
        if cfg.robot_protocol == Some(crate::config::RobotProtocol::Ur) {
            let ur = ur::UrSimCell::start(world.clone(), &cfg).await?;
            (None, SocketAddr::from(([127, 0, 0, 1], 0)), Some(ur))
        } else {
            let l = bind(cfg.robot_port, "robot").await?;
            let a = local_addr(&l, "robot")?;
            (Some(l), a, None)
        };
    let stage_pty = match &stage_sim {
        Some(sim) => {
            Some(
                zaber::pty::spawn_stage_pty(sim.clone()).map_err(|cause| SimError::Io {
                    what: "stage: cannot open a pty".into(),
                    cause,
                })?,
            )
        }
        None => None,
    };
    let (gauge_pty, gauge_faults) = if cfg.gauge {
        let (pty, faults) = gauge_on_pty(&world)?;
        (Some(pty), Some(faults))
    } else {
        (None, None)
    };
    let stage_path = stage_pty.as_ref().map(|p| p.path());
    let gauge_path = gauge_pty.as_ref().map(|p| p.path());

    let (stop_tx, stop_rx) = watch::channel(false);
    let tracker_options = emscon::ServerOptions {
        measuring_time_scale: cfg.measuring_scale(),
        ..emscon::ServerOptions::default()
    };
    let mut tasks = vec![
        serve_tracker(
            tracker_listener,
            Arc::new(SimTrackerBackend::new(world.clone())),
            tracker_faults.clone(),
            tracker_options,
            stop_rx.clone(),
        ),
        // the ptys close when the cell stops
        tokio::spawn({
            let stop = stop_rx.clone();
            async move {
                stopped(stop).await;
                drop(stage_pty);
                drop(gauge_pty);
            }
        }),
        stop_on(shutdown, stop_tx.clone()),
    ];
    if let Some(l) = robot_listener {
        tasks.push(serve_robot(
            l,
            Arc::new(SimRobotBackend::new(world.clone())),
            robot_faults.clone(),
            robotlink::ServerAccess {
                allow: cfg.robot_allow.clone(),
                ..robotlink::ServerAccess::loopback(robot_secret.clone())
            },
            stop_rx.clone(),
        ));
    }
    info!(%tracker_addr, %robot_addr, ?stage_path, ?gauge_path, "simulated cell listening");
    Ok(RunningSimCell {
        tracker_addr,
        robot_addr,
        stage_path,
        gauge_path,
        world,
        tracker_faults,
        robot_faults,
        stage_sim,
        gauge_faults,
        ur,
        config: cfg,
        robot_secret,
        stop_tx,
        tasks,
    })
}

/// What the simulated cell cannot run with: another joint count than the controller's six, a
/// stage without range or scale, a beam-break probability outside [0, 1].
fn check_world_config(robot: &RobotModel, cfg: &SimWorldConfig) -> Result<(), SimError> {
    if robot.dof() != 6 {
        return Err(SimError::Config(format!(
            "the simulated robot controller drives 6 joints, the model has {}",
            robot.dof()
        )));
    }
    // the parser's rules, for a configuration built in code
    cfg.check().map_err(|e| SimError::Config(e.to_string()))
}

/// The motorised stage's simulator with the configured range, speed and faults (`None`: a
/// manual micrometer).
fn stage_simulator(cfg: &SimWorldConfig) -> Result<Option<StageSim>, SimError> {
    if cfg.stage_mode != StageMode::Zaber {
        return Ok(None);
    }
    let k = cfg.stage_microsteps_per_mm;
    let sim = StageSim::new(StageSimConfig {
        resolution: sim_stage_resolution(k)?,
        limit_min: 0,
        limit_max: (cfg.stage_max_mm * k).round() as i64,
        speed_steps_s: cfg.stage_speed_scaled_mm_s().max(1e-3) * k,
        homed: false,
        move_overhead: Duration::from_secs_f64(cfg.stage_settle_s()),
        device: cfg.stage_address.0,
        axis: cfg.stage_address.1,
        ..StageSimConfig::default()
    });
    {
        let s = &cfg.faults.stage;
        let mut f = sim.faults();
        f.reject = s.reject;
        f.reject_reason = s.reject_reason.clone();
        f.stall = s.stall;
        f.fault = s.fault;
        f.overshoot = s.overshoot;
        f.lose_home = s.lose_home;
    }
    Ok(Some(sim))
}

/// The emScon server's fault table from `[sim.faults.tracker]`.
fn tracker_faults(cfg: &SimWorldConfig) -> emscon::SharedFaults {
    let tf = &cfg.faults.tracker;
    let faults = emscon::FaultConfig::shared();
    {
        let mut f = faults.lock().unwrap_or_else(|p| p.into_inner());
        f.beam_break_before_measure = tf.beam_break_before_measure;
        f.beam_break_during_measure = tf.beam_break_during_measure;
        f.beam_break_status = tf.beam_break_status;
        f.relock_after_ms = tf.relock_after_ms;
        f.no_reply = tf.no_reply;
        f.initialize_delay_ms = tf.initialize_delay_ms;
    }
    faults
}

/// The robotlink server's fault table from `[sim.faults.robot]`.
fn robot_faults(cfg: &SimWorldConfig) -> robotlink::FaultHandle {
    let rf = &cfg.faults.robot;
    let faults = robotlink::FaultConfig::handle();
    {
        let mut f = faults.lock().unwrap_or_else(|p| p.into_inner());
        f.never_settle = rf.never_settle;
        f.slow_settle = rf.slow_settle;
        f.slow_settle_extra = Duration::from_millis(rf.slow_settle_extra_ms);
        f.disconnect_during_move = rf.disconnect_during_move;
    }
    faults
}

fn local_addr(l: &TcpListener, what: &str) -> Result<SocketAddr, SimError> {
    l.local_addr().map_err(|cause| SimError::Io {
        what: format!("{what}: local address"),
        cause,
    })
}

/// The RS-232 gauge on a pty, reading the world's true stage position, and its fault table.
fn gauge_on_pty(
    world: &SharedWorld,
) -> Result<(zaber::pty::PtyDevice, Arc<Mutex<GaugeFaults>>), SimError> {
    let w = world.clone();
    let sim = GaugeSim::new(Arc::new(move || lock_world(&w).stage_true_mm()));
    let faults = sim.faults.clone();
    let pty = zaber::pty::spawn_gauge_pty(sim).map_err(|cause| SimError::Io {
        what: "gauge: cannot open a pty".into(),
        cause,
    })?;
    Ok((pty, faults))
}

/// The simulated tracker's emScon server task, until the cell stops.
fn serve_tracker(
    listener: TcpListener,
    backend: Arc<dyn emscon::TrackerBackend>,
    faults: emscon::SharedFaults,
    options: emscon::ServerOptions,
    stop: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let served = emscon::serve_with_options(listener, backend, faults, options, stopped(stop));
        if let Err(e) = served.await {
            warn!(error = %e, "sim tracker server ended");
        }
    })
}

/// The simulated controller's robotlink server task, until the cell stops.
fn serve_robot(
    listener: TcpListener,
    backend: Arc<dyn robotlink::RobotBackend>,
    faults: robotlink::FaultHandle,
    access: robotlink::ServerAccess,
    stop: watch::Receiver<bool>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        if let Err(e) = robotlink::serve(listener, backend, faults, access, stopped(stop)).await {
            warn!(error = %e, "sim robot server ended");
        }
    })
}

/// The task that stops the cell when `shutdown` completes (or ends once it stopped otherwise).
fn stop_on(
    shutdown: impl Future<Output = ()> + Send + 'static,
    stop_tx: watch::Sender<bool>,
) -> JoinHandle<()> {
    let mut rx = stop_tx.subscribe();
    tokio::spawn(async move {
        tokio::select! {
            _ = shutdown => { let _ = stop_tx.send(true); }
            _ = rx.wait_for(|v| *v) => {}
        }
    })
}
