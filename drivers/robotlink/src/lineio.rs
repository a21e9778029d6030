//! Bounded, cancel-safe line reading shared by client and server.

use tokio::io::{AsyncBufRead, AsyncBufReadExt};

/// Outcome of reading one line.
#[derive(Debug)]
pub(crate) enum LineRead {
    /// A complete line (terminator stripped, `\r\n` accepted).
    Line(String),
    /// Clean end of stream before any byte of a new line.
    Eof,
    /// The line exceeded the limit or was not UTF-8; the stream is no longer usable.
    Bad(String),
}

/// Line reader that keeps a partial line across cancelled reads.
pub(crate) struct LineReader<R> {
    inner: R,
    max: usize,
    buf: Vec<u8>,
}

impl<R: AsyncBufRead + Unpin> LineReader<R> {
    /// Reader refusing lines longer than `max` bytes (terminator excluded).
    pub(crate) fn new(inner: R, max: usize) -> Self {
        Self {
            inner,
            max,
            buf: Vec::new(),
        }
    }

    /// Next line. Cancel-safe: bytes already consumed stay in `self` and a later call goes on
    /// with the same line, so a dropped call never loses or splits a line.
    pub(crate) async fn next_line(&mut self) -> std::io::Result<LineRead> {
        loop {
            let chunk = self.inner.fill_buf().await?;
            if chunk.is_empty() {
                return Ok(if self.buf.is_empty() {
                    LineRead::Eof
                } else {
                    LineRead::Bad("connection closed in the middle of a line".into())
                });
            }
            let (used, done) = match chunk.iter().position(|&b| b == b'\n') {
                Some(i) => (i + 1, true),
                None => (chunk.len(), false),
            };
            self.buf.extend_from_slice(&chunk[..used]);
            self.inner.consume(used);
            if self.buf.len() > self.max + 2 {
                return Ok(LineRead::Bad(format!(
                    "line longer than {} bytes",
                    self.max
                )));
            }
            if done {
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
}
