//! `cellcal import`: an identify CSV as a new, fully measured campaign.

use std::path::PathBuf;

use anyhow::Context;

use cellcal::dataset::{parse_csv, Required};
use cellcal::identify::ObsModel;
use cellcal::model::load_robot;
use cellcal::store::{NewCampaign, Store};

use super::{input, Failure};

/// Arguments of `cellcal import`.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// Store file.
    #[arg(long)]
    store: PathBuf,
    /// Robot model file (TOML).
    #[arg(long)]
    robot: PathBuf,
    /// Input CSV.
    #[arg(long)]
    data: PathBuf,
    /// Observation model recorded with the campaign.
    #[arg(long, default_value = "op", value_parser = ObsModel::parse)]
    model: ObsModel,
}

/// `cellcal import`: a CSV data set as a new, fully measured campaign.
pub fn run(a: ImportArgs) -> Result<(), Failure> {
    let (store, robot, data, model) = (&a.store, &a.robot, &a.data, a.model.name());
    let m = load_robot(robot).map_err(input)?;
    let text = std::fs::read_to_string(data)
        .with_context(|| format!("{}: cannot read", data.display()))
        .map_err(input)?;
    let rows = parse_csv(&text, m.dof(), Required::default())
        .with_context(|| data.display().to_string())
        .map_err(input)?;
    let mut s = Store::open(store).map_err(input)?;
    let now = cellcal::wall_clock::now_unix_ms();
    let id = s
        .import_observations(
            &NewCampaign {
                name: format!("import {}", data.display()),
                created_at_ms: now,
                model: model.to_owned(),
                seed: 0,
                config_toml: String::new(),
                robot_toml: std::fs::read_to_string(robot).unwrap_or_default(),
            },
            &rows,
        )
        .map_err(input)?;
    println!(
        "imported {} poses as campaign {id} into {}",
        rows.len(),
        store.display()
    );
    Ok(())
}
