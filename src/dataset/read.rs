//! Reading a data file: into memory, or a data set in chunks.

use std::fs::File;
use std::io::{self, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::Path;

use super::csv_format::{
    finish, header, parse_csv, parse_setup_header, plain, Columns, CsvError, CsvSetup, Observation,
    Required,
};

/// Files from this size on are read in two halves on two threads.
const PARALLEL_MIN_BYTES: u64 = 1 << 20;

/// The file at `path` as UTF-8 text, as `std::fs::read_to_string` reads it (same text, same
/// errors); a large file in two halves on two threads, which share the kernel's copy into the
/// buffer and the page faults of a fresh buffer (a large part of reading a 4 MB data set).
pub fn read_text(path: &Path) -> io::Result<String> {
    let mut file = File::open(path)?;
    let len = file.metadata()?.len();
    let Some(n) = usize::try_from(len)
        .ok()
        .filter(|_| len >= PARALLEL_MIN_BYTES)
    else {
        let mut text = String::new();
        file.read_to_string(&mut text)?;
        return Ok(text);
    };
    // zeroed by the kernel when its pages are first written, by the two readers
    let mut buf = vec![0u8; n];
    let half = n / 2;
    let (a, b) = buf.split_at_mut(half);
    let (ra, rb) = std::thread::scope(|s| {
        let hb = s.spawn(|| file.read_exact_at(b, half as u64));
        let ra = file.read_exact_at(a, 0);
        (ra, hb.join())
    });
    let rb = rb.unwrap_or_else(|_| Err(io::Error::other("reader thread panicked")));
    match ra.and(rb) {
        Ok(()) => {}
        // the file shrank meanwhile: read it as it is now
        Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => return std::fs::read_to_string(path),
        Err(e) => return Err(e),
    }
    // and whatever it grew by meanwhile
    file.seek(SeekFrom::Start(len))?;
    file.read_to_end(&mut buf)?;
    String::from_utf8(buf).map_err(|_| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            "stream did not contain valid UTF-8",
        )
    })
}

/// Bytes each reader of [`read_csv`] holds and reads at a time (and the head read for the
/// header row): small enough to stay in the core's cache.
const CHUNK: usize = 1 << 16;

/// A data set's setup header and rows.
pub type DataSet = (CsvSetup, Vec<Observation>);

