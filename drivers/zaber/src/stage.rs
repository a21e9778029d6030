//! Async Zaber ASCII stage client.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::time::Instant;
use tracing::{debug, trace, warn};

use crate::ascii::{
    format_command, parse_message, parse_steps, CodecError, Command, Message, Reply, ReplyFlag,
    Status, Warning, WarningClass,
};
use crate::lineio::{ascii_lines, read_line, LineRead, LineReader};
use crate::product;

/// DEL: a Zaber device discards the incomplete command it is receiving (ASCII protocol,
/// "Delete"); sent before a command when the previous line may have been cut short.
pub const DISCARD_PARTIAL: u8 = 0x7f;

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
    Io(std::io::Error),
    /// The axis stopped on a limit sensor it did not expect (`WL`): a stage fault.
    #[error("unexpected limit trigger (WL): the axis stopped on a limit sensor")]
    UnexpectedLimit,
    /// The idle axis was pushed off its position (`WM`): a stage fault.
    #[error("axis displaced while stationary (WM)")]
    Displaced,
    /// The device's identity is not in [`crate::product::KNOWN_PRODUCTS`] and no
    /// `microsteps_per_mm` is configured, so mm cannot be converted to microsteps.
    #[error(
        "unknown stage product (device.id {device_id}, peripheral.id {peripheral_id}): \
         add it to zaber::product or configure microsteps_per_mm"
    )]
    UnknownProduct {
        /// `device.id` read from the device.
        device_id: u32,
        /// `peripheral.id` read from the axis.
        peripheral_id: u32,
    },
    /// The configured `microsteps_per_mm` disagrees with the one the device's facts give.
    #[error(
        "configured microsteps_per_mm {configured} disagrees with the device: {product} at \
         resolution {resolution} has {device} microsteps per mm"
    )]
    ScaleMismatch {
        /// Configured value.
        configured: f64,
        /// Value derived from the device.
        device: f64,
        /// Product name from the table.
        product: &'static str,
        /// Microsteps per full step read from the device.
        resolution: u32,
    },
    /// A configuration value is unusable (e.g. a non-positive or NaN microsteps_per_mm).
    #[error("invalid stage configuration: {0}")]
    InvalidConfig(String),
}

/// The message prints the I/O error, so it is not also the `source()` (printed with its
/// causes, it would appear twice).
impl From<std::io::Error> for StageError {
    fn from(cause: std::io::Error) -> Self {
        StageError::Io(cause)
    }
}

/// Largest accepted relative difference between a configured `microsteps_per_mm` and the
/// device's (1e-4: 5 µm over 50 mm of travel).
pub const SCALE_REL_TOLERANCE: f64 = 1e-4;

/// What the device said about itself at [`ZaberStage::identify`], and the scale derived.
#[derive(Debug, Clone, PartialEq)]
pub struct StageIdentity {
    /// `device.id`.
    pub device_id: u32,
    /// `peripheral.id` of the axis.
    pub peripheral_id: u32,
    /// `system.serial`.
    pub serial: u32,
    /// `version` (firmware `major.minor`).
    pub firmware: String,
    /// `resolution`: microsteps per full step.
    pub resolution: u32,
    /// Microsteps per mm in use.
    pub microsteps_per_mm: f64,
    /// Product from the table; `None` when the scale came from the configuration.
    pub product: Option<&'static str>,
}

/// Microsteps per mm from the device's identity and resolution, cross-checked against a
/// configured value (see [`crate::product`]); returns the scale and the product name.
pub fn resolve_scale(
    device_id: u32,
    peripheral_id: u32,
    resolution: u32,
    configured: Option<f64>,
) -> Result<(f64, Option<&'static str>), StageError> {
    if let Some(c) = configured {
        if !(c.is_finite() && c > 0.0) {
            return Err(StageError::InvalidConfig(format!(
                "microsteps_per_mm must be a positive number, got {c}"
            )));
        }
    }
    if resolution == 0 {
        return Err(StageError::Protocol("device reports resolution 0".into()));
    }
    match (product::lookup(device_id, peripheral_id), configured) {
        (Some(p), configured) => {
            let k = product::microsteps_per_mm(p, resolution);
            match configured {
                Some(c) if ((c - k) / k).abs() > SCALE_REL_TOLERANCE => {
                    Err(StageError::ScaleMismatch {
                        configured: c,
                        device: k,
                        product: p.name,
                        resolution,
                    })
                }
                _ => Ok((k, Some(p.name))),
            }
        }
        (None, Some(c)) => {
            warn!(
                device_id,
                peripheral_id, "unknown stage product: using the configured microsteps_per_mm"
            );
            Ok((c, None))
        }
        (None, None) => Err(StageError::UnknownProduct {
            device_id,
            peripheral_id,
        }),
    }
}

