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
//! limits_deg = [-180, 180]  # or limits_rad
//! max_speed_deg_s = 435     # optional: joint speed at 100 % (deg/s)
//! max_accel_deg_s2 = 870    # optional: joint acceleration (deg/s²)
//! [base]                # optional: robot base -> measurement frame
//! translation_mm = [0, 0, 0]
//! rotation_vector_rad = [0, 0, 0]
//! [tool]                # optional: ball position in the flange frame
//! translation_mm = [0, 0, 0]
//! ```
//!
//! The gravity model and the non-geometric terms (§10), all optional: a top-level
//! `gravity = [x, y, z]` (unit vector, robot base frame, default `[0, 0, -1]`), lumped masses
//! `[[masses]] frame = k, at_mm = [x, y, z], kg = m` (k = 1..n, the MDH frame the mass is fixed
//! in), per joint `compliance_rad_per_nm` and `harmonics_rad = [sin_q, cos_q, sin_2q, cos_2q]`,
//! and `[[torque_chain]]` (one table of MDH keys per joint, no limits): the chain the torques
//! are computed on when it is not the model's own (a corrected model's nominal chain).

use std::path::Path;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::chain::{JointLimit, JointMotion, Mdh, RobotModel};
use super::checked_toml::parse_checked;
pub use super::checked_toml::FileError;
use super::gravity::{default_gravity, Mass};
use super::rotation::{from_rotation_vector, log_so3};
use super::terms::JointTerms;

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct RobotFile {
    name: String,
    gravity: Option<[f64; 3]>,
    joints: Vec<JointEntry>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    masses: Vec<MassEntry>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    torque_chain: Vec<ChainEntry>,
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
    limits_deg: Option<[f64; 2]>,
    limits_rad: Option<[f64; 2]>,
    max_speed_deg_s: Option<f64>,
    max_accel_deg_s2: Option<f64>,
    compliance_rad_per_nm: Option<f64>,
    harmonics_rad: Option<[f64; 4]>,
}

