//! `cellcal select-poses`: choose identification poses by the I-optimal criterion
//! (docs/method.md §9) from a pool of poses a campaign could measure, and predict what they
//! give against as many random poses.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{anyhow, Context};
use nalgebra::{DMatrix, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use cellcal::config::RobotSection;
use cellcal::dataset::parse_vec3;
use cellcal::identify::{ObsConfig, ObsModel};
use cellcal::model::{load_robot, SignedAxis};
use cellcal::plan::campaign::{measurable_pool, more_measurable, plan_design, REFERENCE_SEED};
use cellcal::plan::selection::{
    predicted_verification, select, DesignSetup, PredictedError, Selection,
};
use cellcal::plan::{PlanRequest, Workspace};

use super::{input, other, Failure};

/// Mixed into the seed for the verification poses the figures are predicted at (a draw of
/// their own, as the criterion's reference poses are).
const VERIFY_SEED: u64 = 0x7e21_f1ed;
/// Poses of each of those draws.
const DRAW: usize = 300;

/// Arguments of `cellcal select-poses`.
#[derive(clap::Args)]
pub struct SelectPosesArgs {
    /// Robot model file (TOML), the nominal model.
    #[arg(long)]
    robot: PathBuf,
    /// Observation model the poses are chosen for: op, np, full or position.
    #[arg(long)]
    model: ObsModel,
    /// Identification poses to choose.
    #[arg(long)]
    count: usize,
    /// Candidate poses in the pool.
    #[arg(long, default_value_t = 2000)]
    candidates: usize,
    /// Seed of the pool (and of the reference and verification draws).
    #[arg(long, default_value_t = 4802)]
    seed: u64,
    /// Workspace box centre X,Y,Z (mm, robot base frame).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, default_value = "550,0,550")]
    box_center_mm: Vector3<f64>,
    /// Workspace box edge lengths A,B,C (mm).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, default_value = "1000,1000,1000")]
    box_size_mm: Vector3<f64>,
    /// Stage axis in the flange frame (+x, -x, +y, -y or X,Y,Z); default +y (np: +x).
    #[arg(long, value_parser = SignedAxis::parse, allow_hyphen_values = true)]
    stage_axis: Option<SignedAxis>,
    /// Stage travel P1 → P2 (mm).
    #[arg(long, default_value_t = 10.0)]
    stage_travel_mm: f64,
    /// Ball position in the flange frame X,Y,Z (mm).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, default_value = "0,0,0")]
    tool_mm: Vector3<f64>,
    /// Tracker per-axis σ at 2.5 m range (mm); the AT960 model σ = (15 µm + 6 µm/m·range)/2 scaled to it.
    #[arg(long, default_value_t = 0.015)]
    noise_mm: f64,
    /// Tracker position X,Y,Z (mm, robot base frame): the range of the noise model and the line of sight.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true, default_value = "2550,0,0")]
    tracker_mm: Vector3<f64>,
    /// Largest angle between the ball's opening (flange +z) and the line to the tracker (deg); 180 = no limit.
    #[arg(long, default_value_t = 180.0)]
    line_of_sight_max_deg: f64,
    /// The base (tracker frame) is known: not identified (a campaign identifies it by default).
    #[arg(long)]
    known_base: bool,
    /// The ball position is identified too.
    #[arg(long)]
    identify_tool: bool,
    /// Write the predicted σ of every parameter and the predicted verification errors here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// The chosen poses, in measuring order (CSV: pose,q1_deg,…).
    #[arg(long)]
    out: PathBuf,
}

impl SelectPosesArgs {
    /// Refuse values no selection can use.
    fn check(&self) -> anyhow::Result<()> {
        if self.count == 0 {
            return Err(anyhow!("--count must be at least 1"));
        }
        if self.candidates == 0 {
            return Err(anyhow!(
                "--candidates 0: the pool of candidate poses is empty"
            ));
        }
        if self.candidates < self.count {
            return Err(anyhow!(
                "--candidates {} is fewer than --count {}",
                self.candidates,
                self.count
            ));
        }
        for (flag, v) in [
            ("--stage-travel-mm", self.stage_travel_mm),
            ("--noise-mm", self.noise_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(anyhow!("{flag} {v}: must be a finite number > 0"));
            }
        }
        if !(self.line_of_sight_max_deg.is_finite()
            && self.line_of_sight_max_deg > 0.0
            && self.line_of_sight_max_deg <= 180.0)
        {
            return Err(anyhow!(
                "--line-of-sight-max-deg {}: must be in (0, 180]",
                self.line_of_sight_max_deg
            ));
        }
        if self.box_size_mm.iter().any(|v| *v <= 0.0) {
            return Err(anyhow!("--box-size-mm: every edge must be > 0"));
        }
        let u = self.axis().unit();
        let along = |want: Vector3<f64>| u.dot(&want).abs() > (5f64.to_radians()).cos();
        match self.model {
            ObsModel::Np if !along(Vector3::x()) => Err(anyhow!(
                "--model np needs the stage along ±x (--stage-axis +x or -x)"
            )),
            ObsModel::Op if !along(Vector3::y()) => Err(anyhow!(
                "--model op needs the stage along ±y (--stage-axis +y or -y)"
            )),
            _ => Ok(()),
        }
    }

    fn axis(&self) -> SignedAxis {
        self.stage_axis.unwrap_or(match self.model {
            ObsModel::Np => SignedAxis::PLUS_X,
            _ => SignedAxis::PLUS_Y,
        })
    }

    fn request(&self) -> PlanRequest {
        let mut obs = ObsConfig::new(self.model, self.stage_travel_mm);
        obs.stage_axis = self.axis().unit();
        PlanRequest {
            workspace: Workspace {
                center_mm: self.box_center_mm,
                size_mm: self.box_size_mm,
                ..Workspace::default()
            },
            poses: self.candidates,
            ident: self.count,
            seed: self.seed,
            tracker_mm: self.tracker_mm,
            line_of_sight_max_rad: self.line_of_sight_max_deg.to_radians(),
            tool_mm: self.tool_mm,
            drift_every: 0,
            ident_block: None,
            speed_pct: RobotSection::default().speed_pct,
            move_speed_rad_s: None,
            settle_s: 0.0,
            // the robot moves with the ball at P1 or P2: both are checked
            stage_offset_mm: obs.stage_axis * self.stage_travel_mm,
            selection: Selection::Optimal,
            design: DesignSetup {
                obs,
                stage_travel_mm: self.stage_travel_mm,
                identify_base: !self.known_base,
                identify_tool: self.identify_tool,
                noise_mm: self.noise_mm,
                joint_jitter_rad: 0.0,
            },
        }
    }
}

/// The predicted figures of one design, for the JSON.
fn figures(e: &PredictedError, poses: usize) -> serde_json::Value {
    serde_json::json!({
        "poses": poses,
        "mean_mm": e.mean_mm,
        "noise_floor_mm": e.noise_floor_mm,
        "ratio_to_floor": e.mean_mm / e.noise_floor_mm,
    })
}

/// Choose the poses, write the CSV (and the JSON), print a summary.
pub fn run(a: &SelectPosesArgs) -> Result<(), Failure> {
    a.check().map_err(input)?;
    let robot = load_robot(&a.robot).map_err(input)?;
    let req = a.request();
    let mut rng = ChaCha8Rng::seed_from_u64(a.seed);
    let pool = measurable_pool(&robot, &req, a.candidates, &mut rng).map_err(input)?;
    let draw = |seed: u64| {
        let mut r = ChaCha8Rng::seed_from_u64(a.seed ^ seed);
        more_measurable(&robot, &req, &pool.hub, pool.side, DRAW, &mut r).map_err(input)
    };
    let reference = draw(REFERENCE_SEED)?;
    let verify = draw(VERIFY_SEED)?;
    let design = plan_design(&robot, &req, &pool.poses).map_err(input)?;
    let started = std::time::Instant::now();
    let chosen = select(&design, &pool.poses, a.count, &reference).map_err(input)?;
    let took = started.elapsed().as_secs_f64();
    let selected: Vec<Vec<f64>> = chosen
        .indices
        .iter()
        .map(|&k| pool.poses[k].clone())
        .collect();
    let random = &pool.poses[..a.count];
    let cov = |set: &[Vec<f64>]| -> Result<DMatrix<f64>, Failure> {
        design
            .covariance(set)
            .ok_or_else(|| input(anyhow!("the poses do not determine every parameter")))
    };
    let (c_sel, c_rand) = (cov(&selected)?, cov(random)?);
    let e_sel = predicted_verification(&design, &c_sel, &verify);
    let e_rand = predicted_verification(&design, &c_rand, &verify);

    let mut csv = String::from("pose");
    for j in 1..=robot.dof() {
        write!(csv, ",q{j}_deg").map_err(other)?;
    }
    csv.push('\n');
    for (i, q) in selected.iter().enumerate() {
        write!(csv, "{}", i + 1).map_err(other)?;
        for v in q {
            write!(csv, ",{:.6}", v.to_degrees()).map_err(other)?;
        }
        csv.push('\n');
    }
    std::fs::write(&a.out, csv)
        .with_context(|| format!("{}: cannot write", a.out.display()))
        .map_err(other)?;

    if let Some(path) = &a.json {
        let parameters: Vec<serde_json::Value> = design
            .params
            .iter()
            .enumerate()
            .map(|(i, p)| {
                serde_json::json!({
                    "name": p.name(),
                    "unit": if p.is_angle() { "rad" } else { "mm" },
                    "sigma_selected": c_sel[(i, i)].max(0.0).sqrt(),
                    "sigma_random": c_rand[(i, i)].max(0.0).sqrt(),
                })
            })
            .collect();
        let doc = serde_json::json!({
            "model": a.model.name(),
            "count": a.count,
            "candidates": a.candidates,
            "seed": a.seed,
            "noise_mm": a.noise_mm,
            "criterion": "i_optimal",
            "parameters": parameters,
            "predicted_verification": {
                "verification_poses": verify.len(),
                "selected": figures(&e_sel, a.count),
                "random": figures(&e_rand, a.count),
            },
        });
        std::fs::write(path, serde_json::to_string_pretty(&doc).map_err(other)?)
            .with_context(|| format!("{}: cannot write", path.display()))
            .map_err(other)?;
    }
    println!(
        "{} poses chosen from {} candidates for {} ({} parameters) in {:.1} s",
        a.count,
        a.candidates,
        a.model.name(),
        design.params.len(),
        took
    );
    println!(
        "predicted verification error (mean over {} random poses): selected {:.4} mm, {} random {:.4} mm, noise floor {:.4} mm",
        verify.len(),
        e_sel.mean_mm,
        a.count,
        e_rand.mean_mm,
        e_sel.noise_floor_mm
    );
    Ok(())
}
