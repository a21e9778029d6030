//! Async Zaber ASCII stage client.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::time::Instant;
use tracing::{debug, trace, warn};

use crate::ascii::{
    format_command, parse_message, parse_steps, CodecError, Command, Message, Reply, ReplyFlag,
    Status, Warning, WarningClass,
};
use crate::lineio::{read_line, LineRead};

/// Typed stage error.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    /// The axis has no reference position (`WR`): home first.
    #[error("stage not homed")]
    NotHomed,
    /// The device rejected the command (`RJ`), with its reason (`BADCOMMAND`, `BADDATA`, ...).
    #[error("command rejected: {0}")]
    Rejected(String),
    /// A fault flag (`F*`) was reported.
    #[error("stage fault {0}")]
    Fault(String),
    /// The movement was interrupted (`NI`).
    #[error("movement interrupted")]
    Interrupted,
    /// No (complete) reply, or not idle, in time.
    #[error("timeout: {0}")]
    Timeout(&'static str),
    /// Requested position outside the configured travel.
    #[error("position {0} mm outside travel")]
    OutOfRange(f64),
    /// Read-back after a move differs from the target by more than the tolerance.
    #[error("read-back {readback_mm} mm differs from target {target_mm} mm")]
    Mismatch {
        /// Commanded target.
        target_mm: f64,
        /// Position read back.
        readback_mm: f64,
    },
    /// A reply failed its checksum.
    #[error("reply checksum mismatch")]
    Checksum,
    /// Malformed or unexpected reply.
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The port is closed.
    #[error("disconnected")]
    Disconnected,
    /// I/O error (opening or using the port).
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}

/// Stage configuration.
#[derive(Debug, Clone)]
pub struct StageConfig {
    /// Device address (1-based on the daisy chain).
    pub device: u8,
    /// Axis number (1 for a single-axis device).
    pub axis: u8,
    /// Microsteps per millimetre (device-specific; e.g. 1 / 0.000047625 mm for many LSM stages).
    pub microsteps_per_mm: f64,
    /// Lowest allowed target in mm.
    pub min_mm: f64,
    /// Highest allowed target in mm.
    pub max_mm: f64,
    /// Allowed |read-back − target| after a move, mm.
    pub tolerance_mm: f64,
    /// Timeout for a single reply.
    pub reply_timeout: Duration,
    /// Status poll period in `poll_until_idle`.
    pub poll_interval: Duration,
    /// Timeout for a move to finish.
    pub move_timeout: Duration,
    /// Timeout for homing to finish.
    pub home_timeout: Duration,
    /// Append `:XX` checksums to commands.
    pub send_checksum: bool,
    /// Baud rate used by [`ZaberStage::open`] (ASCII default 115200).
    pub baud: u32,
}

impl Default for StageConfig {
    fn default() -> Self {
        Self {
            device: 1,
            axis: 1,
            microsteps_per_mm: 1.0 / 0.000_047_625,
            min_mm: 0.0,
            max_mm: 100.0,
            tolerance_mm: 0.001,
            reply_timeout: Duration::from_millis(500),
            poll_interval: Duration::from_millis(20),
            move_timeout: Duration::from_secs(30),
            home_timeout: Duration::from_secs(60),
            send_checksum: true,
            baud: 115_200,
        }
    }
}

/// Zaber ASCII stage client over any byte stream (serial port, pty, in-memory pipe).
#[derive(Debug)]
pub struct ZaberStage<S> {
    io: Option<BufReader<S>>,
    cfg: StageConfig,
    next_id: u8,
    /// Set after a timeout or bad line: discard stale input before the next command.
    dirty: bool,
}

impl ZaberStage<tokio_serial::SerialStream> {
    /// Open a serial port at `cfg.baud` 8N1, no flow control.
    pub fn open(path: &str, cfg: StageConfig) -> Result<Self, StageError> {
        let port = crate::serial::open_port(path, &crate::serial::SerialSettings::zaber(cfg.baud))?;
        Ok(Self::from_stream(port, cfg))
    }
}