/// Why a data set could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file cannot be read (or is not UTF-8).
    #[error(transparent)]
    Io(#[from] io::Error),
    /// The setup header or the rows are bad.
    #[error(transparent)]
    Csv(#[from] CsvError),
}

/// The setup header and the rows of the data set at `path`, as [`parse_setup_header`] and
/// [`parse_csv`] give them from its text ([`read_text`]), with the same errors; a large plain
/// file ([`plain`], UTF-8) is read in chunks by two readers, each parsing its half as it reads,
/// so the whole text is never in memory (its buffer's page faults were the largest part of the
/// reading); anything else is read whole.
pub fn read_csv(path: &Path, dof: usize, required: Required) -> Result<DataSet, ReadError> {
    if let Some(read) = read_in_chunks(path, dof, required)? {
        return Ok(read);
    }
    let text = read_text(path)?;
    let setup = parse_setup_header(&text)?;
    Ok((setup, parse_csv(&text, dof, required)?))
}

/// What one reader of [`read_in_chunks`] found in its part.
enum Part {
    /// The rows, and the lines before the part's end.
    Rows(Vec<Observation>, usize),
    /// A bad row.
    Bad(CsvError),
    /// Text the chunked reading does not take (quotes, a lone CR, not UTF-8, a read error):
    /// the whole file is read instead.
    Irregular,
}

/// [`read_csv`] in chunks; `None` when the file is small or not plain (read it whole).
fn read_in_chunks(
    path: &Path,
    dof: usize,
    required: Required,
) -> Result<Option<DataSet>, ReadError> {
    let file = File::open(path)?;
    let len = file.metadata()?.len();
    if len < PARALLEL_MIN_BYTES {
        return Ok(None);
    }
    // the header row and the comments before it, within the first chunk
    let mut head = vec![0u8; CHUNK];
    let got = file.read_at(&mut head, 0)?;
    head.truncate(got);
    let Some(end) = head.iter().rposition(|&b| b == b'\n') else {
        return Ok(None);
    };
    let Ok(head_text) = std::str::from_utf8(&head[..=end]) else {
        return Ok(None);
    };
    let (cols, body_start, lines_before) = match header(head_text, dof, required) {
        Ok(h) if h.1 < head_text.len() => h,
        // the header row may go on past the first chunk: read the file whole
        _ => return Ok(None),
    };
    let setup = parse_setup_header(head_text)?;
    drop(head);
    let body_start = body_start as u64;
    let mid = body_start + (len - body_start) / 2;
    let (a, b) = std::thread::scope(|s| {
        let hb = s.spawn(|| part_rows(&file, &cols, (mid - 1, true), u64::MAX, 0));
        let a = part_rows(&file, &cols, (body_start, false), mid, lines_before);
        (a, hb.join().unwrap_or(Part::Irregular))
    });
    match (a, b) {
        (Part::Irregular, _) | (_, Part::Irregular) => Ok(None),
        (Part::Bad(e), _) => Err(e.into()),
        (Part::Rows(_, lines), Part::Bad(e)) => Err(shifted(e, lines).into()),
        (Part::Rows(mut rows, lines), Part::Rows(rows_b, _)) => {
            rows.extend(rows_b.into_iter().map(|o| Observation {
                line: o.line + lines,
                ..o
            }));
            Ok(Some((setup, finish(&cols, rows)?)))
        }
    }
}

/// `e` with its line number moved on by `lines`.
fn shifted(e: CsvError, lines: usize) -> CsvError {
    let mut e = e;
    match &mut e {
        CsvError::NotNumeric { line, .. }
        | CsvError::NotFinite { line, .. }
        | CsvError::BadSet { line, .. }
        | CsvError::BadSetup { line, .. }
        | CsvError::DuplicateSetup { line, .. }
        | CsvError::Malformed { line, .. } => *line += lines,
        // the header row's, read from the file's start
        CsvError::Delimiter { .. }
        | CsvError::Empty
        | CsvError::NoRows
        | CsvError::MissingColumn(_)
        | CsvError::DuplicateColumn(_) => {}
    }
    e
}

/// The rows of the lines of `file` that start in `[start, stop)` (`from = (start, false)`), or
/// from the first line start after `start` (`from = (start, true)`: `start` is then the byte
/// before the part) to `stop`, read a chunk at a time; `lines_before` lines before the part.
fn part_rows(
    file: &File,
    cols: &Columns,
    from: (u64, bool),
    stop: u64,
    lines_before: usize,
) -> Part {
    let (start, after_line_end) = from;
    // the unread text is buf[..filled], from file offset `pos`
    let mut buf = vec![0u8; CHUNK];
    let (mut pos, mut filled) = (start, 0);
    let mut skip = after_line_end;
    let mut rows = Vec::new();
    let mut lines = lines_before;
    loop {
        if filled == buf.len() {
            // a line longer than the buffer
            buf.resize(2 * buf.len(), 0);
        }
        let Ok(n) = file.read_at(&mut buf[filled..], pos + filled as u64) else {
            return Part::Irregular;
        };
        filled += n;
        let eof = n == 0;
        if skip {
            match buf[..filled].iter().position(|&b| b == b'\n') {
                Some(i) => {
                    buf.copy_within(i + 1..filled, 0);
                    (pos, filled) = (pos + i as u64 + 1, filled - i - 1);
                    skip = false;
                }
                None if eof => return Part::Rows(rows, lines),
                None => continue,
            }
        }
        // whole lines only (all that is left at the end of the file)
        let whole = if eof {
            filled
        } else {
            match buf[..filled].iter().rposition(|&b| b == b'\n') {
                Some(i) => i + 1,
                None => continue,
            }
        };
        // and only those that start before `stop`
        let limit = usize::try_from(stop.saturating_sub(pos)).unwrap_or(usize::MAX);
        let (cut, done) = if limit == 0 {
            (0, true)
        } else if limit <= whole {
            match buf[limit - 1..whole].iter().position(|&b| b == b'\n') {
                Some(k) => (limit + k, true),
                None => (whole, eof),
            }
        } else {
            (whole, eof)
        };
        let Ok(text) = std::str::from_utf8(&buf[..cut]) else {
            return Part::Irregular;
        };
        if !plain(text) {
            return Part::Irregular;
        }
        match cols.push_plain_rows(text, lines, &mut rows) {
            Ok(line_ends) => lines += line_ends,
            Err(e) => return Part::Bad(e),
        }
        if done {
            return Part::Rows(rows, lines);
        }
        // the part line after the whole ones to the front
        buf.copy_within(cut..filled, 0);
        (pos, filled) = (pos + cut as u64, filled - cut);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A data set of `rows` rows over more than [`PARALLEL_MIN_BYTES`]: a setup header, CRLF
    /// line ends, comments and blank lines among the rows, `bad` rows with a bad q2, no `pose`
    /// column when `ids` is false.
    fn data_set(rows: usize, bad: &[usize], ids: bool) -> String {
        let mut s = String::from("# made by a test\r\n# stage_travel_mm = 12.5\r\n");
        s.push_str(if ids {
            "pose, set,q1,q2,p1_x,p1_y,p1_z\r\n"
        } else {
            "set,q1,q2,p1_x,p1_y,p1_z\r\n"
        });
        for i in 0..rows {
            if i % 1001 == 17 {
                s.push_str("# a comment\r\n\r\n");
            }
            let q2 = if bad.contains(&i) {
                "x".to_owned()
            } else {
                format!("{:?}", i as f64 * 1e-3)
            };
            let id = if ids { format!("p{i},") } else { String::new() };
            s.push_str(&format!(
                "{id}ident,{:?},{q2},1.5,-2.25,{}\r\n",
                (i as f64).sin(),
                3 * i
            ));
        }
        s
    }

    /// [`read_csv`]'s answer from the text as a whole.
    fn from_text(text: &str) -> Result<(CsvSetup, Vec<Observation>), CsvError> {
        Ok((
            parse_setup_header(text)?,
            parse_csv(text, 2, Required::default())?,
        ))
    }

    #[test]
    fn a_data_set_read_in_chunks_is_the_data_set_of_its_text() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.csv");
        let read = |text: &str| {
            std::fs::write(&path, text).unwrap();
            read_csv(&path, 2, Required::default())
        };
        for ids in [true, false] {
            let text = data_set(70_000, &[], ids);
            assert!(text.len() as u64 > 2 * PARALLEL_MIN_BYTES);
            let (setup, rows) = read(&text).unwrap();
            assert_eq!(setup.stage_travel_mm, Some(12.5));
            assert_eq!(rows.len(), 70_000);
            assert_eq!((setup, rows), from_text(&text).unwrap());
            // with the last line end missing too
            let cut = text.trim_end();
            assert_eq!(read(cut).unwrap(), from_text(cut).unwrap());
        }
        // the first bad row, wherever it is, with its line
        for bad in [vec![69_000], vec![60, 69_000], vec![34_990, 35_010]] {
            let text = data_set(70_000, &bad, true);
            let want = from_text(&text).unwrap_err();
            match read(&text) {
                Err(ReadError::Csv(e)) => assert_eq!(e, want),
                other => panic!("{bad:?}: {other:?}"),
            }
        }
        // quotes: read whole, by the csv crate
        let quoted = data_set(70_000, &[], true).replacen("ident,", "\"ident\",", 1);
        assert_eq!(read(&quoted).unwrap(), from_text(&quoted).unwrap());
        // not UTF-8 in the second half: the error of reading the text
        let mut bytes = data_set(70_000, &[], true).into_bytes();
        let at = bytes.len() - 100;
        bytes[at] = 0xfe;
        std::fs::write(&path, &bytes).unwrap();
        let e = read_csv(&path, 2, Required::default()).unwrap_err();
        assert!(matches!(e, ReadError::Io(e) if e.kind() == io::ErrorKind::InvalidData));
        // small files are read whole
        let small = data_set(10, &[], true);
        assert_eq!(read(&small).unwrap(), from_text(&small).unwrap());
    }

    #[test]
    fn a_large_file_reads_as_read_to_string_does() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.csv");
        // a multi-byte character across the middle of the file
        let line = "ident,0.125,é€,-3.5e-7\n";
        let text = line.repeat((PARALLEL_MIN_BYTES as usize * 3) / line.len());
        std::fs::write(&path, &text).unwrap();
        assert_eq!(read_text(&path).unwrap(), text);
        assert_eq!(
            read_text(&path).unwrap(),
            std::fs::read_to_string(&path).unwrap()
        );
        let small = dir.path().join("small.csv");
        std::fs::write(&small, line).unwrap();
        assert_eq!(read_text(&small).unwrap(), line);
        // not UTF-8, far from the start: the error of read_to_string
        let mut bytes = text.into_bytes();
        let at = bytes.len() - 10;
        bytes[at] = 0xff;
        std::fs::write(&path, &bytes).unwrap();
        let e = read_text(&path).unwrap_err();
        let want = std::fs::read_to_string(&path).unwrap_err();
        assert_eq!((e.kind(), e.to_string()), (want.kind(), want.to_string()));
        let missing = read_text(&dir.path().join("none.csv")).unwrap_err();
        assert_eq!(missing.kind(), io::ErrorKind::NotFound);
    }
}
