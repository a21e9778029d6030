//! The `cellcal identify` CSV format.
//!
//! A header row; lines starting with `#` are comments; columns found by name in any order
//! (names are trimmed and case-insensitive): `pose` (optional id), `set` (`ident`|`verify`),
//! `q1`…`qn` (rad), `p1_x,p1_y,p1_z` (mm, measurement frame), optional `p2_x,p2_y,p2_z` (mm,
//! ball after the stage moved by +travel along `u`; all three empty in a row without P2),
//! optional `n_x … a_z` (measured flange
//! rotation columns). Unknown columns are ignored.
//!
//! The measurement setup travels with the data in comment lines before the header row, one
//! `# key = value` each, exact spelling ([`CsvSetup`], [`parse_setup_header`]):
//! `# stage_axis = X,Y,Z` (unit vector in the flange frame), `# tool_mm = X,Y,Z` (ball in the
//! flange frame), `# stage_travel_mm = V`, and the cell's registered base,
//! `# base_translation_mm = X,Y,Z` and `# base_rotation_vector_rad = X,Y,Z` (held when the base
//! is not identified; with `--identify-base` the base of the "before" accuracy). Any other
//! `#` line is a plain comment. Values are written with Rust's shortest round-trip formatting,
//! so a value read back is the value written, bit for bit.

use nalgebra::{Matrix3, Vector3};

use crate::identify::observation::ObsModel;
use crate::identify::problem::{join_parts, split_map};
use crate::model::SignedAxis;

/// Identification or verification set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PoseSet {
    /// Used to identify the parameters.
    Ident,
    /// Only used to verify the result.
    Verify,
}

impl PoseSet {
    /// CSV spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            PoseSet::Ident => "ident",
            PoseSet::Verify => "verify",
        }
    }
}

/// One row of a data set.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Line number in the file (1-based; 0 when not read from a file).
    pub line: usize,
    /// Pose id (the `pose` column, or the row number).
    pub id: String,
    /// Identification or verification.
    pub set: PoseSet,
    /// Joint values (rad).
    pub q: Vec<f64>,
    /// Ball at stage position P1 (mm).
    pub p1: Vector3<f64>,
    /// Ball at stage position P2 (mm), if measured.
    pub p2: Option<Vector3<f64>>,
    /// Measured flange rotation (columns n, o, a), if measured (boxed: most data sets have
    /// none, and a row without one stays small).
    pub rotation: Option<Box<Matrix3<f64>>>,
}

/// A CSV problem, naming the line, column or value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CsvError {
    /// The file has no header.
    #[error("the file is empty (no header row)")]
    Empty,
    /// A header but no data rows.
    #[error("the file has a header but no data rows")]
    NoRows,
    /// The header row is separated by another character than the comma (a spreadsheet in a
    /// decimal-comma locale writes `;`), so it is one column.
    #[error(
        "line {line}: the header row is separated by {found}, not by commas: this format is \
         comma-separated with a decimal point (`set,q1,…`, `0.25`); save the file as CSV with \
         `,` between columns and `.` in numbers (in a spreadsheet: a locale with a decimal point)"
    )]
    Delimiter {
        /// The line of the header row (1-based).
        line: usize,
        /// The separator found, for people: `` `;` (semicolon) ``, `` a tab ``, `` `|` ``.
        found: &'static str,
    },
    /// A required column is missing.
    #[error("missing column `{0}`")]
    MissingColumn(String),
    /// A column name appears twice.
    #[error("duplicated column `{0}`")]
    DuplicateColumn(String),
    /// A cell is not a number.
    #[error("line {line}, column `{column}`: `{value}` is not a number")]
    NotNumeric {
        /// Line number.
        line: usize,
        /// Column name.
        column: String,
        /// The cell.
        value: String,
    },
    /// A cell is NaN or infinite.
    #[error("line {line}, column `{column}`: `{value}` is not finite")]
    NotFinite {
        /// Line number.
        line: usize,
        /// Column name.
        column: String,
        /// The cell.
        value: String,
    },
    /// The `set` value is not `ident` or `verify`.
    #[error("line {line}, column `set`: `{value}` is neither `ident` nor `verify`")]
    BadSet {
        /// Line number.
        line: usize,
        /// The cell.
        value: String,
    },
    /// A setup header line (`# key = value`) has a bad value.
    #[error("line {line}, header `{key}`: {message}")]
    BadSetup {
        /// Line number.
        line: usize,
        /// Header key.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// A setup header key appears twice.
    #[error("line {line}: header `{key}` given twice")]
    DuplicateSetup {
        /// Line number of the second one.
        line: usize,
        /// Header key.
        key: String,
    },
    /// Structural CSV problem (e.g. wrong number of fields).
    #[error("line {line}: {message}")]
    Malformed {
        /// Line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

const ROT_COLS: [&str; 9] = [
    "n_x", "n_y", "n_z", "o_x", "o_y", "o_z", "a_x", "a_y", "a_z",
];

/// Header keys of [`CsvSetup`], in writing order.
const SETUP_KEYS: [&str; 5] = [
    "stage_axis",
    "tool_mm",
    "stage_travel_mm",
    "base_translation_mm",
    "base_rotation_vector_rad",
];

/// The measurement setup a data set carries in its header comment lines (each `None` when
/// absent); what `identify` takes as its defaults.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CsvSetup {
    /// Unit stage axis `u` in the flange frame.
    pub stage_axis: Option<Vector3<f64>>,
    /// Ball position in the flange frame (mm).
    pub tool_mm: Option<Vector3<f64>>,
    /// Stage travel P1 → P2 (mm).
    pub stage_travel_mm: Option<f64>,
    /// Given base translation, robot base → measurement frame (mm).
    pub base_translation_mm: Option<Vector3<f64>>,
    /// Given base rotation, robot base → measurement frame (rotation vector, rad).
    pub base_rotation_vector_rad: Option<Vector3<f64>>,
}

fn vec3_text(v: &Vector3<f64>) -> String {
    format!("{:?},{:?},{:?}", v.x, v.y, v.z)
}

impl CsvSetup {
    /// The `key = value` lines of the present fields (for [`write_csv`]'s comment, which
    /// prefixes `# `), values in shortest round-trip form.
    pub fn comment_lines(&self) -> String {
        let vec = |v: &Option<Vector3<f64>>| v.as_ref().map(vec3_text);
        let values = [
            vec(&self.stage_axis),
            vec(&self.tool_mm),
            self.stage_travel_mm.map(|v| format!("{v:?}")),
            vec(&self.base_translation_mm),
            vec(&self.base_rotation_vector_rad),
        ];
        SETUP_KEYS
            .iter()
            .zip(values)
            .filter_map(|(k, v)| v.map(|v| format!("{k} = {v}\n")))
            .collect()
    }
}

/// Three finite numbers `X,Y,Z`.
pub fn parse_vec3(s: &str) -> Result<Vector3<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f64>()
                .map_err(|_| format!("`{}` is not a number", x.trim()))
        })
        .collect::<Result<_, _>>()?;
    if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!("`{s}`: expected three finite numbers X,Y,Z"));
    }
    Ok(Vector3::new(v[0], v[1], v[2]))
}

