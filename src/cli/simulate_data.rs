//! `cellcal simulate-data`: a simulated measurement campaign (CSV + truth JSON) for dry runs
//! and tests.

use std::path::PathBuf;

use anyhow::{anyhow, Context};
use nalgebra::Vector3;

use cellcal::dataset::{parse_vec3, write_csv};
use cellcal::model::rotation::{from_rotation_vector, to_rotation_vector};
use cellcal::model::SignedAxis;
use cellcal::model::{load_robot, RobotModel};
use cellcal::simulate::{self, truth, SimConfig, TrackerNoise};

use super::{input, other, Failure};

#[derive(clap::Args)]
/// Arguments of `cellcal simulate-data`.
pub struct SimArgs {
    /// Robot model file (TOML), the nominal model.
    #[arg(long)]
    robot: PathBuf,
    /// Output CSV.
    #[arg(long)]
    out: PathBuf,
    /// Output truth JSON (default: OUT with .truth.json).
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Total poses.
    #[arg(long, default_value_t = 300)]
    poses: usize,
    /// Identification poses (the rest verify).
    #[arg(long, default_value_t = 100)]
    ident: usize,
    /// RNG seed.
    #[arg(long, default_value_t = 4802)]
    seed: u64,
    /// True errors: `paper` (docs/method.md §7), `random`, or a JSON/TOML file of name = value.
    #[arg(long, default_value = "paper")]
    errors: String,
    /// Seed of `--errors random` and `--nongeometric-errors typical`.
    #[arg(long, default_value_t = 1)]
    error_seed: u64,
    /// True joint compliance C1,…,Cn (rad/(N·m)): joint j deflects by c_j·τ_j, τ_j its gravity torque from the robot file's [[masses]].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    compliance_rad_per_nm: Option<Vec<f64>>,
    /// True harmonic errors (µrad), four per joint from joint 1: sin q, cos q, sin 2q, cos 2q.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    harmonics_urad: Option<Vec<f64>>,
    /// Generated non-geometric errors: `none` or `typical` (seeded by --error-seed; not with the explicit values).
    #[arg(long, default_value = "none", value_parser = ["none", "typical"])]
    nongeometric_errors: String,
    /// Stage axis in the flange frame: +x, -x, +y, -y, +z, -z or a vector X,Y,Z (normalised).
    #[arg(long, value_parser = SignedAxis::parse, default_value = "+y", allow_hyphen_values = true)]
    stage_axis: SignedAxis,
    /// Stage travel (mm).
    #[arg(long, default_value_t = 10.0)]
    stage_travel_mm: f64,
    /// Stage axis misalignment, rotation vector X,Y,Z (mrad).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    stage_misalignment_mrad: Option<Vector3<f64>>,
    /// Systematic cross-travel deviation (mm per mm of travel).
    #[arg(long, default_value_t = 0.0)]
    stage_cross_mm_per_mm: f64,
    /// Stage repeatability σ (mm).
    #[arg(long, default_value_t = 0.0)]
    stage_repeatability_mm: f64,
    /// True ball position in the flange frame X,Y,Z (mm).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    tool_mm: Option<Vector3<f64>>,
    /// True base translation (robot base origin in the measurement frame) X,Y,Z (mm).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    base_translation_mm: Option<Vector3<f64>>,
    /// True base rotation vector X,Y,Z (deg).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    base_rotvec_deg: Option<Vector3<f64>>,
    /// Tracker position in the measurement frame X,Y,Z (mm); default (2550,0,0), or the origin when a base is given.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    tracker_pos_mm: Option<Vector3<f64>>,
    /// Joint jitter σ (rad).
    #[arg(long, default_value_t = 1.2746e-5)]
    joint_jitter_rad: f64,
    /// No tracker noise and no joint jitter.
    #[arg(long)]
    no_noise: bool,
    /// Fraction of poses that are gross outliers.
    #[arg(long, default_value_t = 0.0)]
    outliers: f64,
    /// Gross outlier size (mm).
    #[arg(long, default_value_t = 1.0)]
    outlier_mm: f64,
    /// Workspace box centre X,Y,Z (mm, robot base frame).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    box_center_mm: Option<Vector3<f64>>,
    /// Workspace box edge (mm).
    #[arg(long, default_value_t = 1000.0)]
    box_size_mm: f64,
}