/// Flags listed in `warnings` / `warnings clear` data (`02 WR NI`); malformed tokens skipped.
pub fn parse_warning_list(data: &str) -> Vec<Warning> {
    data.split_whitespace()
        .skip(1)
        .filter_map(|t| Warning::parse(t).ok())
        .collect()
}

/// The stage fault among `flags`, most severe first: `F*`, then `WL`, then `WM`.
pub fn safety_error(flags: &[Warning]) -> Option<StageError> {
    if let Some(f) = flags.iter().find(|w| w.class() == WarningClass::Fault) {
        return Some(StageError::Fault(f.to_string()));
    }
    if flags.contains(&Warning::WL) {
        return Some(StageError::UnexpectedLimit);
    }
    flags
        .contains(&Warning::WM)
        .then_some(StageError::Displaced)
}

/// Stage configuration.
#[derive(Debug, Clone)]
pub struct StageConfig {
    /// Device address (1-based on the daisy chain).
    pub device: u8,
    /// Axis number (1 for a single-axis device).
    pub axis: u8,
    /// Expected microsteps per millimetre: `None` takes the device's (see [`crate::product`]);
    /// `Some` is a cross-check that [`ZaberStage::identify`] refuses on a mismatch beyond
    /// [`SCALE_REL_TOLERANCE`], or the scale itself for a product not in the table.
    pub microsteps_per_mm: Option<f64>,
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
            microsteps_per_mm: None,
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
    io: Option<LineReader<BufReader<S>>>,
    cfg: StageConfig,
    next_id: u8,
    /// Set while a command is in flight and after a timeout or bad line: discard stale input
    /// before the next command (so a dropped command future cannot desynchronise the line).
    dirty: bool,
    /// Set while a command line is being written: if the write was dropped (or timed out) part
    /// way, the next command is preceded by DEL, which makes the device discard the partial
    /// command instead of running it joined to the next one.
    cut: bool,
    /// Identity and scale, once [`ZaberStage::identify`] ran.
    ident: Option<StageIdentity>,
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
            io: Some(ascii_lines(BufReader::new(stream), crate::ascii::MAX_LINE)),
            cfg,
            next_id: 0,
            dirty: false,
            cut: false,
            ident: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &StageConfig {
        &self.cfg
    }

    /// The identity read by [`ZaberStage::identify`], if it ran.
    pub fn identity(&self) -> Option<&StageIdentity> {
        self.ident.as_ref()
    }

    /// Microsteps per mm in use (known once identified).
    pub fn microsteps_per_mm(&self) -> Option<f64> {
        self.ident.as_ref().map(|i| i.microsteps_per_mm)
    }

    /// Scale in use, identifying the device first if needed. Not cancel-safe on its own
    /// (see [`ZaberStage::command`] for why a drop never desynchronises).
    async fn scale(&mut self) -> Result<f64, StageError> {
        match &self.ident {
            Some(i) => Ok(i.microsteps_per_mm),
            None => Ok(self.identify().await?.microsteps_per_mm),
        }
    }

    /// Read `device.id`, `system.serial`, `version` (device scope, axis 0) and the axis's
    /// `peripheral.id` and `resolution`, derive microsteps per mm ([`resolve_scale`]) and keep
    /// them. Cancel-safe in the sense of [`ZaberStage::command`]: a drop leaves it unidentified.
    pub async fn identify(&mut self) -> Result<StageIdentity, StageError> {
        let axis = self.cfg.axis;
        let device_id = self.query_u32(0, "device.id").await?;
        let serial = self.query_u32(0, "system.serial").await?;
        let firmware = self.query(0, "version").await?;
        let peripheral_id = self.query_u32(axis, "peripheral.id").await?;
        let resolution = self.query_u32(axis, "resolution").await?;
        let (k, product) = resolve_scale(
            device_id,
            peripheral_id,
            resolution,
            self.cfg.microsteps_per_mm,
        )?;
        let ident = StageIdentity {
            device_id,
            peripheral_id,
            serial,
            firmware,
            resolution,
            microsteps_per_mm: k,
            product,
        };
        debug!(?ident, "zaber: identified");
        self.ident = Some(ident.clone());
        Ok(ident)
    }

