//! Time of a campaign: its planned duration (`campaign_estimates`, written with the campaign)
//! and what its journal says of when things happened (the entries of one kind, each with the
//! time of the entry before it, and the time of the last entry). The planned duration is kept
//! as the JSON object the planner wrote; this module does not know its fields.

use rusqlite::{params, OptionalExtension, Transaction};

use super::error::{Ctx, StoreError};
use super::kinds::CampaignKind;
use super::records::{JournalEntry, JournalEvent, NewCampaign, PlannedPose};
use super::Store;

/// A journal entry with the time of the campaign's entry before it (`None`: the first), entries
/// of an ignored kind skipped ([`Store::entries_of_kind`]).
#[derive(Debug, Clone, PartialEq)]
pub struct EntryAfter<E> {
    /// The entry.
    pub entry: JournalEntry<E>,
    /// When the campaign's previous journal entry (not of the ignored kind) was written (ms
    /// since the Unix epoch): where a process that died without a last word stopped, when this
    /// entry starts a new one.
    pub previous_at_ms: Option<i64>,
}

/// Insert campaign `id`'s planned duration (inside the transaction that creates the campaign).
pub(crate) fn insert_estimate(tx: &Transaction<'_>, id: i64, json: &str) -> Result<(), StoreError> {
    tx.execute(
        "INSERT INTO campaign_estimates (campaign_id, json) VALUES (?1, ?2)",
        params![id, json],
    )
    .map(|_| ())
    .map_err(|e| StoreError::Invalid(format!("the campaign's estimate: {e}")))
}

impl Store {
    /// [`Store::create_campaign`] (of `kind`, none: a calibration) with its planned duration
    /// `estimate_json` (a JSON object) stored in the same transaction, so the campaign is shown
    /// with the same estimate for as long as it is stored. Returns the new id.
    pub fn create_campaign_estimated(
        &mut self,
        campaign: &NewCampaign,
        plan: &[PlannedPose],
        kind: Option<&CampaignKind>,
        estimate_json: &str,
    ) -> Result<i64, StoreError> {
        self.create_campaign_as(campaign, plan, kind, Some(estimate_json))
    }

    /// The planned duration stored with campaign `id` (its JSON object); `None` for a campaign
    /// created without one.
    pub fn campaign_estimate(&self, id: i64) -> Result<Option<String>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT json FROM campaign_estimates WHERE campaign_id = ?1",
                [id],
                |r| r.get(0),
            )
            .optional()
            .ctx("read the campaign's estimate")
    }

    /// The campaign's journal entries of `kind`, oldest first, each with the time of the
    /// campaign's entry before it that is not of `ignored` kind; typed as
    /// [`Store::events_after`].
    pub fn entries_of_kind<E: JournalEvent>(
        &self,
        id: i64,
        kind: &str,
        ignored: &str,
    ) -> Result<Vec<EntryAfter<E>>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT e.id, e.at_ms, e.kind, e.message, \
                        (SELECT p.at_ms FROM events p WHERE p.campaign_id = ?1 AND p.id < e.id \
                         AND p.kind <> ?3 ORDER BY p.id DESC LIMIT 1) \
                 FROM events e WHERE e.campaign_id = ?1 AND e.kind = ?2 ORDER BY e.id",
            )
            .ctx("read events of a kind")?;
        let rows = st
            .query_map(params![id, kind, ignored], |r| {
                Ok(EntryAfter {
                    entry: JournalEntry {
                        seq: r.get(0)?,
                        at_ms: r.get(1)?,
                        event: E::from_stored(r.get(2)?, r.get(3)?),
                    },
                    previous_at_ms: r.get(4)?,
                })
            })
            .ctx("read events of a kind")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read events of a kind")?;
        Ok(rows)
    }

    /// When the campaign's newest journal entry not of `ignored` kind was written (ms since the
    /// Unix epoch); `None` without one.
    pub fn last_event_at(&self, id: i64, ignored: &str) -> Result<Option<i64>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT at_ms FROM events WHERE campaign_id = ?1 AND kind <> ?2 \
                 ORDER BY id DESC LIMIT 1",
                params![id, ignored],
                |r| r.get(0),
            )
            .optional()
            .ctx("read the last event's time")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::PoseSet;

    /// A journal event that is its kind and text.
    #[derive(Debug, PartialEq)]
    struct Raw(String, String);

    impl JournalEvent for Raw {
        fn kind(&self) -> &str {
            &self.0
        }
        fn to_text(&self) -> Result<String, StoreError> {
            Ok(self.1.clone())
        }
        fn from_stored(kind: String, text: String) -> Raw {
            Raw(kind, text)
        }
    }

    fn new() -> (NewCampaign, [PlannedPose; 1]) {
        let c = NewCampaign {
            name: "c".into(),
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
        (c, plan)
    }

    #[test]
    fn the_estimate_is_stored_with_the_campaign_and_never_changes() {
        let mut s = Store::open_in_memory().unwrap();
        let (c, plan) = new();
        let plain = s.create_campaign(&c, &plan).unwrap();
        assert_eq!(s.campaign_estimate(plain).unwrap(), None);
        let json = r#"{"poses": 1, "total_s": 12.5}"#;
        let id = s.create_campaign_estimated(&c, &plan, None, json).unwrap();
        assert_eq!(s.campaign_estimate(id).unwrap().as_deref(), Some(json));
        // not an object: refused, and nothing of the campaign is stored
        assert!(s.create_campaign_estimated(&c, &plan, None, "[1]").is_err());
        assert_eq!(s.list_campaigns().unwrap().len(), 2);
        let e = s
            .conn
            .execute("UPDATE campaign_estimates SET json = '{}'", [])
            .unwrap_err()
            .to_string();
        assert!(e.contains("append-only"), "{e}");
    }

    #[test]
    fn entries_of_a_kind_come_with_the_time_of_the_entry_before() {
        let mut s = Store::open_in_memory().unwrap();
        let (c, plan) = new();
        let id = s.create_campaign(&c, &plan).unwrap();
        assert_eq!(s.last_event_at(id, "note").unwrap(), None);
        for (at, kind) in [
            (10, "state"),
            (20, "measured"),
            (25, "fault"),
            (30, "note"),
            (40, "state"),
            (50, "note"),
        ] {
            s.add_event(id, at, &Raw(kind.into(), "{}".into())).unwrap();
        }
        let got = |ignored: &str| -> Vec<_> {
            s.entries_of_kind::<Raw>(id, "state", ignored)
                .unwrap()
                .into_iter()
                .map(|e| (e.entry.at_ms, e.previous_at_ms))
                .collect()
        };
        assert_eq!(got("note"), [(10, None), (40, Some(25))]);
        assert_eq!(got("fault"), [(10, None), (40, Some(30))]);
        assert_eq!(s.last_event_at(id, "note").unwrap(), Some(40));
        assert_eq!(s.last_event_at(id, "fault").unwrap(), Some(50));
    }
}
