//! The `cellcal identify` CSV format.
//!
//! A header row; lines starting with `#` are comments; columns found by name in any order
//! (names are trimmed and case-insensitive): `pose` (optional id), `set` (`ident`|`verify`),
//! `q1`…`qn` (rad), `p1_x,p1_y,p1_z` (mm, measurement frame), optional `p2_x,p2_y,p2_z` (mm,
//! ball after the stage moved by +travel along `u`), optional `n_x … a_z` (measured flange
//! rotation columns). Unknown columns are ignored.

use nalgebra::{Matrix3, Vector3};

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
    /// Measured flange rotation (columns n, o, a), if measured.
    pub rotation: Option<Matrix3<f64>>,
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

/// Which optional groups a caller requires.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Required {
    /// Require `p2_*`.
    pub p2: bool,
    /// Require `n_* o_* a_*`.
    pub rotation: bool,
}

/// Parse a data set for a robot with `dof` joints.
pub fn parse_csv(text: &str, dof: usize, required: Required) -> Result<Vec<Observation>, CsvError> {
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .has_headers(true)
        .from_reader(text.as_bytes());
    let headers = rdr
        .headers()
        .map_err(|e| CsvError::Malformed {
            line: 1,
            message: e.to_string(),
        })?
        .clone();
    if headers.is_empty() || (headers.len() == 1 && headers[0].is_empty()) {
        return Err(CsvError::Empty);
    }
    let names: Vec<String> = headers.iter().map(|h| h.to_ascii_lowercase()).collect();
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(CsvError::DuplicateColumn(n.clone()));
        }
    }
    let find = |n: &str| names.iter().position(|h| h == n);
    let need = |n: &str| find(n).ok_or_else(|| CsvError::MissingColumn(n.to_owned()));
    let set_col = need("set")?;
    let pose_col = find("pose");
    let q_cols = (1..=dof)
        .map(|i| need(&format!("q{i}")))
        .collect::<Result<Vec<_>, _>>()?;
    let p1_cols = ["p1_x", "p1_y", "p1_z"].map(need);
    let p1_cols = [
        p1_cols[0].clone()?,
        p1_cols[1].clone()?,
        p1_cols[2].clone()?,
    ];
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
    let p2_cols = group(&["p2_x", "p2_y", "p2_z"], required.p2)?;
    let rot_cols = group(&ROT_COLS, required.rotation)?;
    let mut out = Vec::new();
    for (row, rec) in rdr.records().enumerate() {
        let rec = rec.map_err(|e| CsvError::Malformed {
            line: e.position().map(|p| p.line() as usize).unwrap_or(row + 2),
            message: e.to_string(),
        })?;
        let line = rec.position().map(|p| p.line() as usize).unwrap_or(row + 2);
        let num = |c: usize| -> Result<f64, CsvError> {
            let raw = rec.get(c).unwrap_or("");
            let v: f64 = raw.parse().map_err(|_| CsvError::NotNumeric {
                line,
                column: names[c].clone(),
                value: raw.to_owned(),
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(CsvError::NotFinite {
                    line,
                    column: names[c].clone(),
                    value: raw.to_owned(),
                })
            }
        };
        let vec3 = |cols: &[usize]| -> Result<Vector3<f64>, CsvError> {
            Ok(Vector3::new(num(cols[0])?, num(cols[1])?, num(cols[2])?))
        };
        let set_raw = rec.get(set_col).unwrap_or("");
        let set = match set_raw.to_ascii_lowercase().as_str() {
            "ident" => PoseSet::Ident,
            "verify" => PoseSet::Verify,
            _ => {
                return Err(CsvError::BadSet {
                    line,
                    value: set_raw.to_owned(),
                })
            }
        };
        let q = q_cols
            .iter()
            .map(|&c| num(c))
            .collect::<Result<Vec<_>, _>>()?;
        let p2 = p2_cols.as_deref().map(vec3).transpose()?;
        let rotation = match &rot_cols {
            Some(c) => {
                let v = c.iter().map(|&k| num(k)).collect::<Result<Vec<_>, _>>()?;
                Some(Matrix3::from_column_slice(&v))
            }
            None => None,
        };
        out.push(Observation {
            line,
            id: pose_col
                .and_then(|c| rec.get(c))
                .map(str::to_owned)
                .unwrap_or_else(|| row.to_string()),
            set,
            q,
            p1: vec3(&p1_cols)?,
            p2,
            rotation,
        });
    }
    if out.is_empty() {
        return Err(CsvError::NoRows);
    }
    Ok(out)
}

/// Write a data set; p2 and rotation columns are written when every row has them.
pub fn write_csv(obs: &[Observation], dof: usize, comment: &str) -> String {
    let with_p2 = !obs.is_empty() && obs.iter().all(|o| o.p2.is_some());
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
        if let (true, Some(p2)) = (with_p2, o.p2) {
            cells.extend(p2.iter().map(|v| format!("{v:?}")));
        }
        if let (true, Some(r)) = (with_rot, o.rotation) {
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
                rotation: false,
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
}
