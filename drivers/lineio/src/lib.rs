//! Bounded, cancel-safe line reading shared by the drivers that speak line protocols
//! (robotlink over TCP, Zaber stage and gauge over serial/pty).
//!
//! [`LineReader`] keeps the bytes of a line it has consumed in itself, so a read dropped
//! part way (a reply timeout, a `select!` branch that lost) never loses or splits a line: the
//! next read goes on with the same line.

use tokio::io::{AsyncBufRead, AsyncBufReadExt};

/// Outcome of reading one line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LineRead {
    /// A complete line, without its terminator and one `\r` before it.
    Line(String),
    /// Clean end of stream before any byte of a new line.
    Eof,
    /// The line was too long or not UTF-8, or the stream ended in the middle of a line.
    Bad(String),
}

/// What a reader does with a line longer than its limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overlong {
    /// Report it as soon as the limit is passed; the stream is then no longer usable.
    Fail,
    /// Discard it up to its terminator, then report it; the next read starts on the next line.
    Skip,
}

/// Line reader that keeps a partial line across cancelled reads.
#[derive(Debug)]
pub struct LineReader<R> {
    inner: R,
    max: usize,
    terms: &'static [u8],
    overlong: Overlong,
    buf: Vec<u8>,
    too_long: bool,
}

impl<R: AsyncBufRead + Unpin> LineReader<R> {
    /// Reader of `\n`-terminated lines (`\r\n` accepted) refusing lines longer than `max` bytes
    /// (terminator excluded) with [`Overlong::Fail`].
    pub fn new(inner: R, max: usize) -> Self {
        Self {
            inner,
            max,
            terms: b"\n",
            overlong: Overlong::Fail,
            buf: Vec::new(),
            too_long: false,
        }
    }

    /// End a line at any byte of `terms` (e.g. `b"\r\n"`: either byte ends a line).
    pub fn terminators(mut self, terms: &'static [u8]) -> Self {
        self.terms = terms;
        self
    }

    /// Handle lines longer than the limit with `policy`.
    pub fn overlong(mut self, policy: Overlong) -> Self {
        self.overlong = policy;
        self
    }

    /// The wrapped reader (to write to a duplex stream).
    pub fn get_mut(&mut self) -> &mut R {
        &mut self.inner
    }

    /// Drop the partial line kept from cancelled reads (when resynchronising after an error).
    pub fn discard_partial(&mut self) {
        self.buf.clear();
        self.too_long = false;
    }

    /// Next line. Cancel-safe: bytes already consumed stay in `self` and a later call goes on
    /// with the same line, so a dropped call never loses or splits a line.
    pub async fn next_line(&mut self) -> std::io::Result<LineRead> {
        loop {
            let chunk = self.inner.fill_buf().await?;
            if chunk.is_empty() {
                return Ok(if self.buf.is_empty() && !self.too_long {
                    LineRead::Eof
                } else {
                    self.discard_partial();
                    LineRead::Bad("stream ended in the middle of a line".into())
                });
            }
            let (used, done) = match chunk.iter().position(|b| self.terms.contains(b)) {
                Some(i) => (i + 1, true),
                None => (chunk.len(), false),
            };
            if !self.too_long {
                self.buf.extend_from_slice(&chunk[..used]);
            }
            self.inner.consume(used);
            if self.buf.len() > self.max + 2 {
                self.buf.clear();
                match self.overlong {
                    Overlong::Fail => return Ok(self.overlong_line()),
                    Overlong::Skip => self.too_long = true,
                }
            }
            if done {
                if self.too_long {
                    self.too_long = false;
                    return Ok(self.overlong_line());
                }
                let mut line = std::mem::take(&mut self.buf);
                line.pop();
                if line.last() == Some(&b'\r') {
                    line.pop();
                }
                return Ok(match String::from_utf8(line) {
                    Ok(s) => LineRead::Line(s),
                    Err(_) => LineRead::Bad("line is not UTF-8".into()),
                });
            }
        }
    }

    fn overlong_line(&self) -> LineRead {
        LineRead::Bad(format!("line longer than {} bytes", self.max))
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use tokio::io::{AsyncWriteExt, BufReader};

    use super::*;

    #[tokio::test]
    async fn a_dropped_read_keeps_its_partial_line() {
        let (mut peer, host) = tokio::io::duplex(64);
        let mut rd = LineReader::new(BufReader::new(host), 32);
        peer.write_all(b"OK 1 ").await.unwrap();
        let cut = tokio::time::timeout(Duration::from_millis(20), rd.next_line()).await;
        assert!(cut.is_err(), "{cut:?}");
        peer.write_all(b"2 3\r\nNEXT\n").await.unwrap();
        assert_eq!(
            rd.next_line().await.unwrap(),
            LineRead::Line("OK 1 2 3".into())
        );
        assert_eq!(rd.next_line().await.unwrap(), LineRead::Line("NEXT".into()));
    }

    #[tokio::test]
    async fn discard_partial_drops_the_kept_bytes() {
        let (mut peer, host) = tokio::io::duplex(64);
        let mut rd = LineReader::new(BufReader::new(host), 32);
        peer.write_all(b"stale").await.unwrap();
        let cut = tokio::time::timeout(Duration::from_millis(20), rd.next_line()).await;
        assert!(cut.is_err(), "{cut:?}");
        rd.discard_partial();
        peer.write_all(b"fresh\n").await.unwrap();
        assert_eq!(
            rd.next_line().await.unwrap(),
            LineRead::Line("fresh".into())
        );
    }

    #[tokio::test]
    async fn overlong_fail_reports_at_once_and_eof_mid_line_is_bad() {
        let (mut peer, host) = tokio::io::duplex(1024);
        let mut rd = LineReader::new(BufReader::new(host), 4);
        peer.write_all(b"0123456789").await.unwrap();
        assert_eq!(
            rd.next_line().await.unwrap(),
            LineRead::Bad("line longer than 4 bytes".into())
        );
        let (mut peer, host) = tokio::io::duplex(64);
        let mut rd = LineReader::new(BufReader::new(host), 32);
        peer.write_all(b"a\r\r\nhalf").await.unwrap();
        drop(peer);
        assert_eq!(rd.next_line().await.unwrap(), LineRead::Line("a\r".into()));
        assert_eq!(
            rd.next_line().await.unwrap(),
            LineRead::Bad("stream ended in the middle of a line".into())
        );
    }
}
