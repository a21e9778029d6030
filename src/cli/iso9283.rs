//! `cellcal iso9283`: the ISO 9283 pose accuracy and repeatability of a stored ISO campaign,
//! recomputed from the store alone (`cellcal::campaign::iso::iso_report`).

use std::path::PathBuf;

use anyhow::anyhow;

use cellcal::campaign::iso::{iso_report, IsoResultError};
use cellcal::iso9283::format_table;

use super::identify::write_file;
use super::stored::StoredCampaignArgs;
use super::{input, other, Failure};

/// Arguments of `cellcal iso9283`.
#[derive(clap::Args)]
pub struct Iso9283Args {
    #[command(flatten)]
    source: StoredCampaignArgs,
    /// Also write the figures as JSON (`"kind": "iso9283"`, mm and deg).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Run `cellcal iso9283`: exit 2 when the campaign is not an ISO campaign or has fewer than 2
/// complete cycles.
pub fn run(a: Iso9283Args) -> Result<(), Failure> {
    let (s, id) = a.source.open()?;
    let name = a.source.store.display().to_string();
    let report = iso_report(&s, id).map_err(|e| match e {
        IsoResultError::NotIso(_)
        | IsoResultError::TooFewCycles { .. }
        | IsoResultError::NoFrame(_) => input(anyhow!("{name}: {e}")),
        _ => other(anyhow!("{name}: {e}")),
    })?;
    print!("{}", format_table(&report));
    if report.partial {
        println!(
            "campaign {id} is measured in part: the figures use its {} complete cycles of {}",
            report.cycles_complete, report.cycles_planned
        );
    }
    if let Some(path) = &a.json {
        let text = serde_json::to_string_pretty(&report).map_err(other)?;
        write_file(path, &text)?;
    }
    Ok(())
}
