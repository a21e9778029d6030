//! Reading a TOML file into a typed schema with the checks serde leaves out, for every key at
//! once (so a new key cannot forget them): every float is finite (TOML accepts `nan` and `inf`,
//! and a NaN compares false, which silently switches a `<`/`>` safety check off), and every
//! array keeps all its values (serde fills a `[f64; N]` from the first N values of a longer
//! array and drops the rest). Errors name the file and the dotted key, e.g.
//! `cell.toml: campaign.box_center_mm[0]: nan is not a finite number`.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::Serialize;
use toml::Value;

/// Why a TOML file (robot model, cell configuration) could not be loaded; always names the
/// file and, where known, the key (`campaign.box_center_mm[0]`: number arrays are indexed from
/// 0, arrays of tables such as `[[joints]]` from 1, so `joints[1]` is joint 1).
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file could not be read.
    #[error("{path}: cannot read: {cause}")]
    Read {
        /// File path.
        path: PathBuf,
        /// Underlying I/O error.
        cause: std::io::Error,
    },
    /// TOML syntax or schema error (unknown key, wrong type, missing key).
    #[error("{path}: {message}")]
    Parse {
        /// File path.
        path: PathBuf,
        /// Parser message, naming the key and line.
        message: String,
    },
    /// A value is invalid.
    #[error("{path}: {key}: {message}")]
    Invalid {
        /// File path.
        path: PathBuf,
        /// Dotted key path.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// Parse `text` into `T`: a finite-float check over the whole document, then the typed
/// deserialisation (errors name the key), then an array-length check against what `T` kept.
pub fn parse_checked<T: DeserializeOwned + Serialize>(
    text: &str,
    path: &Path,
) -> Result<T, FileError> {
    let doc =
        Value::Table(toml::from_str::<toml::Table>(text).map_err(|e| parse_error(path, "", &e))?);
    check_finite(&doc, path)?;
    let de = toml::Deserializer::parse(text).map_err(|e| parse_error(path, "", &e))?;
    let typed: T = serde_path_to_error::deserialize(de)
        .map_err(|e| parse_error(path, &key_of(e.path(), &doc), e.inner()))?;
    let kept = Value::try_from(&typed).map_err(|e| FileError::Parse {
        path: path.to_owned(),
        message: format!("cannot re-read the parsed values: {e}"),
    })?;
    match first_length_mismatch(&doc, &kept, "") {
        Some((key, given, takes)) => Err(FileError::Invalid {
            path: path.to_owned(),
            key,
            message: format!("has {given} values; it takes exactly {takes}"),
        }),
        None => Ok(typed),
    }
}

/// Every float of a parsed TOML value (a whole document or one table) is finite; else the
/// error names the first offending key.
pub fn check_finite(doc: &Value, path: &Path) -> Result<(), FileError> {
    match first_non_finite(doc, String::new()) {
        Some((key, v)) => Err(FileError::Invalid {
            path: path.to_owned(),
            key,
            message: format!("{} is not a finite number", toml_spelling(v)),
        }),
        None => Ok(()),
    }
}

/// A TOML or schema error, prefixed with the key when it is known.
fn parse_error(path: &Path, key: &str, e: &toml::de::Error) -> FileError {
    let text = e.to_string().trim_end().replace('\n', " ");
    FileError::Parse {
        path: path.to_owned(),
        message: if key.is_empty() {
            text
        } else {
            format!("{key}: {text}")
        },
    }
}

/// `nan`, `inf` or `-inf`, as TOML spells them.
fn toml_spelling(v: f64) -> &'static str {
    if v.is_nan() {
        "nan"
    } else if v > 0.0 {
        "inf"
    } else {
        "-inf"
    }
}

/// `parent.name`, or `name` at the top.
fn child(parent: &str, name: &str) -> String {
    if parent.is_empty() {
        name.to_owned()
    } else {
        format!("{parent}.{name}")
    }
}

/// `parent[n]`: number arrays from 0, arrays of tables from 1 (see [`FileError`]).
fn item(parent: &str, index: usize, is_table: bool) -> String {
    format!("{parent}[{}]", index + usize::from(is_table))
}