fn load_errors(spec: &str, dof: usize, seed: u64) -> anyhow::Result<truth::ErrorTable> {
    match spec {
        "paper" => {
            if dof != 6 {
                return Err(anyhow!("--errors paper needs a six-joint robot"));
            }
            Ok(truth::paper_errors())
        }
        "random" => Ok(truth::random_errors(dof, seed)),
        path => {
            let text =
                std::fs::read_to_string(path).with_context(|| format!("{path}: cannot read"))?;
            let table: truth::ErrorTable = if path.ends_with(".json") {
                serde_json::from_str(&text).with_context(|| path.to_owned())?
            } else {
                toml::from_str(&text).with_context(|| path.to_owned())?
            };
            Ok(table)
        }
    }
}

/// Simulate the campaign, write the CSV and the truth JSON.
pub fn run(a: &SimArgs) -> Result<(), Failure> {
    let nominal = load_robot(&a.robot).map_err(input)?;
    if a.ident == 0 || a.ident > a.poses {
        return Err(input(anyhow!("--ident must be between 1 and --poses")));
    }
    if !(0.0..=0.5).contains(&a.outliers) {
        return Err(input(anyhow!(
            "--outliers must be a fraction between 0 and 0.5"
        )));
    }
    let errors = load_errors(&a.errors, nominal.dof(), a.error_seed).map_err(input)?;
    let true_model = true_robot(a, &nominal, &errors)?;
    let has_base = a.base_translation_mm.is_some() || a.base_rotvec_deg.is_some();
    let tracker_pos = a.tracker_pos_mm.unwrap_or(if has_base {
        Vector3::zeros()
    } else {
        Vector3::new(2550.0, 0.0, 0.0)
    });
    let cfg = sim_config(a, tracker_pos);
    let sim = simulate::simulate(&nominal, &true_model, &cfg).map_err(input)?;
    let comment = format!(
        "cellcal simulate-data: robot {}, seed {}, errors {}, stage axis {:?} travel {} mm\nP2 = P1 + travel * R * u; q in rad; positions in mm (measurement frame)",
        nominal.name,
        a.seed,
        a.errors,
        cfg.stage_axis.as_slice(),
        cfg.stage_travel_mm
    );
    std::fs::write(
        &a.out,
        write_csv(&sim.observations, nominal.dof(), &comment),
    )
    .with_context(|| format!("{}: cannot write", a.out.display()))
    .map_err(other)?;
    let truth_path = a
        .truth
        .clone()
        .unwrap_or_else(|| a.out.with_extension("truth.json"));
    let doc = truth_json(
        a,
        &nominal,
        &true_model,
        &errors,
        &cfg,
        tracker_pos,
        &sim.outliers,
    );
    std::fs::write(
        &truth_path,
        serde_json::to_string_pretty(&doc).map_err(other)?,
    )
    .with_context(|| format!("{}: cannot write", truth_path.display()))
    .map_err(other)?;
    println!(
        "wrote {} poses ({} ident, {} verify) to {} and the truth to {}",
        a.poses,
        a.ident,
        a.poses - a.ident,
        a.out.display(),
        truth_path.display()
    );
    Ok(())
}

/// The simulated true robot: the nominal model with the error table, and the given tool and
/// base.
fn true_robot(
    a: &SimArgs,
    nominal: &RobotModel,
    errors: &truth::ErrorTable,
) -> Result<RobotModel, Failure> {
    let mut true_model = truth::apply_errors(nominal, errors)
        .map_err(|e| input(anyhow!("--errors {}: {e}", a.errors)))?;
    true_model = truth::apply_terms(&true_model, &term_errors(a, nominal.dof())?)
        .map_err(|e| {
            input(anyhow!(
                "non-geometric errors (--compliance-rad-per-nm, --harmonics-urad, --nongeometric-errors): {e}"
            ))
        })?;
    if let Some(t) = a.tool_mm {
        true_model.tool = t;
    }
    if let Some(t) = a.base_translation_mm {
        true_model.base_translation = t;
    }
    if let Some(r) = a.base_rotvec_deg {
        true_model.base_rotation = from_rotation_vector(&(r * std::f64::consts::PI / 180.0));
    }
    Ok(true_model)
}

