//! [`EmsconTracker`]: the [`Tracker`] trait over a Leica emScon TPI server (`drivers/emscon`).

use std::time::Duration;

use async_trait::async_trait;
use emscon::{Client, ClientConfig, EmsconError, StationarySetup, SystemStatus};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use tracing::{debug, info, warn};

use super::{CellError, DeviceKind, FaultKind, Tracker, TrackerPoint};
use crate::config::TrackerSection;

/// Configuration of an [`EmsconTracker`] (serde: every field has a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmsconTrackerConfig {
    /// Server address, `host:port` (emScon listens on port 700).
    pub address: String,
    /// Stationary measuring time (ms).
    pub meas_time_ms: i32,
    /// Reflector id; `None` picks the first RRR 1.5".
    pub reflector_id: Option<i32>,
    /// Use the ADM.
    pub use_adm: bool,
    /// Status codes meaning "beam broken"; `None` keeps the driver's set (10004, 10009, 10014).
    pub beam_break_codes: Option<Vec<i32>>,
    /// One extra site-specific beam-break code.
    pub beam_break_code: Option<i32>,
    /// Approximate distance (mm) given to FindReflector when re-locking.
    pub search_distance_mm: f64,
    /// TCP connect timeout (ms).
    pub connect_timeout_ms: u64,
    /// Reply timeout of ordinary commands (ms).
    pub command_timeout_ms: u64,
    /// Timeout of Initialize (ms).
    pub initialize_timeout_ms: u64,
    /// Timeout of FindReflector / GoLastMeasuredPoint (ms).
    pub search_timeout_ms: u64,
    /// Added to the measuring time to get the result timeout (ms).
    pub measure_margin_ms: u64,
}

impl Default for EmsconTrackerConfig {
    fn default() -> Self {
        EmsconTrackerConfig {
            address: "192.168.0.1:700".into(),
            meas_time_ms: 1000,
            reflector_id: None,
            use_adm: true,
            beam_break_codes: None,
            beam_break_code: None,
            search_distance_mm: 3000.0,
            connect_timeout_ms: 5000,
            command_timeout_ms: 30_000,
            initialize_timeout_ms: 90_000,
            search_timeout_ms: 30_000,
            measure_margin_ms: 5000,
        }
    }
}

impl EmsconTrackerConfig {
    /// The settings of a simulated cell's tracker at `address`: the measuring time the cell's
    /// clients should use, short timeouts.
    pub fn simulated(address: String, meas_time_ms: i32) -> EmsconTrackerConfig {
        EmsconTrackerConfig {
            address,
            meas_time_ms,
            search_distance_mm: 2500.0,
            connect_timeout_ms: 2000,
            command_timeout_ms: 2000,
            initialize_timeout_ms: 5000,
            search_timeout_ms: 2000,
            measure_margin_ms: 2000,
            ..EmsconTrackerConfig::default()
        }
    }

    /// These settings (the device's address and default timings) with every setting
    /// `[tracker]` gives: the one place the section reaches the adapter.
    pub fn with_section(self, s: &TrackerSection) -> EmsconTrackerConfig {
        EmsconTrackerConfig {
            // unset: this configuration's (the simulated cell's, or the real default)
            meas_time_ms: s.measure_ms.map_or(self.meas_time_ms, |ms| {
                i32::try_from(ms).unwrap_or(i32::MAX)
            }),
            reflector_id: s.reflector_id,
            use_adm: s.use_adm,
            beam_break_codes: s.beam_break_codes.clone(),
            beam_break_code: s.beam_break_code,
            search_distance_mm: s.search_distance_mm.unwrap_or(self.search_distance_mm),
            connect_timeout_ms: s.connect_timeout_ms.unwrap_or(self.connect_timeout_ms),
            command_timeout_ms: s.command_timeout_ms.unwrap_or(self.command_timeout_ms),
            initialize_timeout_ms: s
                .initialize_timeout_ms
                .unwrap_or(self.initialize_timeout_ms),
            search_timeout_ms: s.search_timeout_ms.unwrap_or(self.search_timeout_ms),
            measure_margin_ms: s.measure_margin_ms.unwrap_or(self.measure_margin_ms),
            address: self.address,
        }
    }

