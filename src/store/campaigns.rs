//! Campaigns, plans, state, events and setup results (identification results: `results.rs`).

use std::collections::HashSet;

use rusqlite::{params, OptionalExtension, Row, Transaction, TransactionBehavior};

use super::error::{Ctx, StoreError};
use super::estimates::insert_estimate;
use super::kinds::{insert_kind, CampaignKind};
use super::records::{
    decode_joints, encode_joints, from_sql_index, parse_set, to_sql_index, CampaignRow,
    JournalEntry, JournalEvent, NewCampaign, PlannedPose, StoredState,
};
use super::Store;

/// State of a freshly created campaign.
pub const INITIAL_STATE: StoredState = StoredState::Created;

const CAMPAIGN_COLUMNS: &str =
    "id, name, created_at_ms, state, model, seed, config_toml, robot_toml";

fn campaign_row(r: &Row<'_>) -> rusqlite::Result<CampaignRow> {
    Ok(CampaignRow {
        id: r.get(0)?,
        name: r.get(1)?,
        created_at_ms: r.get(2)?,
        state: r.get(3)?,
        model: r.get(4)?,
        // The u64 seed is stored as the i64 with the same bits.
        seed: r.get::<_, i64>(5)? as u64,
        config_toml: r.get(6)?,
        robot_toml: r.get(7)?,
    })
}

/// Check a plan before writing it: not empty, indices and orders unique, one joint count,
/// finite joints. Returns the encoded joint vectors.
pub(crate) fn check_plan(plan: &[PlannedPose]) -> Result<Vec<String>, StoreError> {
    if plan.is_empty() {
        return Err(StoreError::Invalid("the plan has no poses".into()));
    }
    let dof = plan[0].q_rad.len();
    let mut indices = HashSet::new();
    let mut orders = HashSet::new();
    plan.iter()
        .map(|p| {
            if !indices.insert(p.index) {
                return Err(StoreError::Invalid(format!(
                    "pose index {} twice in the plan",
                    p.index
                )));
            }
            if !orders.insert(p.order) {
                return Err(StoreError::Invalid(format!(
                    "move order {} twice in the plan",
                    p.order
                )));
            }
            if p.q_rad.len() != dof {
                return Err(StoreError::Invalid(format!(
                    "plan pose {} has {} joints, pose {} has {dof}",
                    p.index,
                    p.q_rad.len(),
                    plan[0].index
                )));
            }
            encode_joints(&p.q_rad, &format!("plan pose {}", p.index))
        })
        .collect()
}

impl Store {
    /// Create a campaign and its whole plan in one transaction (state [`INITIAL_STATE`]).
    /// The plan must be non-empty with unique pose indices and move orders and one joint
    /// count. Returns the new campaign id.
    pub fn create_campaign(
        &mut self,
        campaign: &NewCampaign,
        plan: &[PlannedPose],
    ) -> Result<i64, StoreError> {
        self.create_campaign_as(campaign, plan, None, None)
    }

    /// [`Store::create_campaign`], with the campaign's `kind` (none: a calibration) and its
    /// planned duration (`estimate_json`, a JSON object; none: not estimated) in the same
    /// transaction.
    pub(crate) fn create_campaign_as(
        &mut self,
        campaign: &NewCampaign,
        plan: &[PlannedPose],
        kind: Option<&CampaignKind>,
        estimate_json: Option<&str>,
    ) -> Result<i64, StoreError> {
        let encoded = check_plan(plan)?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin create campaign")?;
        let id = insert_campaign(&tx, campaign, plan, &encoded)?;
        if let Some(k) = kind {
            insert_kind(&tx, id, k)?;
        }
        if let Some(json) = estimate_json {
            insert_estimate(&tx, id, json)?;
        }
        tx.commit().ctx("commit create campaign")?;
        Ok(id)
    }