/// The setup header of a data set: the `# key = value` lines among the comment lines before
/// the header row (other comment lines are ignored; nothing after the header row is read).
pub fn parse_setup_header(text: &str) -> Result<CsvSetup, CsvError> {
    let mut setup = CsvSetup::default();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        let Some(comment) = line.strip_prefix('#') else {
            break;
        };
        let Some((key, value)) = comment.split_once('=') else {
            continue;
        };
        let key = key.trim();
        if !SETUP_KEYS.contains(&key) {
            continue;
        }
        let bad = |message: String| CsvError::BadSetup {
            line: i + 1,
            key: key.to_owned(),
            message,
        };
        let value = value.trim();
        let taken = match key {
            "stage_axis" => setup
                .stage_axis
                .replace(
                    SignedAxis::parse(value)
                        .map_err(|e| bad(e.to_string()))?
                        .unit(),
                )
                .is_some(),
            "tool_mm" => setup
                .tool_mm
                .replace(parse_vec3(value).map_err(bad)?)
                .is_some(),
            "stage_travel_mm" => {
                let v = value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v > 0.0)
                    .ok_or_else(|| bad(format!("`{value}` is not a positive number")))?;
                setup.stage_travel_mm.replace(v).is_some()
            }
            "base_translation_mm" => setup
                .base_translation_mm
                .replace(parse_vec3(value).map_err(bad)?)
                .is_some(),
            _ => setup
                .base_rotation_vector_rad
                .replace(parse_vec3(value).map_err(bad)?)
                .is_some(),
        };
        if taken {
            return Err(CsvError::DuplicateSetup {
                line: i + 1,
                key: key.to_owned(),
            });
        }
    }
    Ok(setup)
}

/// Which optional groups a caller requires.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Required {
    /// Require `p2_*`.
    pub p2: bool,
    /// Require `n_* o_* a_*`.
    pub rotation: bool,
    /// The caller reads no rotation: `n_* o_* a_*` cells, when present, are checked to be
    /// finite numbers as ever, but not converted (`Observation::rotation` stays `None`).
    pub rotation_unused: bool,
}

impl Required {
    /// What the identification with `model` reads: P2 for NP and OP, the rotation for the full
    /// model and for it alone (the others leave the rotation cells unconverted).
    pub fn for_model(model: ObsModel) -> Required {
        Required {
            p2: matches!(model, ObsModel::Np | ObsModel::Op),
            rotation: model == ObsModel::Full,
            rotation_unused: model != ObsModel::Full,
        }
    }
}

/// The columns of the fields a data set needs, found by name in its header.
pub(super) struct Columns {
    /// Lower-case, trimmed column names (for error messages).
    names: Vec<String>,
    set: usize,
    pose: Option<usize>,
    q: Vec<usize>,
    p1: [usize; 3],
    p2: Option<Vec<usize>>,
    rotation: Option<Vec<usize>>,
    /// Check the rotation cells but keep no rotation ([`Required::rotation_unused`]).
    rotation_unused: bool,
}

