//! [`ZaberStageAdapter`]: the [`Stage`] trait over a Zaber ASCII stage on a serial port
//! (`drivers/zaber`). Millimetres in the trait; microsteps only inside the driver.

use std::time::Duration;

use async_trait::async_trait;
use serde::{Deserialize, Serialize};
use tokio_serial::SerialStream;
use tracing::{info, warn};
use zaber::{StageConfig, StageError, ZaberStage};

use super::{CellError, DeviceKind, FaultKind, Stage};
use crate::config::StageSection;

/// Configuration of a [`ZaberStageAdapter`] (serde: every field has a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZaberStageAdapterConfig {
    /// Serial port (`/dev/ttyUSB0`, or a pty slave such as `/dev/pts/3`).
    pub port: String,
    /// Device address on the daisy chain.
    pub device: u8,
    /// Axis number.
    pub axis: u8,
    /// Expected microsteps per millimetre: `None` (default) takes the device's, derived from
    /// its `device.id`/`peripheral.id`/`resolution` (`zaber::product`); `Some` is a cross-check
    /// refused on a mismatch, or the scale of a product the table does not know.
    pub microsteps_per_mm: Option<f64>,
    /// Lowest allowed target (mm).
    pub min_mm: f64,
    /// Highest allowed target (mm).
    pub max_mm: f64,
    /// Allowed |read-back − target| after a move (mm).
    pub tolerance_mm: f64,
    /// Home the axis in `prepare` (which always clears latched warnings first).
    pub home_on_prepare: bool,
    /// Timeout of one reply (ms).
    pub reply_timeout_ms: u64,
    /// Status poll period while a move runs (ms).
    pub poll_interval_ms: u64,
    /// Timeout of a move (ms).
    pub move_timeout_ms: u64,
    /// Timeout of homing (ms).
    pub home_timeout_ms: u64,
    /// Baud rate (Zaber ASCII default 115200).
    pub baud: u32,
}

impl Default for ZaberStageAdapterConfig {
    fn default() -> Self {
        let d = StageConfig::default();
        ZaberStageAdapterConfig {
            port: "/dev/ttyUSB0".into(),
            device: d.device,
            axis: d.axis,
            microsteps_per_mm: d.microsteps_per_mm,
            min_mm: d.min_mm,
            max_mm: d.max_mm,
            tolerance_mm: d.tolerance_mm,
            home_on_prepare: true,
            reply_timeout_ms: 500,
            poll_interval_ms: 20,
            move_timeout_ms: 30_000,
            home_timeout_ms: 60_000,
            baud: d.baud,
        }
    }
}

impl ZaberStageAdapterConfig {
    /// These settings (the port, the device's default timings and scale) with every setting
    /// `[stage]` gives: the one place the section reaches the adapter (range, tolerance, Zaber
    /// address, baud, homing; a configured scale replaces the default one).
    pub fn with_section(self, s: &StageSection) -> ZaberStageAdapterConfig {
        ZaberStageAdapterConfig {
            device: s.device_address,
            axis: s.axis_number,
            microsteps_per_mm: s.microsteps_per_mm.or(self.microsteps_per_mm),
            min_mm: s.range_mm[0],
            max_mm: s.range_mm[1],
            tolerance_mm: s.tolerance_mm,
            home_on_prepare: s.home_on_prepare,
            reply_timeout_ms: s.reply_timeout_ms.unwrap_or(self.reply_timeout_ms),
            poll_interval_ms: s.poll_interval_ms.unwrap_or(self.poll_interval_ms),
            move_timeout_ms: s.move_timeout_ms.unwrap_or(self.move_timeout_ms),
            home_timeout_ms: s.home_timeout_ms.unwrap_or(self.home_timeout_ms),
            baud: s.baud,
            port: self.port,
        }
    }

    /// The driver's stage configuration.
    pub fn stage_config(&self) -> StageConfig {
        StageConfig {
            device: self.device,
            axis: self.axis,
            microsteps_per_mm: self.microsteps_per_mm,
            min_mm: self.min_mm,
            max_mm: self.max_mm,
            tolerance_mm: self.tolerance_mm,
            reply_timeout: Duration::from_millis(self.reply_timeout_ms),
            poll_interval: Duration::from_millis(self.poll_interval_ms.max(1)),
            move_timeout: Duration::from_millis(self.move_timeout_ms),
            home_timeout: Duration::from_millis(self.home_timeout_ms),
            baud: self.baud,
            ..StageConfig::default()
        }
    }
}

/// Classify a driver error for the campaign.
pub fn classify_zaber(e: &StageError) -> FaultKind {
    match e {
        StageError::NotHomed | StageError::Rejected(_) | StageError::OutOfRange(_) => {
            FaultKind::Rejected
        }
        StageError::Fault(_)
        | StageError::Interrupted
        | StageError::Mismatch { .. }
        | StageError::UnexpectedLimit
        | StageError::Displaced
        | StageError::UnknownProduct { .. }
        | StageError::ScaleMismatch { .. }
        | StageError::InvalidConfig(_) => FaultKind::Device,
        StageError::Timeout(_) => FaultKind::Timeout,
        StageError::Checksum | StageError::Protocol(_) => FaultKind::Protocol,
        StageError::Disconnected | StageError::Io(_) => FaultKind::Disconnected,
    }
}

fn cell_err(e: StageError) -> CellError {
    CellError::new(DeviceKind::Stage, classify_zaber(&e), e.to_string())
}

