//! `cellcal export`: a stored campaign's measurements as an identify CSV whose header carries
//! the setup the campaign identified with (stage axis, tool, travel; the base when it was
//! given), so that `identify` on the file reproduces the campaign's own result.

use std::path::PathBuf;

use anyhow::Context;

use cellcal::campaign::stored::load_stored;

use super::stored::StoredCampaignArgs;
use super::{input, other, Failure};

/// Arguments of `cellcal export`.
#[derive(clap::Args)]
pub struct ExportArgs {
    #[command(flatten)]
    source: StoredCampaignArgs,
    /// Output CSV.
    #[arg(long)]
    out: PathBuf,
}

/// Run `cellcal export`.
pub fn run(a: ExportArgs) -> Result<(), Failure> {
    let (s, id) = a.source.open()?;
    let c = load_stored(&s, id, None)
        .with_context(|| a.source.store.display().to_string())
        .map_err(input)?;
    let csv = c.export_csv(&a.source.store.display().to_string());
    std::fs::write(&a.out, csv)
        .with_context(|| format!("{}: cannot write", a.out.display()))
        .map_err(other)?;
    println!(
        "wrote {} poses of campaign {id} to {}",
        c.rows.len(),
        a.out.display()
    );
    Ok(())
}
