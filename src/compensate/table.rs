//! The CSV files of `cellcal compensate`.
//!
//! Input: a header row, then one row per target or program point; blank lines and lines
//! starting with `#` are skipped; columns are found by name (trimmed, case-insensitive, any
//! order; unknown columns ignored); an optional `id` column names the rows (else their 1-based
//! number). Targets: `x_mm,y_mm,z_mm` (tool position, measurement frame) and optionally
//! `rx_deg,ry_deg,rz_deg` (tool orientation as a rotation vector, degrees; all three or none).
//! Program points: `q1`…`qn` (rad) or `q1_deg`…`qn_deg`. Every value must be a finite number:
//! a bad cell is refused naming its line and column ([`CsvError`]).
//!
//! Output (`J.csv`): `id,q1,…,qn,reachable,residual_mm,residual_deg,at_limit,q1_deg,…,qn_deg`:
//! joints in rad in shortest round-trip form, `reachable` `true`/`false`, the identified
//! model's remaining tool position and orientation error, the joints on a limit (`q5`,
//! space-separated; empty when none) — the limits that bind when the row is not reachable —
//! and the same joints in degrees with 6 decimals (for a controller programmed in degrees;
//! added after the columns that were there first, so readers by position keep working).

use nalgebra::Vector3;

use super::{Compensated, Target};
use crate::dataset::CsvError;
use crate::model::rotation::from_rotation_vector;
use crate::units::human::fmt_fixed;

/// One named row of an input file.
#[derive(Debug, Clone, PartialEq)]
pub struct Row<T> {
    /// The `id` cell, or the row's 1-based number.
    pub id: String,
    /// Line number in the file (1-based).
    pub line: usize,
    /// What the row gives.
    pub value: T,
}

/// A header and its data rows (cells trimmed), with their line numbers.
struct Table {
    header_line: usize,
    names: Vec<String>,
    rows: Vec<(usize, Vec<String>)>,
}

/// A cell without its surrounding blanks and one pair of double quotes.
fn cell(raw: &str) -> String {
    let t = raw.trim();
    t.strip_prefix('"')
        .and_then(|s| s.strip_suffix('"'))
        .unwrap_or(t)
        .trim()
        .to_owned()
}

impl Table {
    /// Split `text` into the header and the data rows; every row has the header's field count.
    fn read(text: &str) -> Result<Table, CsvError> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l))
            .filter(|(_, l)| !(l.trim().is_empty() || l.trim_start().starts_with('#')));
        let Some((header_line, header)) = lines.next() else {
            return Err(CsvError::Empty);
        };
        let names: Vec<String> = header
            .split(',')
            .map(|h| cell(h).to_ascii_lowercase())
            .collect();
        if let Some(dup) = names
            .iter()
            .enumerate()
            .find(|(i, n)| !n.is_empty() && names[..*i].contains(n))
        {
            return Err(CsvError::DuplicateColumn(dup.1.clone()));
        }
        let mut rows = Vec::new();
        for (line, l) in lines {
            let cells: Vec<String> = l.split(',').map(cell).collect();
            if cells.len() != names.len() {
                return Err(CsvError::Malformed {
                    line,
                    message: format!("{} fields, but the header has {}", cells.len(), names.len()),
                });
            }
            rows.push((line, cells));
        }
        if rows.is_empty() {
            return Err(CsvError::NoRows);
        }
        Ok(Table {
            header_line,
            names,
            rows,
        })
    }

    fn column(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    fn required(&self, name: &str) -> Result<usize, CsvError> {
        self.column(name)
            .ok_or_else(|| CsvError::MissingColumn(name.to_owned()))
    }

    /// All of `names`, or none of them (the first missing one named).
    fn group(&self, names: &[String]) -> Result<Option<Vec<usize>>, CsvError> {
        let found: Vec<Option<usize>> = names.iter().map(|n| self.column(n)).collect();
        if found.iter().all(Option::is_none) {
            return Ok(None);
        }
        match found.iter().position(Option::is_none) {
            Some(i) => Err(CsvError::MissingColumn(names[i].clone())),
            None => Ok(Some(found.into_iter().flatten().collect())),
        }
    }

    /// The finite number in column `c` of a row (line `line`).
    fn number(&self, line: usize, cells: &[String], c: usize) -> Result<f64, CsvError> {
        let raw = &cells[c];
        let column = self.names[c].clone();
        let value = raw.clone();
        match raw.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(CsvError::NotFinite {
                line,
                column,
                value,
            }),
            Err(_) => Err(CsvError::NotNumeric {
                line,
                column,
                value,
            }),
        }
    }

    /// Each row's values by `parse`, named by the `id` column or the row number.
    fn rows<T>(
        &self,
        parse: impl Fn(usize, &[String]) -> Result<T, CsvError>,
    ) -> Result<Vec<Row<T>>, CsvError> {
        let id = self.column("id");
        self.rows
            .iter()
            .enumerate()
            .map(|(k, (line, cells))| {
                Ok(Row {
                    id: id.map_or_else(|| (k + 1).to_string(), |c| cells[c].clone()),
                    line: *line,
                    value: parse(*line, cells)?,
                })
            })
            .collect()
    }
}