    /// The campaign `id`.
    pub fn campaign(&self, id: i64) -> Result<CampaignRow, StoreError> {
        self.conn
            .query_row(
                &format!("SELECT {CAMPAIGN_COLUMNS} FROM campaigns WHERE id = ?1"),
                [id],
                campaign_row,
            )
            .optional()
            .ctx("read a campaign")?
            .ok_or(StoreError::NoCampaign(id))
    }

    /// Id of the most recently created campaign, if any.
    pub fn latest_campaign(&self) -> Result<Option<i64>, StoreError> {
        self.conn
            .query_row("SELECT max(id) FROM campaigns", [], |r| r.get(0))
            .ctx("find the latest campaign")
    }

    /// All campaigns, oldest first.
    pub fn list_campaigns(&self) -> Result<Vec<CampaignRow>, StoreError> {
        let mut st = self
            .conn
            .prepare(&format!(
                "SELECT {CAMPAIGN_COLUMNS} FROM campaigns ORDER BY id"
            ))
            .ctx("list campaigns")?;
        let rows = st
            .query_map([], campaign_row)
            .ctx("list campaigns")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("list campaigns")?;
        Ok(rows)
    }

    /// The campaign's plan, sorted by move order.
    pub fn plan(&self, id: i64) -> Result<Vec<PlannedPose>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT pose_index, set_name, move_order, q_rad FROM plan_poses \
                 WHERE campaign_id = ?1 ORDER BY move_order",
            )
            .ctx("read the plan")?;
        let raw = st
            .query_map([id], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, String>(3)?,
                ))
            })
            .ctx("read the plan")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read the plan")?;
        raw.into_iter()
            .map(|(index, set, order, q)| {
                Ok(PlannedPose {
                    index: from_sql_index(index, "pose index")?,
                    set: parse_set(&set)?,
                    order: from_sql_index(order, "move order")?,
                    q_rad: decode_joints(&q)?,
                })
            })
            .collect()
    }

    /// Record the campaign's state.
    pub fn set_state(&mut self, id: i64, state: StoredState) -> Result<(), StoreError> {
        let n = self
            .conn
            .execute(
                "UPDATE campaigns SET state = ?2 WHERE id = ?1",
                params![id, state],
            )
            .ctx("set the campaign state")?;
        if n == 0 {
            return Err(StoreError::NoCampaign(id));
        }
        Ok(())
    }

    /// Append `event` (journalled at `at_ms`, ms since the Unix epoch) to the campaign's
    /// journal; returns its sequence number (the row id, increasing in insertion order).
    pub fn add_event<E: JournalEvent>(
        &mut self,
        id: i64,
        at_ms: i64,
        event: &E,
    ) -> Result<i64, StoreError> {
        let text = event.to_text()?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin add event")?;
        Store::ensure_campaign(&tx, id)?;
        tx.execute(
            "INSERT INTO events (campaign_id, at_ms, kind, message) VALUES (?1, ?2, ?3, ?4)",
            params![id, at_ms, event.kind(), text],
        )
        .ctx("add an event")?;
        let seq = tx.last_insert_rowid();
        tx.commit().ctx("commit add event")?;
        Ok(seq)
    }

    /// At most `limit` journal entries of the campaign with a sequence number above `after`,
    /// oldest first (`after = 0`: from the start), typed ([`JournalEvent::from_stored`]: a
    /// row the type cannot read is its fallback, never an error).
    pub fn events_after<E: JournalEvent>(
        &self,
        id: i64,
        after: i64,
        limit: usize,
    ) -> Result<Vec<JournalEntry<E>>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let limit = i64::try_from(limit).unwrap_or(i64::MAX);
        let mut st = self
            .conn
            .prepare(
                "SELECT id, at_ms, kind, message FROM events \
                 WHERE campaign_id = ?1 AND id > ?2 ORDER BY id LIMIT ?3",
            )
            .ctx("read events")?;
        let rows = st
            .query_map(params![id, after, limit], |r| {
                Ok(JournalEntry {
                    seq: r.get(0)?,
                    at_ms: r.get(1)?,
                    event: E::from_stored(r.get(2)?, r.get(3)?),
                })
            })
            .ctx("read events")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read events")?;
        Ok(rows)
    }

    /// The sequence number of the campaign's newest journal entry (0 when it has none).
    pub fn last_event_seq(&self, id: i64) -> Result<i64, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT coalesce(max(id), 0) FROM events WHERE campaign_id = ?1",
                [id],
                |r| r.get(0),
            )
            .ctx("read the last event")
    }

    /// Poses measured (done marks) and poses planned, counted without reading them.
    pub fn pose_counts(&self, id: i64) -> Result<(usize, usize), StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let (done, total): (i64, i64) = self
            .conn
            .query_row(
                "SELECT (SELECT count(*) FROM pose_done WHERE campaign_id = ?1), \
                        (SELECT count(*) FROM plan_poses WHERE campaign_id = ?1)",
                [id],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .ctx("count poses")?;
        Ok((
            from_sql_index(done, "pose count")?,
            from_sql_index(total, "pose count")?,
        ))
    }

    /// Whether the campaign has a stored identification result (without reading it).
    pub fn has_result(&self, id: i64) -> Result<bool, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT EXISTS (SELECT 1 FROM results WHERE campaign_id = ?1)",
                [id],
                |r| r.get(0),
            )
            .ctx("look up a result")
    }

    /// The campaign's whole journal in the order it was written, typed as
    /// [`Store::events_after`].
    pub fn events<E: JournalEvent>(&self, id: i64) -> Result<Vec<JournalEntry<E>>, StoreError> {
        self.events_after(id, 0, usize::MAX)
    }

    /// Store a cell setup result (`json` must be valid JSON).
    pub fn save_setup(&mut self, id: i64, json: &str) -> Result<(), StoreError> {
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin save setup")?;
        Store::ensure_campaign(&tx, id)?;
        let valid: bool = tx
            .query_row("SELECT json_valid(?1)", [json], |r| r.get(0))
            .ctx("check the setup JSON")?;
        if !valid {
            return Err(StoreError::Invalid(
                "the setup result is not valid JSON".into(),
            ));
        }
        tx.execute(
            "INSERT INTO setup_results (campaign_id, json) VALUES (?1, ?2)",
            params![id, json],
        )
        .ctx("save a setup result")?;
        tx.commit().ctx("commit save setup")
    }

    /// The JSON of the campaign's most recent setup result, if any.
    pub fn latest_setup(&self, id: i64) -> Result<Option<String>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT json FROM setup_results WHERE campaign_id = ?1 ORDER BY id DESC LIMIT 1",
                [id],
                |r| r.get(0),
            )
            .optional()
            .ctx("read the setup result")
    }
}