impl<S: AsyncRead + AsyncWrite + Unpin + Send> ZaberStage<S> {
    /// Wrap an open stream.
    pub fn from_stream(stream: S, cfg: StageConfig) -> Self {
        Self {
            io: Some(BufReader::new(stream)),
            cfg,
            next_id: 0,
            dirty: false,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &StageConfig {
        &self.cfg
    }

    /// Convert millimetres to microsteps (rounded).
    pub fn mm_to_steps(&self, mm: f64) -> i64 {
        (mm * self.cfg.microsteps_per_mm).round() as i64
    }

    /// Convert microsteps to millimetres.
    pub fn steps_to_mm(&self, steps: i64) -> f64 {
        steps as f64 / self.cfg.microsteps_per_mm
    }

    /// Discard bytes already received (partial or stale lines) after an error.
    async fn discard_input(&mut self) {
        let Some(io) = self.io.as_mut() else { return };
        loop {
            match tokio::time::timeout(Duration::from_millis(5), io.fill_buf()).await {
                Ok(Ok(buf)) if !buf.is_empty() => {
                    let n = buf.len();
                    debug!(n, "zaber: discarding stale input");
                    io.consume(n);
                }
                _ => break,
            }
        }
    }

    /// Send one command to the configured device/axis and return its reply (warnings unchecked).
    pub async fn command(&mut self, text: &str) -> Result<Reply, StageError> {
        if self.dirty {
            self.discard_input().await;
            self.dirty = false;
        }
        let r = self.command_inner(text).await;
        if matches!(
            r,
            Err(StageError::Timeout(_)) | Err(StageError::Protocol(_)) | Err(StageError::Checksum)
        ) {
            self.dirty = true;
        }
        r
    }

    async fn command_inner(&mut self, text: &str) -> Result<Reply, StageError> {
        let id = self.next_id;
        self.next_id = (self.next_id + 1) % 100;
        let line = format_command(
            &Command {
                device: self.cfg.device,
                axis: self.cfg.axis,
                id: Some(id),
                text: text.to_string(),
            },
            self.cfg.send_checksum,
        );
        let io = self.io.as_mut().ok_or(StageError::Disconnected)?;
        trace!(line = line.trim_end(), "zaber send");
        let write = async {
            io.get_mut().write_all(line.as_bytes()).await?;
            io.get_mut().flush().await
        };
        match tokio::time::timeout(self.cfg.reply_timeout, write).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                self.io = None;
                return Err(StageError::Io(e));
            }
            Err(_) => return Err(StageError::Timeout("write")),
        }
        let deadline = Instant::now() + self.cfg.reply_timeout;
        loop {
            let io = self.io.as_mut().ok_or(StageError::Disconnected)?;
            let read =
                tokio::time::timeout_at(deadline, read_line(io, crate::ascii::MAX_LINE)).await;
            let raw = match read {
                Err(_) => return Err(StageError::Timeout("reply")),
                Ok(Err(e)) => {
                    self.io = None;
                    return Err(StageError::Io(e));
                }
                Ok(Ok(LineRead::Eof)) => {
                    self.io = None;
                    return Err(StageError::Disconnected);
                }
                Ok(Ok(LineRead::Bad(why))) => return Err(StageError::Protocol(why)),
                Ok(Ok(LineRead::Line(l))) => l,
            };
            trace!(line = raw.as_str(), "zaber recv");
            if raw.trim().is_empty() {
                continue;
            }
            match parse_message(&raw) {
                Err(CodecError::Checksum { .. }) => return Err(StageError::Checksum),
                Err(e) => return Err(StageError::Protocol(format!("{e} in {raw:?}"))),
                Ok(Message::Info { text, .. }) => debug!(text, "zaber info"),
                Ok(Message::Alert { warning, .. }) => debug!(%warning, "zaber alert"),
                Ok(Message::Reply(r)) => {
                    if r.device != self.cfg.device || r.axis != self.cfg.axis || r.id != Some(id) {
                        // Stale reply (e.g. to a command that timed out) or another device.
                        debug!(?r, "skipping reply that does not match the command");
                        continue;
                    }
                    return Ok(r);
                }
            }
        }
    }

