//! [`LinkRobot`]: the [`Robot`] trait over the robotlink line protocol (`drivers/robotlink`).
//! Degrees on the wire, radians in the trait.

use std::time::Duration;

use async_trait::async_trait;
use robotlink::{ClientConfig, RobotClient, RobotError, SecretError, SharedSecret, StopHandle};
use serde::{Deserialize, Serialize};
use tracing::info;

use super::{CellError, DeviceKind, FaultKind, Robot};
use crate::config::{DeviceMode, RobotProtocol, RobotSection};

/// Configuration of a [`LinkRobot`] (serde: every field has a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LinkRobotConfig {
    /// Server address, `host:port` (the VAL3 app listens on [`robotlink::DEFAULT_PORT`],
    /// 11100, unless the site set another port on the pendant).
    pub address: String,
    /// TCP connect timeout (ms).
    pub connect_timeout_ms: u64,
    /// Reply timeout of every request except WAIT (ms).
    pub request_timeout_ms: u64,
    /// Extra client-side time granted to WAIT (ms).
    pub wait_margin_ms: u64,
    /// The secret shared with the controller (never serialized; `Debug` hides it).
    #[serde(skip)]
    pub secret: Option<SharedSecret>,
}

impl Default for LinkRobotConfig {
    fn default() -> Self {
        LinkRobotConfig {
            address: format!("127.0.0.1:{}", robotlink::DEFAULT_PORT),
            connect_timeout_ms: 5000,
            request_timeout_ms: 5000,
            wait_margin_ms: 2000,
            secret: None,
        }
    }
}

impl LinkRobotConfig {
    /// These settings (the controller's address, secret and default timings) with every
    /// setting `[robot_controller]` gives: the one place the section reaches the adapter.
    pub fn with_section(self, s: &RobotSection) -> LinkRobotConfig {
        LinkRobotConfig {
            connect_timeout_ms: s.connect_timeout_ms.unwrap_or(self.connect_timeout_ms),
            request_timeout_ms: s.request_timeout_ms.unwrap_or(self.request_timeout_ms),
            wait_margin_ms: s.wait_margin_ms.unwrap_or(self.wait_margin_ms),
            ..self
        }
    }

    /// The driver's client configuration.
    pub fn client_config(&self) -> ClientConfig {
        ClientConfig {
            connect_timeout: Duration::from_millis(self.connect_timeout_ms),
            request_timeout: Duration::from_millis(self.request_timeout_ms),
            wait_margin: Duration::from_millis(self.wait_margin_ms),
            secret: self.secret.clone(),
            ..ClientConfig::default()
        }
    }
}

/// Why the controller's shared secret could not be had.
#[derive(Debug, thiserror::Error)]
pub enum RobotSecretError {
    /// A real controller and no `secret_file`.
    #[error(
        "robot_controller.secret_file: not set. The robot controller (robotlink v3) accepts only \
         a client that proves it holds their shared secret: write 64 hex digits (`openssl rand \
         -hex 32`) to a file only cellcal can read, name it here, and enter the same secret in \
         the controller application (deploy/staubli/README.md)"
    )]
    NotSet,
    /// The file is missing, open to every user, or not 64 hex digits.
    #[error("robot_controller.secret_file: {0}")]
    File(SecretError),
}

from_cause!(SecretError => RobotSecretError::File);

/// The secret shared with the robot controller: read from `[robot_controller] secret_file`
/// (required for a real robotlink controller); a simulated controller or a UR controller
/// without one gets a fresh random secret, which only this process knows.
pub fn controller_secret(section: &RobotSection) -> Result<SharedSecret, RobotSecretError> {
    match (&section.secret_file, section.mode) {
        (Some(path), _) => Ok(SharedSecret::read_file(path)?),
        // a UR controller needs none (and its section takes none): only the simulated
        // Stäubli of this process would see it
        (None, _) if section.protocol == RobotProtocol::Ur => Ok(SharedSecret::generate()?),
        (None, DeviceMode::Sim) => Ok(SharedSecret::generate()?),
        (None, DeviceMode::Real) => Err(RobotSecretError::NotSet),
    }
}