/// One joint of `[[torque_chain]]`: MDH parameters only.
#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct ChainEntry {
    theta_deg: Option<f64>,
    theta_rad: Option<f64>,
    d_mm: f64,
    a_mm: f64,
    alpha_deg: Option<f64>,
    alpha_rad: Option<f64>,
    beta_deg: Option<f64>,
    beta_rad: Option<f64>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct MassEntry {
    frame: usize,
    at_mm: [f64; 3],
    kg: f64,
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
    let text = std::fs::read_to_string(path).map_err(|cause| RobotFileError::Read {
        path: path.to_owned(),
        cause,
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
    let angle =
        |table: &str, i: usize, stem: &str, deg: Option<f64>, rad: Option<f64>, required| {
            let key = format!("{table}[{}].{stem}_deg|{stem}_rad", i + 1);
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
    let mut motion = Vec::new();
    let mut terms = Vec::new();
    for (i, j) in file.joints.iter().enumerate() {
        terms.push(JointTerms {
            compliance: j.compliance_rad_per_nm.unwrap_or(0.0),
            harmonics: j.harmonics_rad.unwrap_or([0.0; 4]),
        });
        let rate = |stem: &str, v: Option<f64>| match v {
            Some(v) if v <= 0.0 => Err(invalid(
                format!("joints[{}].{stem}", i + 1),
                &format!("must be greater than 0, got {v}"),
            )),
            v => Ok(v.map(f64::to_radians)),
        };
        motion.push(JointMotion {
            max_speed: rate("max_speed_deg_s", j.max_speed_deg_s)?,
            max_accel: rate("max_accel_deg_s2", j.max_accel_deg_s2)?,
        });
        joints.push(Mdh {
            theta: angle("joints", i, "theta", j.theta_deg, j.theta_rad, true)?,
            d: j.d_mm,
            a: j.a_mm,
            alpha: angle("joints", i, "alpha", j.alpha_deg, j.alpha_rad, true)?,
            beta: angle("joints", i, "beta", j.beta_deg, j.beta_rad, false)?,
        });
        let key = |unit: &str| format!("joints[{}].limits_{unit}", i + 1);
        let (min, max, unit) = match (j.limits_deg, j.limits_rad) {
            (Some(_), Some(_)) => {
                return Err(invalid(
                    key("deg|limits_rad"),
                    "give degrees or radians, not both",
                ))
            }
            (Some([lo, hi]), None) => (lo.to_radians(), hi.to_radians(), "deg"),
            (None, Some([lo, hi])) => (lo, hi, "rad"),
            (None, None) => return Err(invalid(key("deg|limits_rad"), "missing")),
        };
        if min >= max {
            return Err(invalid(key(unit), "must be [min, max] with min < max"));
        }
        limits.push(JointLimit { min, max });
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
    let gravity = match file.gravity {
        None => default_gravity(),
        Some(g) => {
            let g = Vector3::from(g);
            if (g.norm() - 1.0).abs() > 1e-6 {
                return Err(invalid(
                    "gravity".into(),
                    &format!("must be a unit vector, got length {}", g.norm()),
                ));
            }
            g
        }
    };
    let n = joints.len();
    let mut masses = Vec::new();
    for (i, m) in file.masses.iter().enumerate() {
        let key = |k: &str| format!("masses[{}].{k}", i + 1);
        if !(1..=n).contains(&m.frame) {
            return Err(invalid(
                key("frame"),
                &format!("must be an MDH frame 1..={n}, got {}", m.frame),
            ));
        }
        if m.kg <= 0.0 {
            return Err(invalid(
                key("kg"),
                &format!("must be greater than 0, got {}", m.kg),
            ));
        }
        masses.push(Mass {
            frame: m.frame,
            at: Vector3::from(m.at_mm),
            kg: m.kg,
        });
    }
    if terms.iter().all(JointTerms::is_zero) {
        terms.clear();
    }
    let torque_chain = if file.torque_chain.is_empty() {
        None
    } else if file.torque_chain.len() != n {
        return Err(invalid(
            "torque_chain".into(),
            &format!(
                "must have one table per joint ({n}), got {}",
                file.torque_chain.len()
            ),
        ));
    } else {
        let mut chain = Vec::with_capacity(n);
        for (i, j) in file.torque_chain.iter().enumerate() {
            let t = "torque_chain";
            chain.push(Mdh {
                theta: angle(t, i, "theta", j.theta_deg, j.theta_rad, true)?,
                d: j.d_mm,
                a: j.a_mm,
                alpha: angle(t, i, "alpha", j.alpha_deg, j.alpha_rad, true)?,
                beta: angle(t, i, "beta", j.beta_deg, j.beta_rad, false)?,
            });
        }
        Some(chain)
    };
    Ok(RobotModel {
        name: file.name,
        joints,
        limits,
        motion,
        base_rotation,
        base_translation,
        tool,
        masses,
        gravity,
        terms,
        torque_chain,
    })
}

/// A float in the shortest form that reads back to the same bits (TOML syntax).
fn exact(v: f64) -> String {
    format!("{v:?}")
}

/// `[a, b, …]` of [`exact`] floats.
fn exact_array(v: &[f64]) -> String {
    let items: Vec<String> = v.iter().map(|x| exact(*x)).collect();
    format!("[{}]", items.join(", "))
}

/// The shortest decimal degrees that [`parse_robot`] turns back into exactly `rad`, if any.
fn exact_degrees(rad: f64) -> Option<f64> {
    let deg = rad.to_degrees();
    (0..=17)
        .filter_map(|digits| format!("{deg:.digits$}").parse::<f64>().ok())
        .find(|d| d.to_radians() == rad)
}

/// The `limits_deg` line of a joint, or `limits_rad` when no decimal degrees give the limits
/// back exactly.
fn limits_line(l: &JointLimit) -> String {
    match (exact_degrees(l.min), exact_degrees(l.max)) {
        (Some(lo), Some(hi)) => format!("limits_deg = {}", exact_array(&[lo, hi])),
        _ => format!("limits_rad = {}", exact_array(&[l.min, l.max])),
    }
}

/// One joint's MDH lines (angles in rad, with degrees in a comment).
fn write_mdh(out: &mut String, m: &Mdh) {
    use std::fmt::Write;
    let angle =
        |stem: &str, v: f64| format!("{stem}_rad = {}  # {:.6} deg", exact(v), v.to_degrees());
    let _ = writeln!(out, "{}", angle("theta", m.theta));
    let _ = writeln!(out, "d_mm = {}", exact(m.d));
    let _ = writeln!(out, "a_mm = {}", exact(m.a));
    let _ = writeln!(out, "{}", angle("alpha", m.alpha));
    let _ = writeln!(out, "{}", angle("beta", m.beta));
}

/// A robot model as robot-file TOML that [`parse_robot`] reads back to the same model:
/// every float in shortest round-trip form (angles in rad, with degrees in a comment), the
/// base rotation as a rotation vector ([`log_so3`], exact for small angles). `header` lines
/// become `# ` comments at the top.
pub fn write_robot(model: &RobotModel, header: &[String]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for line in header {
        let _ = writeln!(out, "{}", format!("# {line}").trim_end());
    }
    let _ = writeln!(out, "name = {}", toml::Value::String(model.name.clone()));
    if model.gravity != default_gravity() {
        let _ = writeln!(out, "gravity = {}", exact_array(model.gravity.as_slice()));
    }
    for (i, (m, l)) in model.joints.iter().zip(&model.limits).enumerate() {
        let _ = writeln!(out, "\n[[joints]]");
        write_mdh(&mut out, m);
        let _ = writeln!(out, "{}", limits_line(l));
        let motion = model.motion.get(i).copied().unwrap_or_default();
        for (key, v) in [
            ("max_speed_deg_s", motion.max_speed),
            ("max_accel_deg_s2", motion.max_accel),
        ] {
            if let Some(rad) = v {
                let deg = exact_degrees(rad).unwrap_or_else(|| rad.to_degrees());
                let _ = writeln!(out, "{key} = {}", exact(deg));
            }
        }
        let terms = model.terms.get(i).copied().unwrap_or_default();
        if terms.compliance != 0.0 {
            let _ = writeln!(out, "compliance_rad_per_nm = {}", exact(terms.compliance));
        }
        if terms.harmonics != [0.0; 4] {
            let _ = writeln!(out, "harmonics_rad = {}", exact_array(&terms.harmonics));
        }
    }
    for m in &model.masses {
        let _ = writeln!(out, "\n[[masses]]");
        let _ = writeln!(out, "frame = {}", m.frame);
        let _ = writeln!(out, "at_mm = {}", exact_array(m.at.as_slice()));
        let _ = writeln!(out, "kg = {}", exact(m.kg));
    }
    if let Some(chain) = &model.torque_chain {
        for m in chain {
            let _ = writeln!(out, "\n[[torque_chain]]");
            write_mdh(&mut out, m);
        }
    }
    let rv = log_so3(&model.base_rotation);
    let _ = writeln!(out, "\n[base]");
    let _ = writeln!(
        out,
        "translation_mm = {}",
        exact_array(model.base_translation.as_slice())
    );
    let _ = writeln!(out, "rotation_vector_rad = {}", exact_array(rv.as_slice()));
    let _ = writeln!(out, "\n[tool]");
    let _ = writeln!(
        out,
        "translation_mm = {}",
        exact_array(model.tool.as_slice())
    );
    out
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
    fn joint_speed_and_acceleration_are_read_checked_and_written_back() {
        let given = ONE.replace(
            "limits_deg = [-10, 10]",
            "limits_deg = [-10, 10]\nmax_speed_deg_s = 435\nmax_accel_deg_s2 = 870.5",
        );
        let m = parse_robot(&given, Path::new("r.toml")).unwrap();
        assert_eq!(m.motion[0].max_speed, Some(435f64.to_radians()));
        assert_eq!(m.motion[0].max_accel, Some(870.5f64.to_radians()));
        let text = write_robot(&m, &[]);
        assert!(text.contains("max_speed_deg_s = 435.0\n"), "{text}");
        assert!(text.contains("max_accel_deg_s2 = 870.5\n"), "{text}");
        assert_eq!(parse_robot(&text, Path::new("w.toml")).unwrap(), m);
        // optional: absent stays absent, also when written back
        let none = parse_robot(ONE, Path::new("r.toml")).unwrap();
        assert_eq!(none.motion[0], JointMotion::default());
        assert!(!write_robot(&none, &[]).contains("max_speed"));
        for (line, want) in [
            (
                "max_speed_deg_s = 0",
                "r.toml: joints[1].max_speed_deg_s: must be greater than 0, got 0",
            ),
            (
                "max_accel_deg_s2 = -5",
                "r.toml: joints[1].max_accel_deg_s2: must be greater than 0, got -5",
            ),
            (
                "max_speed_deg_s = nan",
                "r.toml: joints[1].max_speed_deg_s: nan is not a finite number",
            ),
            (
                "max_accel_deg_s2 = inf",
                "r.toml: joints[1].max_accel_deg_s2: inf is not a finite number",
            ),
        ] {
            let text = ONE.replace("d_mm = 0", &format!("d_mm = 0\n{line}"));
            let e = parse_robot(&text, Path::new("r.toml"))
                .unwrap_err()
                .to_string();
            assert_eq!(e, want, "{line}");
        }
    }

    #[test]
    fn bad_limits_rejected() {
        let text = ONE.replace("[-10, 10]", "[10, -10]");
        let e = parse_robot(&text, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("limits_deg"), "{e}");
    }

    /// A perturbed TX60 with odd floats everywhere.
    fn perturbed() -> RobotModel {
        let mut m = crate::model::tx60();
        for (i, j) in m.joints.iter_mut().enumerate() {
            let k = i as f64 + 1.0;
            j.theta += 1.234_567_890_123e-4 * k;
            j.d += 0.1 / 3.0 * k;
            j.a -= 1e-7 * k;
            j.alpha -= 2.0e-5 / k;
            j.beta += 1e-20 * k;
        }
        m.base_translation = Vector3::new(2_512.345_678_901, -0.1, 1e-9);
        m.base_rotation = from_rotation_vector(&Vector3::new(1e-9, -0.7, 2.9));
        m.tool = Vector3::new(0.1, -35.7, 60.0 + 1.0 / 3.0);
        m.limits[3].min = 1.0 / 7.0 - 3.0;
        m
    }

    #[test]
    fn masses_gravity_and_terms_are_read_checked_and_written_back() {
        let mut m = perturbed();
        m.gravity = Vector3::new(0.6, 0.0, -0.8);
        m.masses = vec![
            Mass {
                frame: 2,
                at: Vector3::new(-150.0, 0.0, 120.0 + 1.0 / 3.0),
                kg: 8.4,
            },
            Mass {
                frame: 6,
                at: Vector3::new(0.0, 0.0, 30.0),
                kg: 0.35,
            },
        ];
        *m.term_mut(1, crate::model::TermKind::Compliance) = 1.0 / 3.0 * 1e-6;
        *m.term_mut(4, crate::model::TermKind::Cos2Q) = -2.5e-5;
        // the chain its torques were identified on (the nominal one)
        m.torque_chain = Some(crate::model::tx60().joints);
        let text = write_robot(&m, &[]);
        let back = parse_robot(&text, Path::new("w.toml")).unwrap();
        assert_eq!(back.torque_chain, m.torque_chain, "{text}");
        assert_eq!(back.masses, m.masses, "{text}");
        assert_eq!(back.gravity, m.gravity, "{text}");
        assert_eq!(back.terms, m.terms, "{text}");
        assert_eq!(back.joints, m.joints, "{text}");
        // a model without them writes none of the keys
        let plain = write_robot(
            &RobotModel {
                masses: Vec::new(),
                ..perturbed()
            },
            &[],
        );
        for key in [
            "gravity",
            "masses",
            "compliance",
            "harmonics",
            "torque_chain",
        ] {
            assert!(!plain.contains(key), "{plain}");
        }
        for (from, to, want) in [
            (
                "name = \"x\"\n",
                "name = \"x\"\ngravity = [0, 0, -2]\n",
                "gravity: must be a unit vector",
            ),
            (
                "",
                "[[masses]]\nframe = 2\nat_mm = [0, 0, 0]\nkg = 1\n",
                "masses[1].frame: must be an MDH frame 1..=1, got 2",
            ),
            (
                "",
                "[[masses]]\nframe = 1\nat_mm = [0, 0, 0]\nkg = 0\n",
                "masses[1].kg: must be greater than 0",
            ),
            (
                "",
                "[[masses]]\nframe = 1\nat_mm = [0, nan, 0]\nkg = 1\n",
                "masses[1].at_mm[1]: nan is not a finite number",
            ),
            (
                "limits_deg = [-10, 10]\n",
                "limits_deg = [-10, 10]\nharmonics_rad = [0, 1]\n",
                "harmonics_rad",
            ),
            (
                "",
                "[[torque_chain]]\ntheta_deg = 0\nd_mm = 0\na_mm = 0\nalpha_deg = 0\n\
                 [[torque_chain]]\ntheta_deg = 0\nd_mm = 0\na_mm = 0\nalpha_deg = 0\n",
                "torque_chain: must have one table per joint (1), got 2",
            ),
            (
                "",
                "[[torque_chain]]\nd_mm = 0\na_mm = 0\nalpha_deg = 0\n",
                "torque_chain[1].theta_deg|theta_rad: missing",
            ),
        ] {
            let text = if from.is_empty() {
                format!("{ONE}{to}")
            } else {
                ONE.replace(from, to)
            };
            let e = parse_robot(&text, Path::new("r.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{e} (wanted {want})");
        }
    }

    #[test]
    fn written_model_reads_back_exactly() {
        let m = perturbed();
        let text = write_robot(&m, &["one".into(), String::new(), "two".into()]);
        assert!(
            text.starts_with("# one\n#\n# two\nname = \"Staubli TX60\"\n"),
            "{text}"
        );
        let back = parse_robot(&text, Path::new("w.toml")).unwrap();
        assert_eq!(back.name, m.name);
        assert_eq!(back.joints, m.joints, "MDH bit for bit");
        assert_eq!(back.limits, m.limits, "limits bit for bit");
        assert_eq!(back.tool, m.tool);
        assert_eq!(back.base_translation, m.base_translation);
        assert!((back.base_rotation - m.base_rotation).amax() < 1e-15);
        // limits from degrees stay the degrees they were written in; angles in rad, degrees
        // in a comment
        assert!(text.contains("limits_deg = [-127.5, 127.5]"), "{text}");
        assert!(
            text.contains("theta_rad = 3.1417161103788054  # 180.007074 deg"),
            "{text}"
        );
        let rad = JointLimit {
            min: -2.0,
            max: 1.0,
        };
        let line = limits_line(&rad);
        let written = if line.starts_with("limits_deg") {
            exact_degrees(-2.0).unwrap().to_radians()
        } else {
            -2.0
        };
        assert_eq!(written, -2.0, "{line}");
    }

    #[test]
    fn both_limit_units_or_none_rejected() {
        let both = ONE.replace("[-10, 10]", "[-10, 10]\nlimits_rad = [-1, 1]");
        let e = parse_robot(&both, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("joints[1].limits_deg|limits_rad: give degrees or radians"),
            "{e}"
        );
        let none = ONE.replace("limits_deg = [-10, 10]\n", "");
        let e = parse_robot(&none, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("joints[1].limits_deg|limits_rad: missing"),
            "{e}"
        );
        let rad = ONE.replace("limits_deg = [-10, 10]", "limits_rad = [0.5, -0.5]");
        let e = parse_robot(&rad, Path::new("r.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("joints[1].limits_rad: must be [min, max]"),
            "{e}"
        );
    }
}