/// Three numbers of a row as a vector.
fn vec3(
    t: &Table,
    line: usize,
    cells: &[String],
    cols: &[usize],
) -> Result<Vector3<f64>, CsvError> {
    Ok(Vector3::new(
        t.number(line, cells, cols[0])?,
        t.number(line, cells, cols[1])?,
        t.number(line, cells, cols[2])?,
    ))
}

/// Parse a targets file (see the module doc).
pub fn parse_targets(text: &str) -> Result<Vec<Row<Target>>, CsvError> {
    let t = Table::read(text)?;
    let position = ["x_mm", "y_mm", "z_mm"]
        .iter()
        .map(|n| t.required(n))
        .collect::<Result<Vec<_>, _>>()?;
    let rotation = t.group(&["rx_deg".into(), "ry_deg".into(), "rz_deg".into()])?;
    t.rows(|line, cells| {
        let rotation = match &rotation {
            Some(cols) => Some(from_rotation_vector(
                &vec3(&t, line, cells, cols)?.map(f64::to_radians),
            )),
            None => None,
        };
        Ok(Target {
            position_mm: vec3(&t, line, cells, &position)?,
            rotation,
        })
    })
}

/// Parse a program's joints for a robot with `dof` joints (see the module doc), in rad.
pub fn parse_joints(text: &str, dof: usize) -> Result<Vec<Row<Vec<f64>>>, CsvError> {
    let t = Table::read(text)?;
    let names = |suffix: &str| {
        (1..=dof)
            .map(|i| format!("q{i}{suffix}"))
            .collect::<Vec<_>>()
    };
    let (cols, degrees) = match (t.group(&names(""))?, t.group(&names("_deg"))?) {
        (Some(_), Some(_)) => {
            return Err(CsvError::Malformed {
                line: t.header_line,
                message: "give the joints in rad (`q1`) or in degrees (`q1_deg`), not both".into(),
            })
        }
        (Some(c), None) => (c, false),
        (None, Some(c)) => (c, true),
        (None, None) => return Err(CsvError::MissingColumn("q1".into())),
    };
    t.rows(|line, cells| {
        cols.iter()
            .map(|&c| {
                let v = t.number(line, cells, c)?;
                Ok(if degrees { v.to_radians() } else { v })
            })
            .collect()
    })
}

/// The output file: one line per compensated row, `ids` naming them (see the module doc).
pub fn write_joints(ids: &[String], rows: &[Compensated], dof: usize) -> String {
    use std::fmt::Write;
    let q: Vec<String> = (1..=dof).map(|i| format!("q{i}")).collect();
    let q_deg: Vec<String> = (1..=dof).map(|i| format!("q{i}_deg")).collect();
    let mut out = format!(
        "id,{},reachable,residual_mm,residual_deg,at_limit,{}\n",
        q.join(","),
        q_deg.join(",")
    );
    for (id, c) in ids.iter().zip(rows) {
        let joints: Vec<String> = c.q.iter().map(|v| format!("{v:?}")).collect();
        let degrees: Vec<String> = c.q.iter().map(|v| fmt_fixed(v.to_degrees(), 6)).collect();
        let limits: Vec<String> = c.at_limit.iter().map(|j| format!("q{j}")).collect();
        let _ = writeln!(
            out,
            "{},{},{},{:.6},{:.6},{},{}",
            csv_cell(id),
            joints.join(","),
            c.reachable,
            c.residual_mm,
            c.residual_rad.to_degrees(),
            limits.join(" "),
            degrees.join(",")
        );
    }
    out
}

/// An id as a CSV cell (quoted when it holds a comma or a quote).
fn csv_cell(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}
