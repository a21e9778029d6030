//! Generic RS-232 gauge (digital micrometer / indicator): request/response ASCII readings.
//!
//! Accepted reply lines (terminated by `\r` and/or `\n`):
//! * signed reading, optional unit: `+10.0012`, `-0.0035 mm`, `+0.3937 in` (inch → error)
//! * Mitutoyo-style data: `01A+00012.345`
//! * status line: anything starting with `9` (Mitutoyo status) → [`GaugeError::DeviceStatus`]
//!
//! Readings must carry a sign (or the `01A` prefix), so a status line is never mistaken for one.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tracing::trace;

use crate::lineio::{gauge_lines, read_line, LineRead, LineReader};
use crate::serial::SerialSettings;

/// Longest accepted gauge line.
pub const MAX_GAUGE_LINE: usize = 64;

/// Typed gauge error.
#[derive(Debug, thiserror::Error)]
pub enum GaugeError {
    /// No reply in time.
    #[error("gauge did not reply in time")]
    Timeout,
    /// The reading is in another unit (e.g. inch).
    #[error("gauge reports unit {0:?}, expected mm")]
    WrongUnit(String),
    /// Reading outside the configured range (mm).
    #[error("reading {0} mm outside the configured range")]
    OutOfRange(f64),
    /// The gauge sent a status line instead of a reading.
    #[error("gauge status: {0}")]
    DeviceStatus(String),
    /// Unparseable reply.
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The port is closed.
    #[error("disconnected")]
    Disconnected,
    /// I/O error.
    #[error("i/o error: {0}")]
    Io(std::io::Error),
}

/// The message prints the I/O error, so it is not also the `source()` (printed with its
/// causes, it would appear twice).
impl From<std::io::Error> for GaugeError {
    fn from(cause: std::io::Error) -> Self {
        GaugeError::Io(cause)
    }
}

/// Gauge configuration.
#[derive(Debug, Clone)]
pub struct GaugeConfig {
    /// Bytes sent to request one reading (Sylvac `?\r`, Mitutoyo USB-ITN `1\r`).
    pub request: String,
    /// Reply timeout.
    pub reply_timeout: Duration,
    /// Lowest plausible reading in mm.
    pub min_mm: f64,
    /// Highest plausible reading in mm.
    pub max_mm: f64,
    /// Serial settings used by [`GaugeClient::open`].
    pub serial: SerialSettings,
}

impl Default for GaugeConfig {
    fn default() -> Self {
        Self {
            request: "?\r".into(),
            reply_timeout: Duration::from_millis(500),
            min_mm: -50.0,
            max_mm: 50.0,
            serial: SerialSettings::sylvac(),
        }
    }
}

/// A parsed reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Value in millimetres.
    pub value_mm: f64,
}

/// Parse one gauge line into a reading in mm (no range check).
pub fn parse_reading(line: &str) -> Result<Reading, GaugeError> {
    let s = line.trim_matches(|c: char| c == '\r' || c == '\n' || c == ' ');
    if s.is_empty() {
        return Err(GaugeError::Protocol("empty line".into()));
    }
    if !s.bytes().all(|b| (0x20..0x7f).contains(&b)) {
        return Err(GaugeError::Protocol("non-printable characters".into()));
    }
    if s.starts_with('9') {
        return Err(GaugeError::DeviceStatus(s.to_string()));
    }
    let s = s.strip_prefix("01A").unwrap_or(s);
    let mut parts = s.split_whitespace();
    let num = parts.next().unwrap_or("");
    let unit = parts.next();
    if parts.next().is_some() {
        return Err(GaugeError::Protocol(format!("unexpected fields in {s:?}")));
    }
    if !num.starts_with(['+', '-']) {
        return Err(GaugeError::Protocol(format!(
            "reading without sign: {num:?}"
        )));
    }
    // Unit glued to the number, e.g. "+1.0000mm" or "+0.0394in".
    let split = num
        .char_indices()
        .find(|(i, c)| *i > 0 && c.is_ascii_alphabetic())
        .map(|(i, _)| i);
    let (num, glued) = match split {
        Some(i) => (&num[..i], Some(&num[i..])),
        None => (num, None),
    };
    if glued.is_some_and(|u| !u.bytes().all(|b| b.is_ascii_alphabetic())) {
        return Err(GaugeError::Protocol(format!("not a number: {num:?}")));
    }
    if glued.is_some() && unit.is_some() {
        return Err(GaugeError::Protocol(format!("two units in {s:?}")));
    }
    match glued.or(unit) {
        None | Some("mm") | Some("MM") => {}
        Some(u) => return Err(GaugeError::WrongUnit(u.to_string())),
    }
    let body = num
        .strip_prefix(['+', '-'])
        .ok_or_else(|| GaugeError::Protocol(format!("reading without sign: {num:?}")))?;
    let digits_ok = !body.is_empty()
        && body.len() <= 16
        && body.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        && body.bytes().filter(|b| *b == b'.').count() <= 1
        && body.bytes().any(|b| b.is_ascii_digit());
    if !digits_ok {
        return Err(GaugeError::Protocol(format!("not a number: {num:?}")));
    }
    let v: f64 = num
        .parse()
        .map_err(|_| GaugeError::Protocol(format!("not a number: {num:?}")))?;
    Ok(Reading { value_mm: v })
}

