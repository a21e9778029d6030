//! `--store FILE [--campaign ID]`, the stored campaign of `identify`, `export`, `report` and
//! `iso9283`, and opening an existing store.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use cellcal::store::Store;

use super::{input, Failure};

/// `--store FILE [--campaign ID]`: a stored campaign (default: the store's latest).
#[derive(clap::Args)]
pub struct StoredCampaignArgs {
    /// Store file.
    #[arg(long)]
    pub store: PathBuf,
    /// Campaign id (default: the latest).
    #[arg(long)]
    pub campaign: Option<i64>,
}

impl StoredCampaignArgs {
    /// The open store and the campaign's id.
    pub fn open(&self) -> Result<(Store, i64), Failure> {
        let s = open_store(&self.store)?;
        let id = campaign_id(&s, &self.store, self.campaign)?;
        Ok((s, id))
    }
}

/// Open an existing store (a missing file is an error, not a new store).
pub(crate) fn open_store(path: &Path) -> Result<Store, Failure> {
    if !path.is_file() {
        return Err(input(anyhow!("{}: no such store file", path.display())));
    }
    Store::open(path).map_err(input)
}

/// The given campaign id, or the store's latest.
pub(crate) fn campaign_id(s: &Store, path: &Path, given: Option<i64>) -> Result<i64, Failure> {
    match given {
        Some(id) => Ok(id),
        None => s
            .latest_campaign()
            .map_err(input)?
            .ok_or_else(|| input(anyhow!("{}: no campaign", path.display()))),
    }
}