impl Columns {
    /// Find the columns of a robot with `dof` joints in the header `names`.
    fn find(names: Vec<String>, dof: usize, required: Required) -> Result<Columns, CsvError> {
        for (i, n) in names.iter().enumerate() {
            if names[..i].contains(n) {
                return Err(CsvError::DuplicateColumn(n.clone()));
            }
        }
        let find = |n: &str| names.iter().position(|h| h == n);
        let need = |n: &str| find(n).ok_or_else(|| CsvError::MissingColumn(n.to_owned()));
        let group = |cols: &[&str], req: bool| -> Result<Option<Vec<usize>>, CsvError> {
            let found: Vec<Option<usize>> = cols.iter().map(|c| find(c)).collect();
            if found.iter().all(Option::is_some) {
                Ok(Some(found.into_iter().flatten().collect()))
            } else if req || found.iter().any(Option::is_some) {
                let missing = cols[found.iter().position(Option::is_none).unwrap_or(0)];
                Err(CsvError::MissingColumn(missing.to_owned()))
            } else {
                Ok(None)
            }
        };
        let set = need("set")?;
        let pose = find("pose");
        let q = (1..=dof)
            .map(|i| need(&format!("q{i}")))
            .collect::<Result<Vec<_>, _>>()?;
        let p1 = [need("p1_x")?, need("p1_y")?, need("p1_z")?];
        let p2 = group(&["p2_x", "p2_y", "p2_z"], required.p2)?;
        let rotation = group(&ROT_COLS, required.rotation)?;
        Ok(Columns {
            set,
            pose,
            q,
            p1,
            p2,
            rotation,
            rotation_unused: required.rotation_unused,
            names,
        })
    }

    /// The observations of the data rows `text` (whole lines, no header) that follow
    /// `lines_before` lines of the file, read by the `csv` crate (any quoting); ids of rows
    /// without a `pose` column are left empty.
    fn quoted_rows(&self, text: &str, lines_before: usize) -> Result<Vec<Observation>, CsvError> {
        let mut rdr = csv::ReaderBuilder::new()
            .comment(Some(b'#'))
            .flexible(true)
            .has_headers(false)
            .from_reader(text.as_bytes());
        let mut out = Vec::new();
        let mut rec = csv::StringRecord::new();
        loop {
            let more = rdr.read_record(&mut rec).map_err(|e| CsvError::Malformed {
                line: lines_before + e.position().map_or(1, |p| p.line() as usize),
                message: e.to_string(),
            })?;
            if !more {
                return Ok(out);
            }
            let line = lines_before + rec.position().map_or(1, |p| record_line(text, p));
            let fields: Vec<&str> = rec.iter().collect();
            out.push(self.observation(&fields, line)?);
        }
    }

    /// [`quoted_rows`](Self::quoted_rows) of a [`plain`] text, split by hand: every line
    /// end ends a record, blank lines and `#` lines are skipped, fields end at commas (the
    /// `csv` crate reads such a text the same, and slower).
    fn plain_rows(&self, text: &str, lines_before: usize) -> Result<Vec<Observation>, CsvError> {
        let mut out = Vec::with_capacity(text.len() / 64);
        self.push_plain_rows(text, lines_before, &mut out)?;
        Ok(out)
    }

    /// [`plain_rows`](Self::plain_rows) pushed onto `out`; the number of line ends in `text`.
    pub(super) fn push_plain_rows(
        &self,
        text: &str,
        lines_before: usize,
        out: &mut Vec<Observation>,
    ) -> Result<usize, CsvError> {
        let mut fields: Vec<&str> = Vec::with_capacity(self.names.len());
        let mut line_ends = 0;
        for (i, raw) in text.split('\n').enumerate() {
            line_ends = i;
            let record = raw.strip_suffix('\r').unwrap_or(raw);
            if record.is_empty() || record.starts_with('#') {
                continue;
            }
            split_fields(record, &mut fields);
            out.push(self.observation(&fields, lines_before + i + 1)?);
        }
        Ok(line_ends)
    }

