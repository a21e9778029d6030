//! This process as the one runner of a campaign: the guard over the store's lock row
//! ([`Store::lock_campaign`]), and whether a recorded holder is still alive (Linux `/proc`).

use super::events::CampaignEvent;
use crate::store::{Acquired, LockHolder, Store, StoreError, StoreHandle, StoredState};
use crate::wall_clock::now_unix_ms;

/// Holds a campaign for this process until dropped (one short SQLite write on the store the
/// session shares with the engine).
#[derive(Debug)]
pub struct CampaignLock {
    store: StoreHandle,
    campaign_id: i64,
    me: LockHolder,
}

impl CampaignLock {
    /// Take campaign `id`. Returns the guard and, when a dead process's lock was taken over,
    /// that holder (the caller journals it). Blocking.
    pub fn acquire(
        store: &StoreHandle,
        id: i64,
    ) -> Result<(CampaignLock, Option<LockHolder>), StoreError> {
        let me = this_process();
        let how = store.blocking(|s| s.lock_campaign(id, &me, is_dead))?;
        let guard = CampaignLock {
            store: store.clone(),
            campaign_id: id,
            me,
        };
        Ok((
            guard,
            match how {
                Acquired::TookOver(h) => Some(h),
                Acquired::Free | Acquired::Again => None,
            },
        ))
    }
}

impl Drop for CampaignLock {
    fn drop(&mut self) {
        let _ = self
            .store
            .blocking(|s| s.unlock_campaign(self.campaign_id, &self.me));
    }
}

/// Mark every campaign stored in a run's state ([`StoredState::RUN`]) that no live process
/// holds [`StoredState::Interrupted`]
/// (nothing of it moves; it stays resumable) and journal why; returns each one's id and the
/// state it had. Blocking (store writes).
pub fn mark_interrupted(store: &mut Store) -> Result<Vec<(i64, StoredState)>, StoreError> {
    let mut out = Vec::new();
    for row in store.list_campaigns()? {
        let Some((was, holder)) =
            store.interrupt_unheld(row.id, &StoredState::RUN, StoredState::Interrupted, is_dead)?
        else {
            continue;
        };
        let who = holder.map_or_else(
            || "the process that ran it".to_owned(),
            |h| format!("the process that ran it ({h})"),
        );
        let text = format!(
            "interrupted: stored `{was}`, but {who} is gone; nothing of it moves. Resume it to \
             measure on"
        );
        journal_note(store, row.id, text)?;
        out.push((row.id, was));
    }
    Ok(out)
}

/// Journal a note in campaign `id`'s events (outside a run: nothing publishes it live).
pub(crate) fn journal_note(store: &mut Store, id: i64, text: String) -> Result<(), StoreError> {
    store.add_event(id, now_unix_ms(), &CampaignEvent::Note { text })?;
    Ok(())
}

/// This process as a lock holder.
pub fn this_process() -> LockHolder {
    let pid = std::process::id();
    LockHolder {
        pid,
        host: host_name(),
        pid_start: process_start(pid).unwrap_or(0),
        acquired_at_ms: now_unix_ms(),
    }
}

/// Whether `h` certainly no longer runs: same host, and its pid is gone or now belongs to a
/// process started at another time. A holder on another host is never presumed dead.
pub fn is_dead(h: &LockHolder) -> bool {
    if h.host != host_name() {
        return false;
    }
    match process_start(h.pid) {
        None => true,
        Some(start) => h.pid_start != 0 && start != h.pid_start,
    }
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_owned())
        .unwrap_or_else(|_| "unknown-host".into())
}

/// Start time of process `pid` (clock ticks since boot, field 22 of `/proc/PID/stat`).
fn process_start(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // the command name (field 2) may hold spaces and parentheses: fields follow the last ')'
    let rest = &stat[stat.rfind(')')? + 1..];
    rest.split_whitespace().nth(19)?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_is_alive_and_a_vanished_pid_is_dead() {
        let me = this_process();
        assert!(me.pid_start > 0, "start time read from /proc");
        assert!(!is_dead(&me));
        let reused = LockHolder {
            pid_start: me.pid_start + 1,
            ..me.clone()
        };
        assert!(is_dead(&reused), "a reused pid is not the holder");
        let gone = LockHolder {
            pid: u32::MAX - 1,
            ..me.clone()
        };
        assert!(is_dead(&gone));
        let elsewhere = LockHolder {
            pid: u32::MAX - 1,
            host: "another-host".into(),
            ..me
        };
        assert!(
            !is_dead(&elsewhere),
            "never presume a process on another host dead"
        );
    }

    #[test]
    fn a_second_holder_is_refused_and_a_dead_one_taken_over() {
        let mut s = Store::open_in_memory().expect("store");
        let id = crate::store::tests::setup(&mut s);
        let store = StoreHandle::new(s);
        let (guard, took) = CampaignLock::acquire(&store, id).expect("first");
        assert!(took.is_none());
        let other = LockHolder {
            pid: 1,
            ..this_process()
        };
        match store.blocking(|s| s.lock_campaign(id, &other, is_dead)) {
            Err(StoreError::Locked { holder, .. }) => assert_eq!(holder.pid, std::process::id()),
            r => panic!("expected Locked, got {r:?}"),
        }
        drop(guard);
        let holder = store.blocking(|s| s.campaign_holder(id)).expect("holder");
        assert_eq!(holder, None, "released on drop");
        let dead = LockHolder {
            pid: u32::MAX - 1,
            ..this_process()
        };
        store
            .blocking(|s| s.lock_campaign(id, &dead, |_| false))
            .expect("dead holder");
        let (_g, took) = CampaignLock::acquire(&store, id).expect("take over");
        assert_eq!(took.map(|h| h.pid), Some(u32::MAX - 1));
    }
}