/// The non-geometric errors of the arguments (`--harmonics-urad` in rows of four, rad).
fn term_errors(a: &SimArgs, dof: usize) -> Result<truth::TermErrors, Failure> {
    let harmonics_rad = match &a.harmonics_urad {
        Some(v) if v.len() != 4 * dof => {
            return Err(input(anyhow!(
                "--harmonics-urad: {} values for {dof} joints (four per joint: sin q, cos q, sin 2q, cos 2q)",
                v.len()
            )))
        }
        Some(v) => Some(
            v.chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]].map(|x| x * 1e-6))
                .collect(),
        ),
        None => None,
    };
    Ok(truth::TermErrors {
        compliance_rad_per_nm: a.compliance_rad_per_nm.clone(),
        harmonics_rad,
        typical_seed: (a.nongeometric_errors == "typical").then_some(a.error_seed),
    })
}

/// The simulation settings of the arguments (noise off with `--no-noise`).
fn sim_config(a: &SimArgs, tracker_pos: Vector3<f64>) -> SimConfig {
    let mut cfg = SimConfig {
        poses: a.poses,
        ident: a.ident,
        seed: a.seed,
        tracker: (!a.no_noise).then(|| TrackerNoise::at960(tracker_pos)),
        joint_jitter_rad: if a.no_noise { 0.0 } else { a.joint_jitter_rad },
        stage_travel_mm: a.stage_travel_mm,
        stage_axis: a.stage_axis.unit(),
        stage_misalignment_rad: a.stage_misalignment_mrad.unwrap_or_else(Vector3::zeros) / 1000.0,
        stage_cross_mm_per_mm: a.stage_cross_mm_per_mm,
        stage_repeatability_mm: a.stage_repeatability_mm,
        outlier_fraction: a.outliers,
        outlier_mm: a.outlier_mm,
        ..SimConfig::default()
    };
    if let Some(c) = a.box_center_mm {
        cfg.workspace.center_mm = c;
    }
    cfg.workspace.size_mm = Vector3::repeat(a.box_size_mm);
    cfg
}

/// The truth JSON: errors, true MDH, base, tool, noise, stage and outliers of the simulation.
fn truth_json(
    a: &SimArgs,
    nominal: &RobotModel,
    true_model: &RobotModel,
    errors: &truth::ErrorTable,
    cfg: &SimConfig,
    tracker_pos: Vector3<f64>,
    outliers: &[usize],
) -> serde_json::Value {
    serde_json::json!({
        "robot": nominal.name,
        "seed": a.seed,
        "errors": errors,
        "true_mdh": true_model.joints.iter().map(|j| [j.theta, j.d, j.a, j.alpha, j.beta]).collect::<Vec<_>>(),
        "base": {
            "translation_mm": true_model.base_translation.as_slice(),
            "rotation_vector_rad": to_rotation_vector(&true_model.base_rotation).as_slice(),
        },
        "tool": { "translation_mm": true_model.tool.as_slice() },
        "true_terms": {
            "compliance_rad_per_nm": true_model.terms.iter().map(|t| t.compliance).collect::<Vec<_>>(),
            "harmonics_rad": true_model.terms.iter().map(|t| t.harmonics).collect::<Vec<_>>(),
        },
        "noise": {
            "tracker_position_mm": tracker_pos.as_slice(),
            "tracker_sigma": if a.no_noise { "none".to_owned() } else { "(15 um + 6 um/m * range)/2 per axis".to_owned() },
            "joint_jitter_rad": cfg.joint_jitter_rad,
        },
        "stage": {
            "axis": cfg.stage_axis.as_slice(),
            "travel_mm": cfg.stage_travel_mm,
            "misalignment_rad": cfg.stage_misalignment_rad.as_slice(),
            "cross_mm_per_mm": cfg.stage_cross_mm_per_mm,
            "repeatability_mm": cfg.stage_repeatability_mm,
        },
        "outlier_poses": outliers.iter().map(|i| i.to_string()).collect::<Vec<_>>(),
        "poses": a.poses,
        "ident": a.ident,
    })
}
