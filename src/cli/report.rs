//! `cellcal report`: the calibration report of a stored campaign as one self-contained HTML
//! file (`cellcal::report::html`).

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};

use cellcal::campaign::report::campaign_report;
use cellcal::report::html::{render, ReportInput};
use cellcal::wall_clock::now_unix_ms;

use super::stored::StoredCampaignArgs;
use super::{input, other, Failure};

/// Arguments of `cellcal report`.
#[derive(clap::Args)]
pub struct ReportArgs {
    #[command(flatten)]
    source: StoredCampaignArgs,
    /// Output HTML file.
    #[arg(long)]
    out: PathBuf,
}

/// Run `cellcal report`.
pub fn run(a: ReportArgs) -> Result<(), Failure> {
    let (s, id) = a.source.open()?;
    let name = a.source.store.display().to_string();
    let report = campaign_report(&s, id, &name, now_unix_ms())
        .with_context(|| name.clone())
        .map_err(input)?
        .ok_or_else(|| {
            input(anyhow!(
                "{name}: campaign {id} has no result yet (run it to the end first)"
            ))
        })?;
    write_report(&a.out, &report)?;
    println!("wrote the report of campaign {id} to {}", a.out.display());
    Ok(())
}

/// Render `report` into `path`.
pub(crate) fn write_report(path: &Path, report: &ReportInput) -> Result<(), Failure> {
    std::fs::write(path, render(report))
        .with_context(|| format!("{}: cannot write", path.display()))
        .map_err(other)
}