    /// The observation in the fields of one record (line `line`).
    fn observation(&self, fields: &[&str], line: usize) -> Result<Observation, CsvError> {
        if fields.len() != self.names.len() {
            return Err(CsvError::Malformed {
                line,
                message: format!(
                    "{} fields, but the header has {}",
                    fields.len(),
                    self.names.len()
                ),
            });
        }
        let field = |c: usize| trim_field(fields[c]);
        let num = |c: usize| -> Result<f64, CsvError> {
            let raw = field(c);
            let bad = |v: &str| (line, self.names[c].clone(), v.to_owned());
            match raw.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                Ok(_) => {
                    let (line, column, value) = bad(raw);
                    Err(CsvError::NotFinite {
                        line,
                        column,
                        value,
                    })
                }
                Err(_) => {
                    let (line, column, value) = bad(raw);
                    Err(CsvError::NotNumeric {
                        line,
                        column,
                        value,
                    })
                }
            }
        };
        let vec3 = |cols: &[usize]| -> Result<Vector3<f64>, CsvError> {
            Ok(Vector3::new(num(cols[0])?, num(cols[1])?, num(cols[2])?))
        };
        let set_raw = field(self.set);
        let set = if set_raw.eq_ignore_ascii_case("ident") {
            PoseSet::Ident
        } else if set_raw.eq_ignore_ascii_case("verify") {
            PoseSet::Verify
        } else {
            return Err(CsvError::BadSet {
                line,
                value: set_raw.to_owned(),
            });
        };
        let mut q = Vec::with_capacity(self.q.len());
        for &c in &self.q {
            q.push(num(c)?);
        }
        // a row without P2 (its three cells empty) verifies the position only
        let p2 = match self.p2.as_deref() {
            Some(cols) if cols.iter().all(|&c| field(c).trim().is_empty()) => None,
            cols => cols.map(vec3).transpose()?,
        };
        let rotation = match &self.rotation {
            Some(cols) if self.rotation_unused => {
                for &c in cols {
                    if !plainly_finite(field(c)) {
                        num(c)?;
                    }
                }
                None
            }
            Some(cols) => {
                let mut m = [0.0; 9];
                for (v, &c) in m.iter_mut().zip(cols) {
                    *v = num(c)?;
                }
                Some(Box::new(Matrix3::from_column_slice(&m)))
            }
            None => None,
        };
        Ok(Observation {
            line,
            id: self.pose.map(|c| field(c).to_owned()).unwrap_or_default(),
            set,
            q,
            p1: vec3(&self.p1)?,
            p2,
            rotation,
        })
    }
}

/// Parse a data set for a robot with `dof` joints.
///
/// The header row by the `csv` crate; the data rows, when none is quoted ([`plain`]), split by
/// hand with no allocation per row beyond the row's own `Observation`, in two halves on two
/// threads ([`split_map`]; same rows, line numbers and first error as one pass; each half
/// checks its own plainness), else by the `csv` crate in one pass.
pub fn parse_csv(text: &str, dof: usize, required: Required) -> Result<Vec<Observation>, CsvError> {
    let (cols, body_start, lines_before) = header(text, dof, required)?;
    let body = &text[body_start..];
    // each half checks itself (a half of a plain text is plain, and a text of plain halves)
    let halves = split_map(body.len(), |r| {
        let (start, end) = (line_start(body, r.start), line_start(body, r.end));
        let part = &body[start..end];
        plain(part).then(|| {
            let before = lines_before + newlines(&body.as_bytes()[..start]);
            cols.plain_rows(part, before)
        })
    });
    let parts = match halves.into_iter().collect::<Option<Vec<_>>>() {
        Some(parts) => parts,
        None => vec![cols.quoted_rows(body, lines_before)],
    };
    finish(&cols, join_parts(parts)?)
}

/// The columns of the header row of `text` (by the `csv` crate, after any comment lines), the
/// byte offset where the data rows begin, and the number of lines before it.
pub(super) fn header(
    text: &str,
    dof: usize,
    required: Required,
) -> Result<(Columns, usize, usize), CsvError> {
    let mut rdr = reader(text);
    let headers = rdr.headers().map_err(|e| CsvError::Malformed {
        line: 1,
        message: e.to_string(),
    })?;
    if headers.is_empty() || (headers.len() == 1 && headers[0].trim().is_empty()) {
        return Err(CsvError::Empty);
    }
    let names: Vec<String> = headers
        .iter()
        .map(|h| h.trim().to_ascii_lowercase())
        .collect();
    let body_start = usize::try_from(rdr.position().byte())
        .ok()
        .filter(|&b| text.is_char_boundary(b))
        .unwrap_or(text.len());
    let lines_before = newlines(&text.as_bytes()[..body_start]);
    if let [one] = names.as_slice() {
        let other = [(';', "`;` (semicolon)"), ('\t', "a tab"), ('|', "`|`")]
            .into_iter()
            .find(|(c, _)| one.contains(*c));
        if let Some((_, found)) = other {
            return Err(CsvError::Delimiter {
                line: lines_before,
                found,
            });
        }
    }
    let cols = Columns::find(names, dof, required)?;
    Ok((cols, body_start, lines_before))
}

/// The data set's rows from the rows read: an error when there are none; numbered ids when
/// there is no `pose` column.
pub(super) fn finish(
    cols: &Columns,
    mut out: Vec<Observation>,
) -> Result<Vec<Observation>, CsvError> {
    if out.is_empty() {
        return Err(CsvError::NoRows);
    }
    if cols.pose.is_none() {
        for (row, o) in out.iter_mut().enumerate() {
            o.id = row.to_string();
        }
    }
    Ok(out)
}

/// Whether `text` needs no CSV unquoting: no `"`, and every `\r` ends a line (`\r\n`), so
/// every record is one line ([`Columns::plain_rows`]).
pub(super) fn plain(text: &str) -> bool {
    !text.contains('"')
        && text
            .match_indices('\r')
            .all(|(i, _)| text.as_bytes().get(i + 1) == Some(&b'\n'))
}