/// Classify a driver error for the campaign.
pub fn classify_robotlink(e: &RobotError) -> FaultKind {
    match e {
        RobotError::EStop(_) | RobotError::PowerOff(_) => FaultKind::EmergencyStop,
        RobotError::Rejected { .. } | RobotError::Auth(_) | RobotError::OldServer(_) => {
            FaultKind::Rejected
        }
        RobotError::NotSettled(_) | RobotError::Timeout(_) => FaultKind::Timeout,
        RobotError::Stopped(_) => FaultKind::Aborted,
        RobotError::Protocol(_) => FaultKind::Protocol,
        RobotError::Disconnected | RobotError::Io(_) => FaultKind::Disconnected,
    }
}

fn cell_err(e: RobotError) -> CellError {
    CellError::new(DeviceKind::Robot, classify_robotlink(&e), e.to_string())
}

fn to_rad(deg: [f64; 6]) -> Vec<f64> {
    deg.iter().map(|d| d.to_radians()).collect()
}

/// A robot controller speaking the robotlink protocol over TCP.
#[derive(Debug)]
pub struct LinkRobot {
    cfg: LinkRobotConfig,
    client: Option<RobotClient>,
    speed_pct: Option<f64>,
    /// From the last `HELLO`.
    identity: Option<String>,
}