    /// `get <name>` on `axis` (0 = device scope); the data, or `Rejected`.
    /// Cancel-safe like [`ZaberStage::command`].
    async fn query(&mut self, axis: u8, name: &str) -> Result<String, StageError> {
        let r = self.command_at(axis, &format!("get {name}")).await?;
        if r.flag == ReplyFlag::Rejected {
            return Err(StageError::Rejected(format!("get {name}: {}", r.data)));
        }
        Ok(r.data)
    }

    /// Cancel-safe like [`ZaberStage::command`].
    async fn query_u32(&mut self, axis: u8, name: &str) -> Result<u32, StageError> {
        let data = self.query(axis, name).await?;
        data.trim()
            .parse::<u32>()
            .map_err(|_| StageError::Protocol(format!("get {name}: not a count: {data:?}")))
    }

    /// Discard bytes already received (partial or stale lines, including the partial line the reader
    /// kept from a cancelled read) after an error.
    /// Cancel-safe: it only consumes bytes already received, and the stage stays dirty until a
    /// command completes.
    async fn discard_input(&mut self) {
        let Some(lines) = self.io.as_mut() else {
            return;
        };
        lines.discard_partial();
        let io = lines.get_mut();
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
    /// Cancel-safe: a dropped call leaves the client marked dirty, so the next command first
    /// drains any late reply, and replies are matched by message id; a line cut short by the
    /// drop is discarded on the device by a DEL before the next command.
    pub async fn command(&mut self, text: &str) -> Result<Reply, StageError> {
        let axis = self.cfg.axis;
        self.command_at(axis, text).await
    }

    /// Send one device-scope command (axis 0); the reply comes on axis 0. Cancel-safe like
    /// [`ZaberStage::command`].
    pub async fn device_command(&mut self, text: &str) -> Result<Reply, StageError> {
        self.command_at(0, text).await
    }

    /// Cancel-safe: it marks the stage dirty before the exchange, so a drop is repaired by the next
    /// command (see [`ZaberStage::command`]).
    async fn command_at(&mut self, axis: u8, text: &str) -> Result<Reply, StageError> {
        if self.dirty {
            self.discard_input().await;
        }
        self.dirty = true;
        let r = self.exchange(axis, text).await;
        self.dirty = matches!(
            r,
            Err(StageError::Timeout(_)) | Err(StageError::Protocol(_)) | Err(StageError::Checksum)
        );
        r
    }

    /// Not cancel-safe on its own: a drop mid-write leaves a partial line (`cut`, discarded with
    /// DEL next time) and a drop while reading leaves a late reply (`dirty`, set by
    /// [`ZaberStage::command_at`]).
    async fn exchange(&mut self, axis: u8, text: &str) -> Result<Reply, StageError> {
        let id = self.next_id;
        self.next_id = (self.next_id + 1) % 100;
        let line = format_command(
            &Command {
                device: self.cfg.device,
                axis,
                id: Some(id),
                text: text.to_string(),
            },
            self.cfg.send_checksum,
        );
        let io = self.io.as_mut().ok_or(StageError::Disconnected)?;
        trace!(line = line.trim_end(), "zaber send");
        let mut bytes = Vec::with_capacity(line.len() + 1);
        if self.cut {
            debug!("zaber: the last command line was cut short; discarding it with DEL");
            bytes.push(DISCARD_PARTIAL);
        }
        bytes.extend_from_slice(line.as_bytes());
        self.cut = true;
        let write = async {
            io.get_mut().get_mut().write_all(&bytes).await?;
            io.get_mut().get_mut().flush().await
        };
        match tokio::time::timeout(self.cfg.reply_timeout, write).await {
            Ok(Ok(())) => self.cut = false,
            Ok(Err(e)) => {
                self.io = None;
                return Err(StageError::Io(e));
            }
            Err(_) => return Err(StageError::Timeout("write")),
        }
        let deadline = Instant::now() + self.cfg.reply_timeout;
        loop {
            let io = self.io.as_mut().ok_or(StageError::Disconnected)?;
            let read = tokio::time::timeout_at(deadline, read_line(io)).await;
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
                    if r.device != self.cfg.device || r.axis != axis || r.id != Some(id) {
                        // Stale reply (e.g. to a command that timed out) or another device.
                        debug!(?r, "skipping reply that does not match the command");
                        continue;
                    }
                    return Ok(r);
                }
            }
        }
    }

    /// Send a command and check the reply: F* → Fault, WL → UnexpectedLimit, WM → Displaced,
    /// RJ → Rejected (WR → NotHomed).
    /// Cancel-safe like [`ZaberStage::command`].
    async fn checked(&mut self, text: &str) -> Result<Reply, StageError> {
        let r = self.command(text).await?;
        if let Some(e) = safety_error(&[r.warning]) {
            return Err(e);
        }
        if r.flag == ReplyFlag::Rejected {
            if r.warning == Warning::WR {
                return Err(StageError::NotHomed);
            }
            return Err(StageError::Rejected(r.data));
        }
        Ok(r)
    }

    /// `warnings clear`: the flags it cleared (WR stays until homed). Cancel-safe like
    /// [`ZaberStage::command`].
    pub async fn clear_warnings(&mut self) -> Result<Vec<Warning>, StageError> {
        let r = self.command("warnings clear").await?;
        if r.flag == ReplyFlag::Rejected {
            return Err(StageError::Rejected(r.data));
        }
        let mut flags = parse_warning_list(&r.data);
        if r.warning != Warning::NONE && !flags.contains(&r.warning) {
            flags.push(r.warning);
        }
        if !flags.is_empty() {
            debug!(?flags, "zaber: warnings cleared");
        }
        Ok(flags)
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

    /// Home the axis and wait until idle (`home_timeout`). A latched fault fails it; a latched
    /// WL/WM does not (homing re-references the axis). Not cancel-safe for the motion: a drop
    /// leaves the axis homing (the protocol stays in sync, see [`ZaberStage::command`]).
    pub async fn home(&mut self) -> Result<(), StageError> {
        let cleared = self.clear_warnings().await?;
        if let Some(f) = cleared.iter().find(|w| w.class() == WarningClass::Fault) {
            return Err(StageError::Fault(f.to_string()));
        }
        self.checked("home").await?;
        let t = self.cfg.home_timeout;
        self.poll_until_idle(t).await
    }

    /// Start an absolute move to `mm` without waiting. Latched F*/WL/WM flags are cleared and
    /// reported as an error instead of moving (reported once). Cancel-safe like
    /// [`ZaberStage::command`]; a drop may leave the move started.
    pub async fn start_move_abs_mm(&mut self, mm: f64) -> Result<(), StageError> {
        if !mm.is_finite() || mm < self.cfg.min_mm || mm > self.cfg.max_mm {
            return Err(StageError::OutOfRange(mm));
        }
        let k = self.scale().await?;
        let cleared = self.clear_warnings().await?;
        if let Some(e) = safety_error(&cleared) {
            return Err(e);
        }
        let steps = (mm * k).round() as i64;
        let r = self.checked(&format!("move abs {steps}")).await?;
        if r.warning == Warning::WR {
            return Err(StageError::NotHomed);
        }
        Ok(())
    }

    /// Move to `mm`, wait until idle (`move_timeout`), check read-back; returns the read-back mm.
    /// Cancel-safe like [`ZaberStage::start_move_abs_mm`].
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

    /// Poll status until IDLE, failing on fault / WL / WM / not-homed / interrupted flags or
    /// timeout. Cancel-safe like [`ZaberStage::command`].
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

    /// Current position in mm (`get pos`); fails on latched F*/WL/WM. Cancel-safe like
    /// [`ZaberStage::command`].
    pub async fn position_mm(&mut self) -> Result<f64, StageError> {
        let k = self.scale().await?;
        let r = self.checked("get pos").await?;
        let steps = parse_steps(&r.data).map_err(|e| StageError::Protocol(e.to_string()))?;
        Ok(steps as f64 / k)
    }

    /// Stop the axis (decelerate) and wait briefly until idle; the NI notice is expected and
    /// only F* faults fail it. Cancel-safe like [`ZaberStage::command`].
    pub async fn stop(&mut self) -> Result<(), StageError> {
        let r = self.command("stop").await?;
        if r.flag == ReplyFlag::Rejected {
            return Err(StageError::Rejected(r.data));
        }
        let deadline = Instant::now() + self.cfg.reply_timeout * 4;
        loop {
            let r = self.command("").await?;
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