    /// The driver's client configuration.
    pub fn client_config(&self) -> ClientConfig {
        let mut c = ClientConfig {
            connect_timeout: Duration::from_millis(self.connect_timeout_ms),
            command_timeout: Duration::from_millis(self.command_timeout_ms),
            initialize_timeout: Duration::from_millis(self.initialize_timeout_ms),
            search_timeout: Duration::from_millis(self.search_timeout_ms),
            measure_margin: Duration::from_millis(self.measure_margin_ms),
            default_meas_time_ms: self.meas_time_ms,
            beam_break_code: self.beam_break_code,
            ..ClientConfig::default()
        };
        if let Some(codes) = &self.beam_break_codes {
            c.beam_break_codes = codes.clone();
        }
        c
    }
}

/// Classify a driver error for the campaign.
pub fn classify_emscon(e: &EmsconError) -> FaultKind {
    match e {
        EmsconError::BeamBroken | EmsconError::TargetNotFound => FaultKind::BeamBroken,
        EmsconError::Timeout { .. } => FaultKind::Timeout,
        EmsconError::Disconnected | EmsconError::Io(_) | EmsconError::ConnectionRefused => {
            FaultKind::Disconnected
        }
        EmsconError::NotInitialized | EmsconError::NotWarmedUp | EmsconError::Busy => {
            FaultKind::NotReady
        }
        EmsconError::Protocol(_) => FaultKind::Protocol,
        EmsconError::Device { .. } => FaultKind::Device,
    }
}

/// The tracker as its system status names it: serial number and emScon version.
fn status_identity(s: &SystemStatus) -> String {
    let [major, minor, build] = s.version;
    format!(
        "emScon tracker serial {}, emScon {major}.{minor}.{build}",
        s.serial_number
    )
}

fn cell_err(e: EmsconError) -> CellError {
    CellError::new(DeviceKind::Tracker, classify_emscon(&e), e.to_string())
}

/// A Leica tracker reached through emScon TPI over TCP.
pub struct EmsconTracker {
    cfg: EmsconTrackerConfig,
    client: Option<Client>,
    /// From the last `GetSystemStatus` of a setup.
    identity: Option<String>,
}

impl std::fmt::Debug for EmsconTracker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EmsconTracker")
            .field("cfg", &self.cfg)
            .field("connected", &self.client.as_ref().map(Client::is_connected))
            .finish()
    }
}