/// The first non-finite float under `v` and its key.
fn first_non_finite(v: &Value, key: String) -> Option<(String, f64)> {
    match v {
        Value::Float(f) if !f.is_finite() => Some((key, *f)),
        Value::Table(t) => t
            .iter()
            .find_map(|(name, v)| first_non_finite(v, child(&key, name))),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .find_map(|(i, v)| first_non_finite(v, item(&key, i, v.is_table()))),
        _ => None,
    }
}

/// The first array of `given` whose counterpart in `kept` has another length: its key, the
/// given length and the kept one.
fn first_length_mismatch(given: &Value, kept: &Value, key: &str) -> Option<(String, usize, usize)> {
    match (given, kept) {
        (Value::Table(g), Value::Table(k)) => g.iter().find_map(|(name, gv)| {
            k.get(name)
                .and_then(|kv| first_length_mismatch(gv, kv, &child(key, name)))
        }),
        (Value::Array(g), Value::Array(k)) if g.len() != k.len() => {
            Some((key.to_owned(), g.len(), k.len()))
        }
        (Value::Array(g), Value::Array(k)) => {
            g.iter().zip(k).enumerate().find_map(|(i, (gv, kv))| {
                first_length_mismatch(gv, kv, &item(key, i, gv.is_table()))
            })
        }
        _ => None,
    }
}

/// The dotted key of a deserialisation error's path, indexed as in the document.
fn key_of(path: &serde_path_to_error::Path, doc: &Value) -> String {
    use serde_path_to_error::Segment;
    let mut key = String::new();
    let mut at = Some(doc);
    for seg in path.iter() {
        match seg {
            Segment::Map { key: name } => {
                at = at.and_then(|v| v.get(name.as_str()));
                key = child(&key, name);
            }
            Segment::Seq { index } => {
                let element = at.and_then(|v| v.get(*index));
                key = item(&key, *index, element.is_some_and(Value::is_table));
                at = element;
            }
            Segment::Enum { .. } | Segment::Unknown => {}
        }
    }
    key
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, Serialize)]
    #[serde(deny_unknown_fields)]
    struct Doc {
        v: Option<[f64; 3]>,
        #[serde(default)]
        rows: Vec<Row>,
    }

    #[derive(Debug, Deserialize, Serialize)]
    #[serde(deny_unknown_fields)]
    struct Row {
        pair: [f64; 2],
    }

    fn err(text: &str) -> String {
        parse_checked::<Doc>(text, Path::new("d.toml"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn non_finite_floats_are_named_by_key() {
        assert_eq!(
            err("v = [1.0, nan, 3.0]\n"),
            "d.toml: v[1]: nan is not a finite number"
        );
        assert_eq!(
            err("v = [1, 2, 3]\n[[rows]]\npair = [0, 1]\n[[rows]]\npair = [-inf, 1]\n"),
            "d.toml: rows[2].pair[0]: -inf is not a finite number"
        );
        // also where the schema has no float: the document is checked as a whole
        assert!(err("w = +inf\n").contains("w: inf is not a finite number"));
    }

    #[test]
    fn arrays_keep_every_value() {
        assert_eq!(
            err("[[rows]]\npair = [1, 2, 3]\n"),
            "d.toml: rows[1].pair: has 3 values; it takes exactly 2"
        );
        let short = err("v = [1.0, 2.0]\n");
        assert!(short.starts_with("d.toml: v: "), "{short}");
        assert!(short.contains("length"), "{short}");
        let d: Doc = parse_checked("v = [1, 2, 3.5]\n", Path::new("d.toml")).unwrap();
        assert_eq!(d.v, Some([1.0, 2.0, 3.5]));
    }

    #[test]
    fn schema_errors_name_the_key() {
        let e = err("[[rows]]\npair = [1, \"x\"]\n");
        assert!(e.starts_with("d.toml: rows[1].pair[1]: "), "{e}");
        assert!(err("v = [1, 2, 3]\nz = 1\n").contains('z'));
    }
}