/// Insert the campaign row and its plan inside `tx`; `encoded[i]` is `plan[i]`'s joints.
pub(crate) fn insert_campaign(
    tx: &Transaction<'_>,
    campaign: &NewCampaign,
    plan: &[PlannedPose],
    encoded: &[String],
) -> Result<i64, StoreError> {
    tx.execute(
        "INSERT INTO campaigns (name, created_at_ms, state, model, seed, config_toml, robot_toml) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
        params![
            campaign.name,
            campaign.created_at_ms,
            INITIAL_STATE,
            campaign.model,
            campaign.seed as i64,
            campaign.config_toml,
            campaign.robot_toml
        ],
    )
    .ctx("insert a campaign")?;
    let id = tx.last_insert_rowid();
    let mut st = tx
        .prepare(
            "INSERT INTO plan_poses (campaign_id, pose_index, set_name, move_order, q_rad) \
             VALUES (?1, ?2, ?3, ?4, ?5)",
        )
        .ctx("insert the plan")?;
    for (p, q) in plan.iter().zip(encoded) {
        st.execute(params![
            id,
            to_sql_index(p.index, "pose index")?,
            p.set.as_str(),
            to_sql_index(p.order, "move order")?,
            q
        ])
        .ctx("insert a plan pose")?;
    }
    Ok(id)
}
