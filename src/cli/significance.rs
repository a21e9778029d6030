//! `cellcal significance`: the significance indices of the MDH parameters (paper §2.2).

use std::path::PathBuf;

use anyhow::{anyhow, Context};

use cellcal::analysis::significance;
use cellcal::model::load_robot;
use cellcal::units::human::fmt_mm;

use super::{input, other, Failure};

/// Arguments of `cellcal significance`.
#[derive(clap::Args)]
pub struct SignificanceArgs {
    /// Robot model file (TOML).
    #[arg(long)]
    robot: PathBuf,
    /// Random joint configurations.
    #[arg(long, default_value_t = 50)]
    samples: usize,
    /// RNG seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write the JSON result here.
    #[arg(long, default_value = "significance.json")]
    json: PathBuf,
}

/// Print the table of ē_p, ē_n, ē_o, ē_a over random poses and write it as JSON.
pub fn run(a: SignificanceArgs) -> Result<(), Failure> {
    let (robot, samples, seed, json) = (&a.robot, a.samples, a.seed, &a.json);
    if samples == 0 {
        return Err(input(anyhow!("--samples must be at least 1")));
    }
    let m = load_robot(robot).map_err(input)?;
    let rows = significance(&m, samples, seed);
    println!("Significance indices over {samples} random poses (perturbation 0.1 mm / 0.1 rad)");
    println!(
        "{:<8} {:>12} {:>12} {:>12} {:>12}",
        "param", "ē_p (mm)", "ē_n", "ē_o", "ē_a"
    );
    for r in &rows {
        println!(
            "{:<8} {:>12} {:>12.5} {:>12.5} {:>12.5}",
            r.name,
            fmt_mm(r.e_p_mm),
            r.e_n,
            r.e_o,
            r.e_a
        );
    }
    let doc = serde_json::json!({ "samples": samples, "seed": seed, "parameters": rows });
    std::fs::write(json, serde_json::to_string_pretty(&doc).map_err(other)?)
        .with_context(|| format!("{}: cannot write", json.display()))
        .map_err(other)?;
    Ok(())
}