/// A motorised Zaber stage on a serial port.
#[derive(Debug)]
pub struct ZaberStageAdapter {
    cfg: ZaberStageAdapterConfig,
    stage: Option<ZaberStage<SerialStream>>,
    /// From the last `identify`.
    identity: Option<String>,
}

impl ZaberStageAdapter {
    /// A stage adapter; the port is opened in [`Stage::prepare`].
    pub fn new(cfg: ZaberStageAdapterConfig) -> ZaberStageAdapter {
        ZaberStageAdapter {
            cfg,
            stage: None,
            identity: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ZaberStageAdapterConfig {
        &self.cfg
    }

    /// Close the port; the next `prepare` opens it again (e.g. after a USB re-enumeration).
    pub fn close(&mut self) {
        self.stage = None;
    }

    fn open(&mut self) -> Result<&mut ZaberStage<SerialStream>, CellError> {
        if self.stage.is_none() {
            let s = ZaberStage::open(&self.cfg.port, self.cfg.stage_config()).map_err(cell_err)?;
            info!(port = %self.cfg.port, "stage port open");
            self.stage = Some(s);
        }
        self.stage.as_mut().ok_or_else(|| {
            CellError::new(DeviceKind::Stage, FaultKind::Disconnected, "port not open")
        })
    }

    fn after(&mut self, e: StageError) -> CellError {
        let err = cell_err(e);
        if err.kind == FaultKind::Disconnected {
            warn!("stage port lost; it is reopened on the next prepare");
            self.stage = None;
        }
        err
    }
}

#[async_trait]
impl Stage for ZaberStageAdapter {
    fn is_manual(&self) -> bool {
        false
    }

    /// Open the port, clear stale warnings, identify the device (scale, cross-check) and home.
    /// Cancel-safe for the protocol (the driver drains a late reply); a drop may leave homing
    /// under way.
    async fn prepare(&mut self) -> Result<(), CellError> {
        let home = self.cfg.home_on_prepare;
        let stage = self.open()?;
        // Clear latched flags first (stale ones from before this session; homing re-references
        // the axis), then read the device's identity and scale.
        let r = stage.clear_warnings().await;
        let cleared = r.map_err(|e| self.after(e))?;
        if !cleared.is_empty() {
            warn!(?cleared, "stage warnings cleared at prepare");
        }
        let stage = self.open()?;
        let r = stage.identify().await;
        let id = r.map_err(|e| self.after(e))?;
        info!(
            device_id = id.device_id,
            peripheral_id = id.peripheral_id,
            serial = id.serial,
            firmware = %id.firmware,
            resolution = id.resolution,
            microsteps_per_mm = id.microsteps_per_mm,
            product = id.product.unwrap_or("(configured scale)"),
            "stage identified"
        );
        self.identity = Some(identity_text(&id));
        let stage = self.open()?;
        if home {
            let r = stage.home().await;
            r.map_err(|e| self.after(e))?;
        }
        Ok(())
    }

    /// Move and read back; WL/WM/F* are `FaultKind::Device` (the campaign pauses).
    /// Cancel-safe for the protocol; a drop may leave the move under way.
    async fn move_to(&mut self, position_mm: f64) -> Result<f64, CellError> {
        let stage = self.open()?;
        let r = stage.move_abs_mm(position_mm).await;
        r.map_err(|e| self.after(e))
    }

    /// The driver's `stop` (decelerate), then idle. Cancel-safe for the protocol (the driver
    /// drains a late reply, also of a dropped move); a drop may leave the axis decelerating.
    async fn stop(&mut self) -> Result<(), CellError> {
        let Some(stage) = self.stage.as_mut() else {
            return Err(CellError::new(
                DeviceKind::Stage,
                FaultKind::Disconnected,
                "not connected",
            ));
        };
        let r = stage.stop().await;
        r.map_err(|e| self.after(e))
    }

    /// Open the port, identify the device (its scale cross-checked as at prepare) and read its
    /// position and warning flags: no homing, no move, no warning cleared. Cancel-safe for the
    /// protocol.
    async fn check(&mut self) -> Result<String, CellError> {
        let stage = self.open()?;
        let r = stage.identify().await;
        let id = r.map_err(|e| self.after(e))?;
        let stage = self.open()?;
        let r = stage.command("get pos").await;
        let reply = r.map_err(|e| self.after(e))?;
        let steps: i64 = reply.data.trim().parse().map_err(|_| {
            CellError::new(
                DeviceKind::Stage,
                FaultKind::Protocol,
                format!("get pos: not a position: {:?}", reply.data),
            )
        })?;
        let identity = identity_text(&id);
        self.identity = Some(identity.clone());
        let flags = match reply.warning.as_str() {
            "--" => "no warning".to_owned(),
            "WR" => "not homed (arming homes it: the stage moves)".to_owned(),
            w => format!("warning flag {w}"),
        };
        Ok(format!(
            "{identity}; {:.3} microsteps/mm; at {:.3} mm; {flags}",
            id.microsteps_per_mm,
            steps as f64 / id.microsteps_per_mm
        ))
    }

    fn identity(&self) -> Option<String> {
        self.identity.clone()
    }
}

/// What the stage says it is, as the `devices` event and the report show it.
fn identity_text(id: &zaber::StageIdentity) -> String {
    format!(
        "Zaber {} (device.id {}, peripheral.id {}), serial {}, firmware {}",
        id.product.unwrap_or("stage of configured scale"),
        id.device_id,
        id.peripheral_id,
        id.serial,
        id.firmware
    )
}
