//! Campaign kinds other than calibration (`campaign_kinds`): an ISO 9283 campaign and its plan.

use rusqlite::{params, OptionalExtension, Transaction};

use super::error::{Ctx, StoreError};
use super::records::{NewCampaign, PlannedPose};
use super::Store;

/// The kind name of an ISO 9283 pose accuracy/repeatability campaign.
pub const ISO9283_KIND: &str = "iso9283";

/// A campaign's kind other than calibration, with its kind's plan.
#[derive(Debug, Clone, PartialEq)]
pub struct CampaignKind {
    /// Kind name ([`ISO9283_KIND`]).
    pub kind: String,
    /// The kind's plan (a JSON object, e.g. the ISO poses with their commanded targets).
    pub plan_json: String,
}

/// Insert campaign `id`'s kind row (inside the transaction that creates the campaign).
pub(crate) fn insert_kind(
    tx: &Transaction<'_>,
    id: i64,
    kind: &CampaignKind,
) -> Result<(), StoreError> {
    tx.execute(
        "INSERT INTO campaign_kinds (campaign_id, kind, plan_json) VALUES (?1, ?2, ?3)",
        params![id, kind.kind, kind.plan_json],
    )
    .map(|_| ())
    .map_err(|e| StoreError::Invalid(format!("campaign kind `{}`: {e}", kind.kind)))
}

impl Store {
    /// [`Store::create_campaign`] of a campaign of `kind`, stored with it in the same
    /// transaction (so a campaign never exists without its kind). Returns the new id.
    pub fn create_campaign_of_kind(
        &mut self,
        campaign: &NewCampaign,
        plan: &[PlannedPose],
        kind: &CampaignKind,
    ) -> Result<i64, StoreError> {
        self.create_campaign_as(campaign, plan, Some(kind), None)
    }

    /// The kind of campaign `id`; `None` for a calibration campaign.
    pub fn campaign_kind(&self, id: i64) -> Result<Option<CampaignKind>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT kind, plan_json FROM campaign_kinds WHERE campaign_id = ?1",
                [id],
                |r| {
                    Ok(CampaignKind {
                        kind: r.get(0)?,
                        plan_json: r.get(1)?,
                    })
                },
            )
            .optional()
            .ctx("read the campaign kind")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::PoseSet;

    #[test]
    fn kind_is_stored_with_the_campaign() {
        let mut s = Store::open_in_memory().unwrap();
        let c = NewCampaign {
            name: "iso".into(),
            created_at_ms: 1,
            model: "op".into(),
            seed: 1,
            config_toml: String::new(),
            robot_toml: String::new(),
        };
        let plan = [PlannedPose {
            index: 0,
            set: PoseSet::Ident,
            order: 0,
            q_rad: vec![0.0; 6],
        }];
        let plain = s.create_campaign(&c, &plan).unwrap();
        assert_eq!(s.campaign_kind(plain).unwrap(), None);
        let kind = CampaignKind {
            kind: ISO9283_KIND.into(),
            plan_json: "{\"cycles\": 2}".into(),
        };
        let iso = s.create_campaign_of_kind(&c, &plan, &kind).unwrap();
        assert_eq!(s.campaign_kind(iso).unwrap(), Some(kind));
        let bad = CampaignKind {
            kind: "dance".into(),
            plan_json: "{}".into(),
        };
        assert!(s.create_campaign_of_kind(&c, &plan, &bad).is_err());
        assert_eq!(
            s.list_campaigns().unwrap().len(),
            2,
            "nothing of the refused one"
        );
    }
}
