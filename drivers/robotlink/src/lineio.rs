//! Bounded line reading shared by client and server.

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

/// Read bytes up to `\n`, refusing lines longer than `max` bytes.
pub(crate) async fn read_line_limited<R: AsyncBufRead + Unpin>(
    reader: &mut R,
    max: usize,
) -> std::io::Result<LineRead> {
    let mut buf: Vec<u8> = Vec::new();
    loop {
        let chunk = reader.fill_buf().await?;
        if chunk.is_empty() {
            return Ok(if buf.is_empty() {
                LineRead::Eof
            } else {
                LineRead::Bad("connection closed in the middle of a line".into())
            });
        }
        let (used, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        buf.extend_from_slice(&chunk[..used]);
        reader.consume(used);
        if buf.len() > max + 2 {
            return Ok(LineRead::Bad(format!("line longer than {max} bytes")));
        }
        if done {
            buf.pop();
            if buf.last() == Some(&b'\r') {
                buf.pop();
            }
            return Ok(match String::from_utf8(buf) {
                Ok(s) => LineRead::Line(s),
                Err(_) => LineRead::Bad("line is not UTF-8".into()),
            });
        }
    }
}
