//! Bounded line reading.

use tokio::io::{AsyncBufRead, AsyncBufReadExt};

/// Outcome of reading one line.
#[derive(Debug)]
pub(crate) enum LineRead {
    /// A complete line without its terminator.
    Line(String),
    /// End of stream before any byte of a new line.
    Eof,
    /// Overlong or non-UTF-8 line (the bytes up to the terminator were consumed).
    Bad(String),
}

/// Read up to a terminator byte from `terms` (`\n`, or `\r`/`\n` for gauges); a `\r`
/// left at the end is stripped. Lines longer than `max` are reported as `Bad`.
/// Not cancel-safe: bytes of a line already consumed are lost on a drop; callers mark their stream
/// dirty and resynchronise on the next line.
pub(crate) async fn read_line_until<R: AsyncBufRead + Unpin>(
    reader: &mut R,
    max: usize,
    terms: &[u8],
) -> std::io::Result<LineRead> {
    let mut buf: Vec<u8> = Vec::new();
    let mut too_long = false;
    loop {
        let chunk = reader.fill_buf().await?;
        if chunk.is_empty() {
            return Ok(if buf.is_empty() && !too_long {
                LineRead::Eof
            } else {
                LineRead::Bad("stream ended in the middle of a line".into())
            });
        }
        let (used, done) = match chunk.iter().position(|b| terms.contains(b)) {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        if !too_long {
            buf.extend_from_slice(&chunk[..used]);
        }
        reader.consume(used);
        if buf.len() > max + 2 {
            too_long = true;
            buf.clear();
        }
        if done {
            if too_long {
                return Ok(LineRead::Bad(format!("line longer than {max} bytes")));
            }
            while matches!(buf.last(), Some(b'\r' | b'\n')) {
                buf.pop();
            }
            return Ok(match String::from_utf8(buf) {
                Ok(s) => LineRead::Line(s),
                Err(_) => LineRead::Bad("line is not UTF-8".into()),
            });
        }
    }
}

/// Read one `\n`-terminated line.
/// Not cancel-safe, like [`read_line_until`].
pub(crate) async fn read_line<R: AsyncBufRead + Unpin>(
    reader: &mut R,
    max: usize,
) -> std::io::Result<LineRead> {
    read_line_until(reader, max, b"\n").await
}
