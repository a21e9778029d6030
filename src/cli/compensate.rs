//! `cellcal compensate`: joints for the real robot (the identified model) from tool targets in
//! the measurement frame (`--targets`) or from a program computed on the nominal model
//! (`--joints`); file formats in [`cellcal::compensate::table`], the rules in
//! [`cellcal::compensate`].

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};

use cellcal::compensate::table::{parse_joints, parse_targets, write_joints, Row};
use cellcal::compensate::{Compensated, Compensator};
use cellcal::model::{load_robot, JointTerms, RobotModel};
use cellcal::units::human::{fmt_deg, fmt_mm, fmt_mrad};

use super::identify::write_file;
use super::{input, Failure};

/// The default start of the first target's nominal solution (deg): elbow up, wrist on its
/// positive side — the ready pose of a TX60-like six-axis arm.
const DEFAULT_START_DEG: [f64; 6] = [0.0, 30.0, 90.0, 0.0, 45.0, 0.0];

/// Arguments of `cellcal compensate`.
#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("input").required(true).args(["targets", "joints"])))]
pub struct CompensateArgs {
    /// The nominal robot model (the controller's; its joint limits apply).
    #[arg(long)]
    robot: PathBuf,
    /// The identified model (`identify --model-out`, `run --model-out`, `GET
    /// /api/campaigns/{id}/model`).
    #[arg(long)]
    identified: PathBuf,
    /// Tool targets: `x_mm,y_mm,z_mm` and optionally `rx_deg,ry_deg,rz_deg` (rotation vector),
    /// in the identified model's measurement frame.
    #[arg(long)]
    targets: Option<PathBuf>,
    /// A program's joints computed on the nominal model: `q1`…`qn` (rad) or `q1_deg`…`qn_deg`.
    #[arg(long)]
    joints: Option<PathBuf>,
    /// Output CSV: `id,q1…qn,reachable,residual_mm,residual_deg,at_limit,q1_deg…qn_deg`.
    #[arg(long)]
    out: PathBuf,
    /// Joints (deg, comma-separated) the first target's nominal solution starts from; its
    /// branch (shoulder, elbow, wrist) is the one every target keeps. Default 0,30,90,0,45,0
    /// for six joints.
    #[arg(long, allow_hyphen_values = true)]
    start_deg: Option<String>,
}

/// Read a text file (exit 2 when it cannot).
fn read(path: &Path) -> Result<String, Failure> {
    std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))
        .map_err(input)
}

/// The start joints (rad) from `--start-deg`, or the default for six joints.
pub(super) fn start(given: Option<&str>, dof: usize) -> Result<Vec<f64>, Failure> {
    let deg: Vec<f64> = match given {
        None if dof == DEFAULT_START_DEG.len() => DEFAULT_START_DEG.to_vec(),
        None => {
            return Err(input(anyhow!(
                "the robot has {dof} joints: give --start-deg with {dof} values"
            )))
        }
        Some(s) => s
            .split(',')
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        input(anyhow!(
                            "--start-deg: `{}` is not a finite number",
                            v.trim()
                        ))
                    })
            })
            .collect::<Result<_, _>>()?,
    };
    if deg.len() != dof {
        return Err(input(anyhow!(
            "--start-deg has {} values; the robot has {dof} joints",
            deg.len()
        )));
    }
    Ok(deg.iter().map(|d| d.to_radians()).collect())
}