    /// Send a command and check the reply: RJ → Rejected (WR → NotHomed), F* → Fault.
    async fn checked(&mut self, text: &str) -> Result<Reply, StageError> {
        let r = self.command(text).await?;
        if r.warning.class() == WarningClass::Fault {
            return Err(StageError::Fault(r.warning.to_string()));
        }
        if r.flag == ReplyFlag::Rejected {
            if r.warning == Warning::WR {
                return Err(StageError::NotHomed);
            }
            return Err(StageError::Rejected(r.data));
        }
        Ok(r)
    }

    /// Check a status reply's warning flag during motion.
    fn check_motion_flags(r: &Reply) -> Result<(), StageError> {
        match r.warning.class() {
            WarningClass::Fault => Err(StageError::Fault(r.warning.to_string())),
            _ if r.warning == Warning::WR => Err(StageError::NotHomed),
            _ if r.warning == Warning::NI => Err(StageError::Interrupted),
            WarningClass::Warning | WarningClass::Notice | WarningClass::Other => {
                warn!(flag = %r.warning, "zaber warning flag ignored");
                Ok(())
            }
            WarningClass::None => Ok(()),
        }
    }

    /// Home the axis and wait until idle (`home_timeout`).
    pub async fn home(&mut self) -> Result<(), StageError> {
        self.checked("warnings clear").await?;
        self.checked("home").await?;
        let t = self.cfg.home_timeout;
        self.poll_until_idle(t).await
    }

    /// Start an absolute move to `mm` without waiting.
    pub async fn start_move_abs_mm(&mut self, mm: f64) -> Result<(), StageError> {
        if !mm.is_finite() || mm < self.cfg.min_mm || mm > self.cfg.max_mm {
            return Err(StageError::OutOfRange(mm));
        }
        self.checked("warnings clear").await?;
        let steps = self.mm_to_steps(mm);
        let r = self.checked(&format!("move abs {steps}")).await?;
        if r.warning == Warning::WR {
            return Err(StageError::NotHomed);
        }
        Ok(())
    }

    /// Move to `mm`, wait until idle (`move_timeout`), check read-back; returns the read-back mm.
    pub async fn move_abs_mm(&mut self, mm: f64) -> Result<f64, StageError> {
        self.start_move_abs_mm(mm).await?;
        let t = self.cfg.move_timeout;
        self.poll_until_idle(t).await?;
        let readback_mm = self.position_mm().await?;
        if (readback_mm - mm).abs() > self.cfg.tolerance_mm {
            return Err(StageError::Mismatch {
                target_mm: mm,
                readback_mm,
            });
        }
        Ok(readback_mm)
    }

    /// Poll status until IDLE, failing on fault / not-homed / interrupted flags or timeout.
    pub async fn poll_until_idle(&mut self, timeout: Duration) -> Result<(), StageError> {
        let deadline = Instant::now() + timeout;
        loop {
            let r = self.checked("").await?;
            Self::check_motion_flags(&r)?;
            if r.status == Status::Idle {
                return Ok(());
            }
            if Instant::now() + self.cfg.poll_interval > deadline {
                return Err(StageError::Timeout("stage still busy"));
            }
            tokio::time::sleep(self.cfg.poll_interval).await;
        }
    }

    /// Current position in mm (`get pos`).
    pub async fn position_mm(&mut self) -> Result<f64, StageError> {
        let r = self.checked("get pos").await?;
        let steps = parse_steps(&r.data).map_err(|e| StageError::Protocol(e.to_string()))?;
        Ok(self.steps_to_mm(steps))
    }

    /// Stop the axis (decelerate) and wait briefly until idle; the NI notice is expected.
    pub async fn stop(&mut self) -> Result<(), StageError> {
        self.checked("stop").await?;
        let deadline = Instant::now() + self.cfg.reply_timeout * 4;
        loop {
            let r = self.checked("").await?;
            if r.warning.class() == WarningClass::Fault {
                return Err(StageError::Fault(r.warning.to_string()));
            }
            if r.status == Status::Idle {
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(StageError::Timeout("stage did not stop"));
            }
            tokio::time::sleep(self.cfg.poll_interval).await;
        }
    }
}