/// The comma-separated fields of one unquoted record into `out` (cleared first): eight bytes
/// at a time, each word's commas found at once (exactly: no carry between its bytes).
fn split_fields<'a>(record: &'a str, out: &mut Vec<&'a str>) {
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    const COMMAS: u64 = 0x2c2c_2c2c_2c2c_2c2c;
    out.clear();
    let bytes = record.as_bytes();
    let mut start = 0;
    let words = bytes.chunks_exact(8);
    let tail = words.remainder();
    for (w, word) in words.enumerate() {
        let x = u64::from_le_bytes([
            word[0], word[1], word[2], word[3], word[4], word[5], word[6], word[7],
        ]) ^ COMMAS;
        // the high bit of each byte that was a comma
        let mut commas = !(((x & LOW7) + LOW7) | x | LOW7);
        while commas != 0 {
            let at = 8 * w + commas.trailing_zeros() as usize / 8;
            out.push(&record[start..at]);
            start = at + 1;
            commas &= commas - 1;
        }
    }
    let base = bytes.len() - tail.len();
    for (i, &b) in tail.iter().enumerate() {
        if b == b',' {
            out.push(&record[start..base + i]);
            start = base + i + 1;
        }
    }
    out.push(&record[start..]);
}

/// Whether `s` is spelled as a decimal number that `f64` parsing takes to a finite value: a
/// sign, digits with at most one point (at least one digit, at most 200 before the point), an
/// exponent of one or two digits. Never true where the parse fails or overflows; false for
/// some finite spellings too (a long exponent), which the caller then parses.
fn plainly_finite(s: &str) -> bool {
    let b = s.as_bytes();
    let mut i = usize::from(matches!(b.first(), Some(b'+' | b'-')));
    let digits = |i: &mut usize| {
        let start = *i;
        while b.get(*i).is_some_and(u8::is_ascii_digit) {
            *i += 1;
        }
        *i - start
    };
    let int = digits(&mut i);
    let frac = if b.get(i) == Some(&b'.') {
        i += 1;
        digits(&mut i)
    } else {
        0
    };
    if int + frac == 0 || int > 200 {
        return false;
    }
    if matches!(b.get(i), Some(b'e' | b'E')) {
        i += 1;
        i += usize::from(matches!(b.get(i), Some(b'+' | b'-')));
        if !(1..=2).contains(&digits(&mut i)) {
            return false;
        }
    }
    i == b.len()
}

/// `field.trim()`, without its character walk when the field starts and ends in visible ASCII.
fn trim_field(field: &str) -> &str {
    let visible = |b: Option<&u8>| b.is_some_and(|b| b.is_ascii_graphic());
    let b = field.as_bytes();
    if visible(b.first()) && visible(b.last()) {
        field
    } else {
        field.trim()
    }
}

/// The number of line ends in `bytes`.
pub(super) fn newlines(bytes: &[u8]) -> usize {
    // byte-wide counts of at most 255 (which the compiler keeps in vector lanes)
    bytes
        .chunks(255)
        .map(|c| usize::from(c.iter().map(|&b| u8::from(b == b'\n')).sum::<u8>()))
        .sum()
}

/// A CSV reader of `text` with `#` comments, records of any length (checked by
/// [`Columns::rows`]).
fn reader(text: &str) -> csv::Reader<&[u8]> {
    csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .flexible(true)
        .has_headers(true)
        .from_reader(text.as_bytes())
}

/// The line (1-based, in `text`) of the record read from position `p`: the reader positions a
/// record where it began to read, at the comment or blank lines before it, so these are skipped.
fn record_line(text: &str, p: &csv::Position) -> usize {
    let mut line = p.line() as usize;
    let mut rest = text.get(p.byte() as usize..).unwrap_or("");
    while let Some((first, after)) = rest.split_once('\n') {
        if !(first.starts_with('#') || first.trim_end_matches('\r').is_empty()) {
            break;
        }
        line += 1;
        rest = after;
    }
    line
}

