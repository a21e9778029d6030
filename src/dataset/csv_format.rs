//! The `cellcal identify` CSV format.
//!
//! A header row; lines starting with `#` are comments; columns found by name in any order
//! (names are trimmed and case-insensitive): `pose` (optional id), `set` (`ident`|`verify`),
//! `q1`…`qn` (rad), `p1_x,p1_y,p1_z` (mm, measurement frame), optional `p2_x,p2_y,p2_z` (mm,
//! ball after the stage moved by +travel along `u`), optional `n_x … a_z` (measured flange
//! rotation columns). Unknown columns are ignored.
//!
//! The measurement setup travels with the data in comment lines before the header row, one
//! `# key = value` each, exact spelling ([`CsvSetup`], [`parse_setup_header`]):
//! `# stage_axis = X,Y,Z` (unit vector in the flange frame), `# tool_mm = X,Y,Z` (ball in the
//! flange frame), `# stage_travel_mm = V`, and, for data whose base is given rather than
//! identified, `# base_translation_mm = X,Y,Z` and `# base_rotation_vector_rad = X,Y,Z`. Any other
//! `#` line is a plain comment. Values are written with Rust's shortest round-trip formatting,
//! so a value read back is the value written, bit for bit.

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

/// A stage axis: `+x`, `-x`, `+y`, `-y`, `+z`, `-z`, or a measured vector `X,Y,Z`, normalised
/// (a vector already unit to 1e-12 is kept bit for bit, so a stored axis reads back exactly);
/// a zero or non-finite vector is an error.
pub fn parse_stage_axis(s: &str) -> Result<Vector3<f64>, String> {
    let named = match s.trim() {
        "+x" => Some(Vector3::x()),
        "-x" => Some(-Vector3::x()),
        "+y" => Some(Vector3::y()),
        "-y" => Some(-Vector3::y()),
        "+z" => Some(Vector3::z()),
        "-z" => Some(-Vector3::z()),
        _ => None,
    };
    if let Some(v) = named {
        return Ok(v);
    }
    let v = parse_vec3(s).map_err(|e| format!("{e} (or one of +x, -x, +y, -y, +z, -z)"))?;
    let n = v.norm();
    if !(n.is_finite() && n > 1e-9) {
        return Err(format!("`{s}`: the stage axis must be a non-zero vector"));
    }
    Ok(if (n - 1.0).abs() <= 1e-12 { v } else { v / n })
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
                .replace(parse_stage_axis(value).map_err(bad)?)
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

    #[test]
    fn stage_axis_names_and_vectors() {
        assert_eq!(parse_stage_axis("+z"), Ok(Vector3::z()));
        assert_eq!(parse_stage_axis("-x"), Ok(-Vector3::x()));
        let u = parse_stage_axis("3,0,4").unwrap();
        assert_eq!(u, Vector3::new(0.6, 0.0, 0.8));
        assert!(parse_stage_axis("y").is_err());
        assert!(parse_stage_axis("1,inf,0").is_err());
    }
}