/// Run `cellcal compensate`: write the output file, print a summary; exit 3 when a row is
/// unreachable (the file is written all the same).
pub fn run(a: CompensateArgs) -> Result<(), Failure> {
    let nominal: RobotModel = load_robot(&a.robot).map_err(input)?;
    let identified = load_robot(&a.identified).map_err(input)?;
    let comp = Compensator::new(&nominal, &identified)
        .with_context(|| format!("{} against {}", a.identified.display(), a.robot.display()))
        .map_err(input)?;
    let (ids, rows) = match (&a.targets, &a.joints) {
        (Some(path), _) => {
            let targets = parse_targets(&read(path)?)
                .with_context(|| path.display().to_string())
                .map_err(input)?;
            let q0 = start(a.start_deg.as_deref(), comp.dof())?;
            let values: Vec<_> = targets.iter().map(|r| r.value).collect();
            let rows = comp.targets(&values, &q0).map_err(input)?;
            (ids(&targets), rows)
        }
        (None, Some(path)) => {
            let program = parse_joints(&read(path)?, comp.dof())
                .with_context(|| path.display().to_string())
                .map_err(input)?;
            let rows = program
                .iter()
                .map(|r| {
                    comp.program_point(&r.value)
                        .with_context(|| format!("{}: line {}", path.display(), r.line))
                        .map_err(input)
                })
                .collect::<Result<Vec<_>, _>>()?;
            (ids(&program), rows)
        }
        (None, None) => return Err(input(anyhow!("give --targets CSV or --joints CSV"))),
    };
    write_file(&a.out, &write_joints(&ids, &rows, comp.dof()))?;
    print!("{}", terms_line(comp.identified()));
    print!("{}", summary(&ids, &rows, &a.out));
    let unreachable = rows.iter().filter(|r| !r.reachable).count();
    if unreachable > 0 {
        return Err(Failure(
            3,
            anyhow!(
                "{unreachable} of {} rows are not reachable (reachable = false in {})",
                rows.len(),
                a.out.display()
            ),
        ));
    }
    Ok(())
}

/// Which non-geometric terms of the identified model the joints account for (empty without).
fn terms_line(m: &RobotModel) -> String {
    if !m.has_terms() {
        return String::new();
    }
    let joints = |f: &dyn Fn(&JointTerms) -> bool| -> String {
        let j: Vec<String> = m
            .terms
            .iter()
            .enumerate()
            .filter(|(_, t)| f(t))
            .map(|(i, _)| (i + 1).to_string())
            .collect();
        if j.is_empty() {
            "none".to_owned()
        } else {
            j.join(", ")
        }
    };
    format!(
        "the joints account for the identified model's non-geometric terms (docs/method.md §10): \
         compliance on joints {} (gravity torques from {} masses), harmonics on joints {}\n",
        joints(&|t| t.compliance != 0.0),
        m.masses.len(),
        joints(&|t| t.harmonics.iter().any(|h| *h != 0.0)),
    )
}

/// The row ids of an input file.
fn ids<T>(rows: &[Row<T>]) -> Vec<String> {
    rows.iter().map(|r| r.id.clone()).collect()
}

/// What was written: counts, the largest joint correction, the unreachable rows.
fn summary(ids: &[String], rows: &[Compensated], out: &Path) -> String {
    let reachable: Vec<&Compensated> = rows.iter().filter(|r| r.reachable).collect();
    let largest = reachable
        .iter()
        .flat_map(|r| r.q.iter().zip(&r.nominal_q).map(|(a, b)| (a - b).abs()))
        .fold(0.0, f64::max);
    let mut s = format!(
        "compensated {} rows into {}: {} reachable, largest joint correction {} mrad ({}°)\n",
        rows.len(),
        out.display(),
        reachable.len(),
        fmt_mrad(largest),
        fmt_deg(largest)
    );
    for (id, r) in ids.iter().zip(rows).filter(|(_, r)| !r.reachable) {
        let limits: Vec<String> = r.at_limit.iter().map(|j| format!("q{j}")).collect();
        s.push_str(&format!(
            "  {id}: not reachable, {} mm and {} mrad left{}\n",
            fmt_mm(r.residual_mm),
            fmt_mrad(r.residual_rad),
            if limits.is_empty() {
                String::new()
            } else {
                format!(", limit binds: {}", limits.join(" "))
            }
        ));
    }
    s
}