/// The first line start at or after byte `i` of `text` (its length when none follows).
fn line_start(text: &str, i: usize) -> usize {
    if i == 0 || i >= text.len() {
        return i.min(text.len());
    }
    text.as_bytes()[i - 1..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(text.len(), |p| i + p)
}

/// Write a data set; p2 columns are written when a row has P2 (empty cells in a row without:
/// a verification row of the position only), rotation columns when every row has one.
pub fn write_csv(obs: &[Observation], dof: usize, comment: &str) -> String {
    let with_p2 = obs.iter().any(|o| o.p2.is_some());
    let with_rot = !obs.is_empty() && obs.iter().all(|o| o.rotation.is_some());
    let mut s = String::new();
    for line in comment.lines() {
        s.push_str("# ");
        s.push_str(line);
        s.push('\n');
    }
    let mut head = vec!["pose".to_owned(), "set".to_owned()];
    head.extend((1..=dof).map(|i| format!("q{i}")));
    head.extend(["p1_x", "p1_y", "p1_z"].map(String::from));
    if with_p2 {
        head.extend(["p2_x", "p2_y", "p2_z"].map(String::from));
    }
    if with_rot {
        head.extend(ROT_COLS.map(String::from));
    }
    s.push_str(&head.join(","));
    s.push('\n');
    for o in obs {
        let mut cells = vec![o.id.clone(), o.set.as_str().to_owned()];
        cells.extend(o.q.iter().map(|v| format!("{v:?}")));
        cells.extend(o.p1.iter().map(|v| format!("{v:?}")));
        match (with_p2, o.p2) {
            (true, Some(p2)) => cells.extend(p2.iter().map(|v| format!("{v:?}"))),
            (true, None) => cells.extend([""; 3].map(String::from)),
            (false, _) => {}
        }
        if let (true, Some(r)) = (with_rot, &o.rotation) {
            cells.extend(r.as_slice().iter().map(|v| format!("{v:?}")));
        }
        s.push_str(&cells.join(","));
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    const OK: &str =
        "# comment\nset,q1,q2,p1_x,p1_y,p1_z,pose\nident,0.1,0.2,1,2,3,a\nverify,0,0,4,5,6,b\n";

    #[test]
    fn parses_any_order_with_comments() {
        let v = parse_csv(OK, 2, Required::default()).unwrap();
        assert_eq!(v.len(), 2);
        assert_eq!(v[0].id, "a");
        assert_eq!(v[1].set, PoseSet::Verify);
        assert_eq!(v[1].p1, Vector3::new(4.0, 5.0, 6.0));
        assert_eq!(v[0].line, 3);
    }

    #[test]
    fn round_trip() {
        let v = parse_csv(OK, 2, Required::default()).unwrap();
        let s = write_csv(&v, 2, "hello");
        let w = parse_csv(&s, 2, Required::default()).unwrap();
        assert_eq!(
            v.iter().map(|o| (&o.q, o.p1)).collect::<Vec<_>>(),
            w.iter().map(|o| (&o.q, o.p1)).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_verification_row_without_p2_is_written_with_empty_cells_and_reads_back() {
        let mut v = parse_csv(OK, 2, Required::default()).unwrap();
        v[0].p2 = Some(Vector3::new(1.0, 12.0, 3.0));
        let s = write_csv(&v, 2, "");
        assert!(s.ends_with("b,verify,0.0,0.0,4.0,5.0,6.0,,,\n"), "{s}");
        let w = parse_csv(&s, 2, Required::default()).unwrap();
        assert_eq!(
            v.iter().map(|o| (o.p1, o.p2)).collect::<Vec<_>>(),
            w.iter().map(|o| (o.p1, o.p2)).collect::<Vec<_>>()
        );
        // one empty cell of three is no row without P2: it is refused
        let half = s.replace(",,,\n", ",1,,\n");
        assert!(parse_csv(&half, 2, Required::default()).is_err());
    }

    /// `n` rows without a `pose` column, a comment every 7th line; row `bad` (if any) has a
    /// non-numeric q2.
    fn many_rows(n: usize, bad: &[usize]) -> String {
        let mut s = String::from("# many\nset, q1,q2,p1_x,p1_y,p1_z\n");
        for i in 0..n {
            if i % 7 == 3 {
                s.push_str("# a comment\n");
            }
            let q2 = if bad.contains(&i) {
                "x".to_owned()
            } else {
                format!("{}", i as f64 * 0.001)
            };
            s.push_str(&format!("ident, {i}.5,{q2},1,2,{}\n", 3 * i));
        }
        s
    }

    #[test]
    fn two_halves_give_the_rows_of_one_pass() {
        let text = many_rows(2000, &[]);
        // a quoted field makes the parser read the file in one pass
        let quoted = text.replacen("ident,", "\"ident\",", 1);
        let halves = parse_csv(&text, 2, Required::default()).unwrap();
        let one = parse_csv(&quoted, 2, Required::default()).unwrap();
        assert_eq!(halves.len(), one.len());
        if let Some(i) = (0..one.len()).find(|&i| halves[i] != one[i]) {
            panic!("row {i}: {:?} vs {:?}", halves[i], one[i]);
        }
        assert_eq!(halves.len(), 2000);
        assert_eq!(halves[1999].id, "1999");
        // a row after a comment is on its own line, not the comment's
        assert_eq!((halves[2].line, halves[3].line), (5, 7));
        assert_eq!(halves[1999].q[0], 1999.5);
        // 2 header lines, 286 comments before the last row
        assert_eq!(halves[1999].line, 2 + 286 + 2000);
        let blank = "set,q1,q2,p1_x,p1_y,p1_z\n\n# c\n\nident,0,0,1,2,x\n";
        let e = parse_csv(blank, 2, Required::default()).unwrap_err();
        assert!(matches!(e, CsvError::NotNumeric { line: 5, .. }), "{e:?}");
    }

    #[test]
    fn rows_split_by_hand_are_the_rows_of_the_csv_crate() {
        // CRLF line ends, blank lines, comments, spaces around fields, a last line without end
        let text = many_rows(600, &[])
            .replace('\n', "\r\n")
            .replacen("\r\n", "\r\n\r\n", 40)
            + "verify,1,2,3,4,5";
        assert!(plain(&text));
        let quoted = text.replacen("ident,", "\"ident\",", 1);
        assert!(!plain(&quoted));
        let by_hand = parse_csv(&text, 2, Required::default()).unwrap();
        assert_eq!(by_hand, parse_csv(&quoted, 2, Required::default()).unwrap());
        assert_eq!(by_hand.len(), 601);
        // a lone carriage return ends a record for the csv crate: not split by hand
        assert!(!plain("ident,1\rident,2\n"));
        // fields trim as `str::trim` does, Unicode spaces included
        for f in ["1.5", " 1.5", "1.5\t", "\u{a0}1.5", "1.5\u{2003}", "", " "] {
            assert_eq!(trim_field(f), f.trim(), "{f:?}");
        }
        let mut fields = Vec::new();
        split_fields(",a,,b ,", &mut fields);
        assert_eq!(fields, ["", "a", "", "b ", ""]);
        // eight bytes at a time: as `str::split`, whatever the bytes around the commas
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let alphabet: Vec<char> = ",,,-+.0123456789e\t é€\u{7f}\u{ac}".chars().collect();
        for _ in 0..5000 {
            let len = rng.random_range(0..40);
            let record: String = (0..len)
                .map(|_| alphabet[rng.random_range(0..alphabet.len())])
                .collect();
            let mut split = Vec::new();
            split_fields(&record, &mut split);
            assert_eq!(split, record.split(',').collect::<Vec<_>>(), "{record:?}");
        }
        let text = "a\nb\n\nc,d\n".repeat(100);
        assert_eq!(newlines(text.as_bytes()), 400);
    }

    #[test]
    fn the_first_bad_row_is_reported_wherever_it_is() {
        for bad in [vec![1500], vec![20, 1500]] {
            let text = many_rows(2000, &bad);
            let e = parse_csv(&text, 2, Required::default()).unwrap_err();
            let one = parse_csv(
                &text.replacen("ident,", "\"ident\",", 1),
                2,
                Required::default(),
            )
            .unwrap_err();
            assert_eq!(e, one);
            let line = 3 + bad[0] + (bad[0] + 3) / 7;
            assert!(
                matches!(&e, CsvError::NotNumeric { line: l, value, .. } if *l == line && value == "x"),
                "{e:?}"
            );
        }
        let short = many_rows(2000, &[]).replace("ident, 1500.5,", "ident,");
        let e = parse_csv(&short, 2, Required::default()).unwrap_err();
        assert!(
            matches!(&e, CsvError::Malformed { message, .. } if message.contains("5 fields, but the header has 6")),
            "{e:?}"
        );
    }

    #[test]
    fn errors_name_line_column_value() {
        let e = parse_csv(&OK.replace("0.2", "abc"), 2, Required::default()).unwrap_err();
        assert_eq!(e.to_string(), "line 3, column `q2`: `abc` is not a number");
        let e = parse_csv(&OK.replace("0.2", "NaN"), 2, Required::default()).unwrap_err();
        assert!(matches!(e, CsvError::NotFinite { line: 3, .. }));
        let e = parse_csv(&OK.replace("verify", "check"), 2, Required::default()).unwrap_err();
        assert!(matches!(e, CsvError::BadSet { line: 4, .. }));
        let e = parse_csv(OK, 3, Required::default()).unwrap_err();
        assert_eq!(e, CsvError::MissingColumn("q3".into()));
        let e = parse_csv(
            OK,
            2,
            Required {
                p2: true,
                ..Required::default()
            },
        )
        .unwrap_err();
        assert_eq!(e, CsvError::MissingColumn("p2_x".into()));
        let e = parse_csv(&OK.replace("pose", "q1"), 2, Required::default()).unwrap_err();
        assert_eq!(e, CsvError::DuplicateColumn("q1".into()));
        assert_eq!(
            parse_csv("", 2, Required::default()).unwrap_err(),
            CsvError::Empty
        );
        let e = parse_csv("set,q1,q2,p1_x,p1_y,p1_z\n", 2, Required::default()).unwrap_err();
        assert_eq!(e, CsvError::NoRows);
    }

    #[test]
    fn setup_header_round_trips_bit_for_bit() {
        let axis = Vector3::new(0.1, 0.7, -0.3).normalize();
        let setup = CsvSetup {
            stage_axis: Some(axis),
            tool_mm: Some(Vector3::new(0.4123456789012345, -0.3, 60.000000000000014)),
            stage_travel_mm: Some(10.0),
            base_translation_mm: None,
            base_rotation_vector_rad: Some(Vector3::new(1e-7, -2.5, 3.0)),
        };
        let v = parse_csv(OK, 2, Required::default()).unwrap();
        let text = write_csv(&v, 2, &format!("exported\n{}", setup.comment_lines()));
        assert!(text.starts_with("# exported\n# stage_axis = "), "{text}");
        assert_eq!(parse_setup_header(&text).unwrap(), setup);
        // the data still parses; a header-less file has no setup
        assert_eq!(parse_csv(&text, 2, Required::default()).unwrap().len(), 2);
        assert_eq!(parse_setup_header(OK).unwrap(), CsvSetup::default());
    }

    #[test]
    fn setup_header_rules() {
        let h = |lines: &str| parse_setup_header(&format!("{lines}set,q1\nident,0\n"));
        // other comments stay comments; spelling is exact; only before the header row
        let s = h("# stage_axis: +y\n# Stage_Axis = +x\n#stage_axis=-y\n").unwrap();
        assert_eq!(s.stage_axis, Some(-Vector3::y()));
        let late = parse_setup_header("set,q1\n# stage_axis = +x\nident,0\n").unwrap();
        assert_eq!(late, CsvSetup::default());
        // a measured axis is normalised
        let s = h("# stage_axis = 0,2,0\n").unwrap();
        assert_eq!(s.stage_axis, Some(Vector3::y()));
        for (line, want) in [
            ("# stage_axis = 0,0,0", "line 1, header `stage_axis`: `0,0,0`: the stage axis must be a non-zero vector"),
            ("# stage_axis = NaN,1,0", "line 1, header `stage_axis`: `NaN,1,0`: expected three finite numbers X,Y,Z (or one of +x, -x, +y, -y, +z, -z)"),
            ("# tool_mm = 1,2", "line 1, header `tool_mm`: `1,2`: expected three finite numbers X,Y,Z"),
            ("# stage_travel_mm = -1", "line 1, header `stage_travel_mm`: `-1` is not a positive number"),
            ("# stage_travel_mm = inf", "line 1, header `stage_travel_mm`: `inf` is not a positive number"),
        ] {
            assert_eq!(h(&format!("{line}\n")).unwrap_err().to_string(), want);
        }
        let e = h("# tool_mm = 0,0,60\n# tool_mm = 0,0,61\n").unwrap_err();
        assert_eq!(e.to_string(), "line 2: header `tool_mm` given twice");
    }

    /// A data set with rotation columns; `cell` replaces the `n_y` of row `bad`.
    fn with_rotations(rows: usize, bad: usize, cell: &str) -> String {
        let mut s = format!("set,q1,q2,p1_x,p1_y,p1_z,{}\n", ROT_COLS.join(","));
        for i in 0..rows {
            let (c, n) = ((0.01 * i as f64).cos(), (0.01 * i as f64).sin());
            let n_y = if i == bad {
                cell.to_owned()
            } else {
                format!("{n:?}")
            };
            s.push_str(&format!(
                "ident,{i}.5,0.2,1,2,3,{c:?},{n_y},0,{:?},{c:?},0,0,0,1e0\n",
                -n
            ));
        }
        s
    }

    #[test]
    fn unused_rotation_cells_are_checked_but_not_kept() {
        let unused = Required {
            rotation_unused: true,
            ..Required::default()
        };
        let text = with_rotations(600, usize::MAX, "");
        let kept = parse_csv(&text, 2, Required::default()).unwrap();
        let skipped = parse_csv(&text, 2, unused).unwrap();
        assert!(kept.iter().all(|o| o.rotation.is_some()));
        let without: Vec<Observation> = kept
            .into_iter()
            .map(|o| Observation {
                rotation: None,
                ..o
            })
            .collect();
        assert_eq!(skipped, without);
        // a bad rotation cell is the same error, kept or not (in either half)
        for bad in [3, 450] {
            for cell in ["x", "NaN", "-inf", "1e999", "1.5.2", "", "--1"] {
                let text = with_rotations(600, bad, cell);
                let want = parse_csv(&text, 2, Required::default()).unwrap_err();
                assert_eq!(parse_csv(&text, 2, unused).unwrap_err(), want, "{cell:?}");
            }
            // finite spellings the quick check leaves to the parse are accepted
            for cell in ["1e-300", "+.5", "5.", " 7 "] {
                let text = with_rotations(600, bad, cell);
                assert_eq!(parse_csv(&text, 2, unused).unwrap().len(), 600, "{cell:?}");
            }
        }
        let full = Required::for_model(ObsModel::Full);
        assert!(full.rotation && !full.rotation_unused && !full.p2);
        assert!(Required::for_model(ObsModel::Op).rotation_unused);
    }

    #[test]
    fn the_quick_finite_check_never_accepts_what_the_parse_refuses() {
        let parsed_finite = |s: &str| s.parse::<f64>().is_ok_and(f64::is_finite);
        for s in [
            "1", "-0.5", "+3.25", ".5", "5.", "1e5", "1E-05", "-2.5e+99", "0.000", "007",
        ] {
            assert!(plainly_finite(s) && parsed_finite(s), "{s:?}");
        }
        let long = format!("{}e99", "9".repeat(201));
        for s in [
            "", "+", "-", ".", "e5", "1e", "1e+", "1e100", "1e-100", "1.2.3", "1,5", " 1", "inf",
            "NaN", "0x10", "1_0", "1e5x", "--1", "+-1", &long,
        ] {
            assert!(!plainly_finite(s), "{s:?}");
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let alphabet = b"0123456789+-.eE";
        for _ in 0..20_000 {
            let len = rng.random_range(0..9);
            let s: String = (0..len)
                .map(|_| alphabet[rng.random_range(0..alphabet.len())] as char)
                .collect();
            assert!(!plainly_finite(&s) || parsed_finite(&s), "{s:?}");
        }
        for v in [0.0, -1.5e-7, 123.456, f64::MAX, f64::MIN_POSITIVE, 1e-320] {
            let (shortest, sci) = (format!("{v:?}"), format!("{v:e}"));
            assert!(!plainly_finite(&shortest) || parsed_finite(&shortest));
            assert!(!plainly_finite(&sci) || parsed_finite(&sci));
        }
    }
}
