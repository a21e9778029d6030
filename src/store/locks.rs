//! One runner per campaign: the `campaign_locks` row names the process that may drive the
//! campaign's robot.

use rusqlite::{params, OptionalExtension, TransactionBehavior};

use super::error::{Ctx, StoreError};
use super::records::StoredState;
use super::Store;

/// The process holding a campaign: the only one that may drive its robot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LockHolder {
    /// Process id.
    pub pid: u32,
    /// Host name (a pid means nothing on another host).
    pub host: String,
    /// The process's start time (clock ticks since boot), so a reused pid is not mistaken for
    /// the holder.
    pub pid_start: u64,
    /// When the lock was taken (ms since the Unix epoch).
    pub acquired_at_ms: i64,
}

impl std::fmt::Display for LockHolder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "pid {} on host {} (since {})",
            self.pid,
            self.host,
            crate::units::human::fmt_local_time(self.acquired_at_ms)
        )
    }
}

/// How [`Store::lock_campaign`] got the campaign.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Acquired {
    /// Nobody held it.
    Free,
    /// This process already held it.
    Again,
    /// A dead process held it; its row was replaced.
    TookOver(LockHolder),
}

impl Store {
    /// Take campaign `id` for `me`. A holder for which `is_dead` returns true is replaced
    /// (the caller journals that); any other holder refuses with [`StoreError::Locked`].
    /// Atomic: of two processes racing for a free campaign, exactly one gets it.
    pub fn lock_campaign(
        &mut self,
        id: i64,
        me: &LockHolder,
        is_dead: impl Fn(&LockHolder) -> bool,
    ) -> Result<Acquired, StoreError> {
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin lock campaign")?;
        Store::ensure_campaign(&tx, id)?;
        let held = holder(&tx, id)?;
        let how = match held {
            None => Acquired::Free,
            Some(h) if h.pid == me.pid && h.host == me.host && h.pid_start == me.pid_start => {
                Acquired::Again
            }
            Some(h) if is_dead(&h) => Acquired::TookOver(h),
            Some(h) => {
                return Err(StoreError::Locked {
                    campaign: id,
                    holder: h,
                })
            }
        };
        tx.execute(
            "INSERT OR REPLACE INTO campaign_locks (campaign_id, pid, host, pid_start, acquired_at_ms) \
             VALUES (?1, ?2, ?3, ?4, ?5)",
            params![
                id,
                me.pid,
                me.host,
                i64::try_from(me.pid_start).unwrap_or(i64::MAX),
                me.acquired_at_ms
            ],
        )
        .ctx("lock a campaign")?;
        tx.commit().ctx("commit lock campaign")?;
        Ok(how)
    }

    /// Let go of campaign `id` if `me` holds it; returns whether a row was deleted.
    pub fn unlock_campaign(&mut self, id: i64, me: &LockHolder) -> Result<bool, StoreError> {
        let n = self
            .conn
            .execute(
                "DELETE FROM campaign_locks WHERE campaign_id = ?1 AND pid = ?2 AND host = ?3",
                params![id, me.pid, me.host],
            )
            .ctx("unlock a campaign")?;
        Ok(n > 0)
    }

    /// Set campaign `id`'s state to `to` if it is one of `from` and no live process holds it
    /// (no lock row, or a holder for which `is_dead` returns true); returns the state it had
    /// and the dead holder. Atomic: a process taking the campaign meanwhile keeps its state.
    pub fn interrupt_unheld(
        &mut self,
        id: i64,
        from: &[StoredState],
        to: StoredState,
        is_dead: impl Fn(&LockHolder) -> bool,
    ) -> Result<Option<(StoredState, Option<LockHolder>)>, StoreError> {
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin interrupt campaign")?;
        let state: StoredState = tx
            .query_row("SELECT state FROM campaigns WHERE id = ?1", [id], |r| {
                r.get(0)
            })
            .optional()
            .ctx("read a campaign state")?
            .ok_or(StoreError::NoCampaign(id))?;
        let held = holder(&tx, id)?;
        if !from.contains(&state) || held.as_ref().is_some_and(|h| !is_dead(h)) {
            return Ok(None);
        }
        tx.execute(
            "UPDATE campaigns SET state = ?2 WHERE id = ?1",
            params![id, to],
        )
        .ctx("set the campaign state")?;
        tx.commit().ctx("commit interrupt campaign")?;
        Ok(Some((state, held)))
    }

    /// The process holding campaign `id`, if any.
    pub fn campaign_holder(&self, id: i64) -> Result<Option<LockHolder>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        holder(&self.conn, id)
    }
}

fn holder(conn: &rusqlite::Connection, id: i64) -> Result<Option<LockHolder>, StoreError> {
    conn.query_row(
        "SELECT pid, host, pid_start, acquired_at_ms FROM campaign_locks WHERE campaign_id = ?1",
        [id],
        |r| {
            Ok(LockHolder {
                pid: r.get(0)?,
                host: r.get(1)?,
                pid_start: r.get::<_, i64>(2)?.max(0) as u64,
                acquired_at_ms: r.get(3)?,
            })
        },
    )
    .optional()
    .ctx("read a campaign lock")
}