impl EmsconTracker {
    /// A tracker adapter; nothing is connected until [`Tracker::prepare`].
    pub fn new(cfg: EmsconTrackerConfig) -> EmsconTracker {
        EmsconTracker {
            cfg,
            client: None,
            identity: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &EmsconTrackerConfig {
        &self.cfg
    }

    /// The connected driver client, if any (events, extra commands).
    pub fn client(&self) -> Option<&Client> {
        self.client.as_ref()
    }

    fn connected(&self) -> Result<&Client, CellError> {
        match &self.client {
            Some(c) if c.is_connected() => Ok(c),
            _ => Err(CellError::new(
                DeviceKind::Tracker,
                FaultKind::Disconnected,
                "not connected",
            )),
        }
    }

    /// Cancel-safe: the client is stored only once set up, so a drop leaves no connection.
    async fn connect_and_setup(&mut self) -> Result<(), CellError> {
        let client = Client::connect(self.cfg.address.as_str(), self.cfg.client_config())
            .await
            .map_err(cell_err)?;
        let setup = StationarySetup {
            meas_time_ms: self.cfg.meas_time_ms,
            use_adm: self.cfg.use_adm,
            reflector_id: self.cfg.reflector_id,
            ..StationarySetup::default()
        };
        let status = client.setup_stationary(&setup).await.map_err(cell_err)?;
        info!(address = %self.cfg.address, tps = status.tracker_processor_status, "tracker ready");
        self.identity = Some(status_identity(&status));
        self.client = Some(client);
        Ok(())
    }
}

#[async_trait]
impl Tracker for EmsconTracker {
    /// Cancel-safe (the emScon client is): a drop during the setup drops the connection (the client
    /// is taken out for it), so the next call fails `Disconnected` or connects afresh.
    async fn prepare(&mut self) -> Result<(), CellError> {
        if let Some(c) = self.client.take() {
            if c.is_connected() {
                let setup = StationarySetup {
                    meas_time_ms: self.cfg.meas_time_ms,
                    use_adm: self.cfg.use_adm,
                    reflector_id: self.cfg.reflector_id,
                    ..StationarySetup::default()
                };
                let res = c.setup_stationary(&setup).await;
                self.client = Some(c);
                let status = res.map_err(cell_err)?;
                self.identity = Some(status_identity(&status));
                return Ok(());
            }
            c.close().await;
        }
        self.connect_and_setup().await
    }

    /// Cancel-safe (the emScon client is): a dropped measurement closes the connection, so its
    /// result never comes back as the next one.
    async fn measure(&mut self) -> Result<TrackerPoint, CellError> {
        let c = self.connected()?;
        let m = c.measure_stationary().await.map_err(|e| {
            debug!(error = %e, "tracker measurement failed");
            cell_err(e)
        })?;
        Ok(TrackerPoint {
            p_mm: Vector3::new(m.x_mm, m.y_mm, m.z_mm),
            std_mm: m.std_mm,
            std_total_mm: m.std_total_mm,
            temperature_c: m.temperature_c,
            pressure_mbar: m.pressure_mbar,
            humidity_pct: m.humidity_pct,
            sent_at: m.sent_at,
            received_at: m.received_at,
        })
    }

    /// GoPosition at the predicted ball position, then GoLastMeasuredPoint (the last point is
    /// often the previous pose's, far away), then FindReflector; after each, a check that a
    /// reflector is locked (GetMeasurementStatusInfo). Cancel-safe (the emScon client is).
    async fn relock(&mut self, predicted_mm: Option<Vector3<f64>>) -> Result<(), CellError> {
        let distance = self.cfg.search_distance_mm;
        let use_adm = self.cfg.use_adm;
        let c = self.connected()?;
        if let Some(p) = predicted_mm.filter(|p| p.iter().all(|v| v.is_finite())) {
            match c.go_position([p.x, p.y, p.z], use_adm).await {
                Ok(()) => {
                    let status = c.measurement_status().await.map_err(cell_err)?;
                    if status.reflector_found() {
                        debug!("relocked at the predicted position");
                        return Ok(());
                    }
                    warn!("no reflector at the predicted position, trying the last point");
                }
                Err(e) if e.is_connection_lost() => return Err(cell_err(e)),
                Err(e) => warn!(error = %e, "GoPosition failed, trying the last point"),
            }
        }
        match c.go_last_measured_point().await {
            Ok(()) => {
                let status = c.measurement_status().await.map_err(cell_err)?;
                if status.reflector_found() {
                    return Ok(());
                }
                warn!("GoLastMeasuredPoint found no reflector there, trying FindReflector");
            }
            Err(e) if e.is_connection_lost() => return Err(cell_err(e)),
            Err(e) => warn!(error = %e, "GoLastMeasuredPoint failed, trying FindReflector"),
        }
        c.find_reflector(distance).await.map_err(cell_err)?;
        let status = c.measurement_status().await.map_err(cell_err)?;
        if status.reflector_found() {
            Ok(())
        } else {
            Err(CellError::new(
                DeviceKind::Tracker,
                FaultKind::BeamBroken,
                "FindReflector returned, but no reflector is locked",
            ))
        }
    }

    /// Cancel-safe: the new client is stored only once set up, so a drop leaves no connection.
    async fn reconnect(&mut self) -> Result<(), CellError> {
        if let Some(c) = self.client.take() {
            c.close().await;
        }
        self.connect_and_setup().await
    }

    /// GetSystemStatus and GetMeasurementStatusInfo on the open connection (or a new one,
    /// kept): nothing that moves the head. Cancel-safe: the client is taken out meanwhile, so a
    /// drop closes the connection.
    async fn check(&mut self) -> Result<String, CellError> {
        let client = match self.client.take() {
            Some(c) if c.is_connected() => c,
            old => {
                if let Some(c) = old {
                    c.close().await;
                }
                Client::connect(self.cfg.address.as_str(), self.cfg.client_config())
                    .await
                    .map_err(cell_err)?
            }
        };
        let status = client.system_status().await.map_err(cell_err)?;
        let found = client.measurement_status().await.map_err(cell_err)?;
        self.client = Some(client);
        let identity = status_identity(&status);
        self.identity = Some(identity.clone());
        let init = if status.is_initialized() {
            "initialised"
        } else {
            "not initialised (arming initialises it: the head moves)"
        };
        let reflector = if found.reflector_found() {
            "reflector locked"
        } else {
            "no reflector locked (put the ball in the beam before arming)"
        };
        let wanted = emscon::SystemSettings::default().weather_monitor_status;
        let weather = if status.weather_monitor_status == wanted {
            format!("weather station on (status {wanted}: T, P, H read, refraction computed)")
        } else {
            format!(
                "weather monitor status {} (arming sets {wanted}: T, P, H read, refraction \
                 computed)",
                status.weather_monitor_status
            )
        };
        Ok(format!("{identity}; {init}; {reflector}; {weather}"))
    }

    fn identity(&self) -> Option<String> {
        self.identity.clone()
    }
}