/// Request/response gauge client over any byte stream.
#[derive(Debug)]
pub struct GaugeClient<S> {
    io: Option<LineReader<BufReader<S>>>,
    cfg: GaugeConfig,
    dirty: bool,
}

impl GaugeClient<tokio_serial::SerialStream> {
    /// Open the gauge's serial port with `cfg.serial` settings.
    pub fn open(path: &str, cfg: GaugeConfig) -> Result<Self, GaugeError> {
        let port = crate::serial::open_port(path, &cfg.serial)?;
        Ok(Self::from_stream(port, cfg))
    }
}

impl<S: AsyncRead + AsyncWrite + Unpin + Send> GaugeClient<S> {
    /// Wrap an open stream.
    pub fn from_stream(stream: S, cfg: GaugeConfig) -> Self {
        Self {
            io: Some(gauge_lines(BufReader::new(stream), MAX_GAUGE_LINE)),
            cfg,
            dirty: false,
        }
    }

    /// Request one reading and return it in mm (unit and range checked).
    /// Cancel-safe: a call dropped after its request went out leaves the client dirty, so the
    /// next call first discards the late reading already received instead of taking it for its
    /// own (a reading later than the 5 ms drain still could be: a device has no request ids).
    pub async fn read_mm(&mut self) -> Result<f64, GaugeError> {
        let io = self.io.as_mut().ok_or(GaugeError::Disconnected)?;
        if self.dirty {
            // A late reply to an earlier request must not be taken for this one, nor its start
            // kept by the reader from a cancelled read.
            io.discard_partial();
            let raw = io.get_mut();
            while let Ok(Ok(buf)) =
                tokio::time::timeout(Duration::from_millis(5), raw.fill_buf()).await
            {
                if buf.is_empty() {
                    break;
                }
                let n = buf.len();
                raw.consume(n);
            }
            self.dirty = false;
        }
        let t = self.cfg.reply_timeout;
        let req = self.cfg.request.as_bytes();
        // Until this request's line is read, a drop leaves its reply to come: drain it next time.
        self.dirty = true;
        let res = tokio::time::timeout(t, async {
            io.get_mut().get_mut().write_all(req).await?;
            io.get_mut().get_mut().flush().await?;
            loop {
                match read_line(io).await? {
                    LineRead::Line(l) if l.trim().is_empty() => continue,
                    other => return Ok::<_, std::io::Error>(other),
                }
            }
        })
        .await;
        let line = match res {
            Err(_) => {
                self.dirty = true;
                return Err(GaugeError::Timeout);
            }
            Ok(Err(e)) => {
                self.io = None;
                return Err(GaugeError::Io(e));
            }
            Ok(Ok(LineRead::Eof)) => {
                self.io = None;
                return Err(GaugeError::Disconnected);
            }
            Ok(Ok(LineRead::Bad(why))) => {
                self.dirty = true;
                return Err(GaugeError::Protocol(why));
            }
            Ok(Ok(LineRead::Line(l))) => {
                self.dirty = false;
                l
            }
        };
        trace!(line = line.as_str(), "gauge recv");
        let r = parse_reading(&line)?;
        if r.value_mm < self.cfg.min_mm || r.value_mm > self.cfg.max_mm {
            return Err(GaugeError::OutOfRange(r.value_mm));
        }
        Ok(r.value_mm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readings() {
        assert_eq!(parse_reading("+10.0012\r").unwrap().value_mm, 10.0012);
        assert_eq!(parse_reading("-0.0035 mm").unwrap().value_mm, -0.0035);
        assert_eq!(parse_reading("01A+00012.345").unwrap().value_mm, 12.345);
        assert_eq!(parse_reading("+1.5mm").unwrap().value_mm, 1.5);
        assert!(matches!(
            parse_reading("+0.3937 in"),
            Err(GaugeError::WrongUnit(_))
        ));
        assert!(matches!(
            parse_reading("+0.3937inch"),
            Err(GaugeError::WrongUnit(_))
        ));
        assert!(matches!(
            parse_reading("91"),
            Err(GaugeError::DeviceStatus(_))
        ));
        assert!(matches!(
            parse_reading("10.0"),
            Err(GaugeError::Protocol(_))
        ));
        assert!(matches!(
            parse_reading("+1.2.3"),
            Err(GaugeError::Protocol(_))
        ));
        assert!(matches!(parse_reading("+"), Err(GaugeError::Protocol(_))));
        assert!(matches!(
            parse_reading("+inf"),
            Err(GaugeError::WrongUnit(_)) | Err(GaugeError::Protocol(_))
        ));
    }
}
