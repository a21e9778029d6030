//! Bounded, cancel-safe line reading: the shared [`lineio::LineReader`] set up for Zaber ASCII
//! (`\n`-terminated) and gauge (`\r` or `\n`-terminated) lines.

use tokio::io::AsyncBufRead;

use lineio::Overlong;
pub(crate) use lineio::{LineRead, LineReader};

/// Reader of `\n`-terminated lines (Zaber ASCII); a line longer than `max` is discarded up to its
/// terminator and reported as `Bad`, and the next read starts on the next line.
pub(crate) fn ascii_lines<R: AsyncBufRead + Unpin>(inner: R, max: usize) -> LineReader<R> {
    LineReader::new(inner, max).overlong(Overlong::Skip)
}

/// Reader of lines ended by `\r` or `\n` (gauges), overlong lines handled like [`ascii_lines`].
pub(crate) fn gauge_lines<R: AsyncBufRead + Unpin>(inner: R, max: usize) -> LineReader<R> {
    ascii_lines(inner, max).terminators(b"\r\n")
}

/// Next line with every `\r` at its end stripped.
/// Cancel-safe like [`LineReader::next_line`]: a dropped call never loses or splits a line.
pub(crate) async fn read_line<R: AsyncBufRead + Unpin>(
    reader: &mut LineReader<R>,
) -> std::io::Result<LineRead> {
    Ok(match reader.next_line().await? {
        LineRead::Line(l) => LineRead::Line(l.trim_end_matches('\r').to_string()),
        other => other,
    })
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use tokio::io::{AsyncWriteExt, BufReader};

    use super::*;

    /// A read dropped while only half a line has arrived (a reply timeout) must not lose that half:
    /// the next read returns the whole line.
    #[tokio::test]
    async fn a_read_dropped_mid_line_keeps_the_line_whole() {
        let (mut dev, host) = tokio::io::duplex(64);
        let mut rd = ascii_lines(BufReader::new(host), crate::ascii::MAX_LINE);
        dev.write_all(b"@01 0 12 OK ID").await.unwrap();
        let cut = tokio::time::timeout(Duration::from_millis(50), read_line(&mut rd)).await;
        assert!(
            cut.is_err(),
            "half a line must not complete a read: {cut:?}"
        );
        dev.write_all(b"LE -- 0\r\n").await.unwrap();
        match read_line(&mut rd).await.unwrap() {
            LineRead::Line(l) => assert_eq!(l, "@01 0 12 OK IDLE -- 0"),
            other => panic!("expected the whole line, got {other:?}"),
        }
    }

    /// The same for a gauge reading cut after its first bytes.
    #[tokio::test]
    async fn a_gauge_read_dropped_mid_line_keeps_the_line_whole() {
        let (mut dev, host) = tokio::io::duplex(64);
        let mut rd = gauge_lines(BufReader::new(host), 64);
        dev.write_all(b"01A+00").await.unwrap();
        let cut = tokio::time::timeout(Duration::from_millis(50), read_line(&mut rd)).await;
        assert!(
            cut.is_err(),
            "half a line must not complete a read: {cut:?}"
        );
        dev.write_all(b"12.345\r").await.unwrap();
        assert_eq!(
            read_line(&mut rd).await.unwrap(),
            LineRead::Line("01A+0012.345".into())
        );
    }

    /// Protocol unchanged: `\r\r\n` endings are stripped whole, an overlong line is skipped to its
    /// end and reported, and the next line is read normally.
    #[tokio::test]
    async fn endings_and_overlong_lines_as_before() {
        let (mut dev, host) = tokio::io::duplex(1024);
        let mut rd = ascii_lines(BufReader::new(host), 8);
        let long = "x".repeat(40);
        dev.write_all(format!("ab\r\r\n{long}\ncd\n").as_bytes())
            .await
            .unwrap();
        drop(dev);
        assert_eq!(
            read_line(&mut rd).await.unwrap(),
            LineRead::Line("ab".into())
        );
        assert_eq!(
            read_line(&mut rd).await.unwrap(),
            LineRead::Bad("line longer than 8 bytes".into())
        );
        assert_eq!(
            read_line(&mut rd).await.unwrap(),
            LineRead::Line("cd".into())
        );
        assert_eq!(read_line(&mut rd).await.unwrap(), LineRead::Eof);
    }
}
