//! Robot model files (TOML): MDH table, joint limits, optional base and tool transforms.
//!
//! ```toml
//! name = "Staubli TX60"
//! [[joints]]            # one table per joint, base to flange
//! theta_deg = 180       # or theta_rad; joint-zero offset
//! d_mm = 0
//! a_mm = 0
//! alpha_deg = 90        # or alpha_rad
//! beta_deg = 0          # or beta_rad; optional, default 0
//! limits_deg = [-180, 180]
//! [base]                # optional: robot base -> measurement frame
//! translation_mm = [0, 0, 0]
//! rotation_vector_rad = [0, 0, 0]
//! [tool]                # optional: ball position in the flange frame
//! translation_mm = [0, 0, 0]
//! ```

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::chain::{JointLimit, Mdh, RobotModel};
use super::checked_toml::parse_checked;
use super::rotation::from_rotation_vector;

/// Why a TOML file (robot model, cell configuration) could not be loaded; always names the
/// file and, where known, the key (`campaign.box_center_mm[0]`: number arrays are indexed from
/// 0, arrays of tables such as `[[joints]]` from 1, so `joints[1]` is joint 1).
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The file could not be read.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// File path.
        path: PathBuf,
        /// Underlying I/O error.
        source: std::io::Error,
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

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RobotFile {
    name: String,
    joints: Vec<JointEntry>,
    base: Option<BaseEntry>,
    tool: Option<ToolEntry>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct JointEntry {
    theta_deg: Option<f64>,
    theta_rad: Option<f64>,
    d_mm: f64,
    a_mm: f64,
    alpha_deg: Option<f64>,
    alpha_rad: Option<f64>,
    beta_deg: Option<f64>,
    beta_rad: Option<f64>,
    limits_deg: [f64; 2],
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct BaseEntry {
    translation_mm: [f64; 3],
    rotation_vector_rad: [f64; 3],
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct ToolEntry {
    translation_mm: [f64; 3],
}

/// Why a robot model file could not be loaded.
pub type RobotFileError = FileError;

/// Load a robot model file.
pub fn load_robot(path: &Path) -> Result<RobotModel, RobotFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| RobotFileError::Read {
        path: path.to_owned(),
        source,
    })?;
    parse_robot(&text, path)
}

/// Exact degrees → radians for the multiples of 90° used in MDH tables (π and π/2 bit for bit).
fn deg_to_rad(deg: f64) -> f64 {
    let quarter = deg / 90.0;
    if quarter == quarter.round() {
        quarter * std::f64::consts::FRAC_PI_2
    } else {
        deg.to_radians()
    }
}

/// Parse a robot model from TOML text; `path` is used in error messages. Every number is
/// finite and every array has its exact length ([`parse_checked`]).
pub fn parse_robot(text: &str, path: &Path) -> Result<RobotModel, RobotFileError> {
    let file: RobotFile = parse_checked(text, path)?;
    let invalid = |key: String, message: &str| RobotFileError::Invalid {
        path: path.to_owned(),
        key,
        message: message.to_owned(),
    };
    if file.joints.is_empty() {
        return Err(invalid("joints".into(), "at least one joint is required"));
    }
    let angle = |i: usize, stem: &str, deg: Option<f64>, rad: Option<f64>, required: bool| {
        let key = format!("joints[{}].{stem}_deg|{stem}_rad", i + 1);
        match (deg, rad) {
            (Some(_), Some(_)) => Err(invalid(key, "give degrees or radians, not both")),
            (Some(d), None) => Ok(deg_to_rad(d)),
            (None, Some(r)) => Ok(r),
            (None, None) if required => Err(invalid(key, "missing")),
            (None, None) => Ok(0.0),
        }
    };
    let mut joints = Vec::new();
    let mut limits = Vec::new();
    for (i, j) in file.joints.iter().enumerate() {
        joints.push(Mdh {
            theta: angle(i, "theta", j.theta_deg, j.theta_rad, true)?,
            d: j.d_mm,
            a: j.a_mm,
            alpha: angle(i, "alpha", j.alpha_deg, j.alpha_rad, true)?,
            beta: angle(i, "beta", j.beta_deg, j.beta_rad, false)?,
        });
        let [lo, hi] = j.limits_deg;
        if lo >= hi {
            return Err(invalid(
                format!("joints[{}].limits_deg", i + 1),
                "must be [min, max] with min < max",
            ));
        }
        limits.push(JointLimit {
            min: lo.to_radians(),
            max: hi.to_radians(),
        });
    }
    let (base_rotation, base_translation) = match &file.base {
        Some(b) => (
            from_rotation_vector(&Vector3::from(b.rotation_vector_rad)),
            Vector3::from(b.translation_mm),
        ),
        None => (nalgebra::Matrix3::identity(), Vector3::zeros()),
    };
    let tool = file
        .tool
        .as_ref()
        .map_or_else(Vector3::zeros, |t| Vector3::from(t.translation_mm));
    Ok(RobotModel {
        name: file.name,
        joints,
        limits,
        base_rotation,
        base_translation,
        tool,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ONE: &str = "name = \"x\"\n[[joints]]\ntheta_deg = 180\nd_mm = 0\na_mm = 0\nalpha_deg = 90\nlimits_deg = [-10, 10]\n";

    #[test]
    fn exact_right_angles() {
        let m = parse_robot(ONE, Path::new("r.toml")).unwrap();
        assert_eq!(m.joints[0].theta, std::f64::consts::PI);
        assert_eq!(m.joints[0].alpha, std::f64::consts::FRAC_PI_2);
        assert_eq!(m.joints[0].beta, 0.0);
    }

    #[test]
    fn unknown_key_is_named() {
        let text = ONE.replace("d_mm = 0", "d_mm = 0\nfoo = 1");
        let e = parse_robot(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("r.toml") && e.contains("foo"), "{e}");
    }

    #[test]
    fn missing_key_is_named() {
        let text = ONE.replace("a_mm = 0\n", "");
        let e = parse_robot(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a_mm"), "{e}");
    }

    #[test]
    fn both_units_rejected() {
        let text = ONE.replace("theta_deg = 180", "theta_deg = 180\ntheta_rad = 3.14");
        let e = parse_robot(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("joints[1].theta"), "{e}");
    }

    #[test]
    fn non_finite_and_truncated_values_are_named() {
        for (from, to, want) in [
            ("d_mm = 0", "d_mm = nan", "r.toml: joints[1].d_mm: nan is not a finite number"),
            ("a_mm = 0", "a_mm = -inf", "r.toml: joints[1].a_mm: -inf is not a finite number"),
            (
                "theta_deg = 180",
                "theta_deg = inf",
                "r.toml: joints[1].theta_deg: inf is not a finite number",
            ),
            (
                "alpha_deg = 90",
                "alpha_rad = nan",
                "r.toml: joints[1].alpha_rad: nan is not a finite number",
            ),
            (
                "[-10, 10]",
                "[-10, nan]",
                "r.toml: joints[1].limits_deg[1]: nan is not a finite number",
            ),
            (
                "[-10, 10]",
                "[-10, 10, 20]",
                "r.toml: joints[1].limits_deg: has 3 values; it takes exactly 2",
            ),
            (
                "name = \"x\"",
                "name = \"x\"\n[base]\ntranslation_mm = [0, 0, 0, 1]\nrotation_vector_rad = [0, 0, 0]",
                "r.toml: base.translation_mm: has 4 values; it takes exactly 3",
            ),
        ] {
            let text = ONE.replacen(from, to, 1);
            let e = parse_robot(&text, Path::new("r.toml"))
                .unwrap_err()
                .to_string();
            assert_eq!(e, want, "{to}");
        }
        let short = ONE.replace("[-10, 10]", "[-10]");
        let e = parse_robot(&short, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("joints[1].limits_deg"), "{e}");
    }

    #[test]
    fn bad_limits_rejected() {
        let text = ONE.replace("[-10, 10]", "[10, -10]");
        let e = parse_robot(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("limits_deg"), "{e}");
    }
}