impl LinkRobot {
    /// A robot adapter; nothing is connected until [`Robot::prepare`].
    pub fn new(cfg: LinkRobotConfig) -> LinkRobot {
        LinkRobot {
            cfg,
            client: None,
            speed_pct: None,
            identity: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &LinkRobotConfig {
        &self.cfg
    }

    /// The connected driver client, if any (events, POSE, STATE).
    pub fn client(&self) -> Option<&RobotClient> {
        self.client.as_ref()
    }

    /// A handle that stops the arm from another task while this adapter is borrowed
    /// (valid for the current connection only); `None` when not connected.
    pub fn stop_handle(&self) -> Option<StopHandle> {
        self.client.as_ref().map(RobotClient::stop_handle)
    }

    fn connected(&self) -> Result<&RobotClient, CellError> {
        match &self.client {
            Some(c) if !c.is_closed() => Ok(c),
            _ => Err(CellError::new(
                DeviceKind::Robot,
                FaultKind::Disconnected,
                "not connected",
            )),
        }
    }

    /// Connect and say HELLO unless a live connection exists. Cancel-safe: a dropped call
    /// leaves either no client or a complete one.
    async fn ensure_connected(&mut self) -> Result<(), CellError> {
        if matches!(&self.client, Some(c) if !c.is_closed()) {
            return Ok(());
        }
        let (client, identity) = self.open().await?;
        self.client = Some(client);
        self.identity = Some(identity);
        Ok(())
    }

    /// A new connection that has authenticated both ways (robotlink v3 handshake), and what
    /// the controller said it is.
    /// Cancel-safe: a drop before it returns drops the new connection (the client closes on drop).
    async fn open(&self) -> Result<(RobotClient, String), CellError> {
        let client = RobotClient::connect(self.cfg.address.as_str(), self.cfg.client_config())
            .await
            .map_err(cell_err)?;
        let id = client.hello().await.map_err(cell_err)?;
        info!(
            address = %self.cfg.address, ctrl = %id.ctrl, arm = %id.arm, sw = %id.sw,
            protocol = client.protocol_version().unwrap_or(0), "robot connected"
        );
        let identity = format!(
            "arm {} on controller {}, robotlink server {} (protocol v{})",
            id.arm,
            id.ctrl,
            id.sw,
            client.protocol_version().unwrap_or(0)
        );
        Ok((client, identity))
    }
}

#[async_trait]
impl Robot for LinkRobot {
    /// Connect, HELLO, `POWER ON`, `SPEED`: the only place that switches power on (called by
    /// the engine on an operator's start/resume). Cancel-safe (driver requests are).
    async fn prepare(&mut self, speed_pct: f64) -> Result<(), CellError> {
        if !(speed_pct > 0.0 && speed_pct <= 100.0) {
            return Err(CellError::new(
                DeviceKind::Robot,
                FaultKind::Rejected,
                format!("speed {speed_pct} % not in (0, 100]"),
            ));
        }
        self.ensure_connected().await?;
        let c = self.connected()?;
        c.power(true).await.map_err(cell_err)?;
        c.speed(speed_pct).await.map_err(cell_err)?;
        self.speed_pct = Some(speed_pct);
        Ok(())
    }

    /// `MOVEJ` (rad → deg). Cancel-safe; a dropped call may still have started the move.
    async fn move_joints(&mut self, q_rad: &[f64]) -> Result<(), CellError> {
        let deg: [f64; 6] = match q_rad {
            [a, b, c, d, e, f] => [*a, *b, *c, *d, *e, *f].map(f64::to_degrees),
            _ => {
                return Err(CellError::new(
                    DeviceKind::Robot,
                    FaultKind::Rejected,
                    format!("robotlink needs 6 joints, got {}", q_rad.len()),
                ))
            }
        };
        if deg.iter().any(|v| !v.is_finite()) {
            return Err(CellError::new(
                DeviceKind::Robot,
                FaultKind::Rejected,
                "joint target is not finite",
            ));
        }
        self.connected()?
            .move_joints(deg, None)
            .await
            .map_err(cell_err)
    }

    /// `WAIT`. Cancel-safe: dropping it leaves the arm moving; follow with [`Robot::stop`].
    async fn wait_settled(&mut self, timeout: Duration) -> Result<Vec<f64>, CellError> {
        let j = self
            .connected()?
            .wait_settled(timeout)
            .await
            .map_err(cell_err)?;
        Ok(to_rad(j))
    }

    /// `JOINTS` (deg → rad). Cancel-safe.
    async fn joints(&mut self) -> Result<Vec<f64>, CellError> {
        let j = self.connected()?.joints().await.map_err(cell_err)?;
        Ok(to_rad(j))
    }

    /// `STOP`, overtaking an outstanding (or abandoned) `WAIT` on protocol v2; on v1 with a
    /// request outstanding it closes the connection (the server stops on disconnect).
    /// Cancel-safe.
    async fn stop(&mut self) -> Result<(), CellError> {
        self.connected()?.stop().await.map_err(cell_err)
    }

    /// New connection, HELLO and the per-connection SPEED again; power is left as it is
    /// (PROTOCOL.md §6: never switched on implicitly; [`Robot::prepare`] does that).
    /// Cancel-safe: the new connection is kept only once its SPEED is set, so a dropped call
    /// leaves no connection (never one running at the default 100 %).
    async fn reconnect(&mut self) -> Result<(), CellError> {
        if let Some(c) = self.client.take() {
            c.close().await;
        }
        let (client, identity) = self.open().await?;
        if let Some(speed) = self.speed_pct {
            client.speed(speed).await.map_err(cell_err)?;
        }
        self.client = Some(client);
        self.identity = Some(identity);
        Ok(())
    }

    /// Connect and authenticate if needed, then `STATE` and `JOINTS`: no `POWER`, `SPEED` or
    /// motion. Cancel-safe (driver requests are).
    async fn check(&mut self) -> Result<String, CellError> {
        self.ensure_connected().await?;
        let c = self.connected()?;
        let st = c.state().await.map_err(cell_err)?;
        let joints = c.joints().await.map_err(cell_err)?;
        let joints: Vec<String> = joints.iter().map(|d| format!("{d:.3}")).collect();
        Ok(format!(
            "{}; power {}, mode {}, e-stop {}, {}; joints [{}] deg",
            self.identity.as_deref().unwrap_or("robotlink controller"),
            if st.power { "on" } else { "off" },
            st.mode,
            if st.estop { "PRESSED" } else { "clear" },
            if st.moving {
                "MOVING"
            } else {
                "standing still"
            },
            joints.join(", ")
        ))
    }

    fn identity(&self) -> Option<String> {
        self.identity.clone()
    }
}
