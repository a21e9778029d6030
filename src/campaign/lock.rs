//! This process as the one runner of a campaign: the guard over the store's lock row
//! ([`Store::lock_campaign`]), and whether a recorded holder is still alive (Linux `/proc`).

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::store::{Acquired, LockHolder, Store, StoreError};

/// Holds campaign `id` for this process until dropped (or [`CampaignLock::release`]d).
#[derive(Debug)]
pub struct CampaignLock {
    store_path: PathBuf,
    campaign_id: i64,
    me: LockHolder,
    released: bool,
}

impl CampaignLock {
    /// Take campaign `id` in `store` (opened from `store_path`). Returns the guard and, when a
    /// dead process's lock was taken over, that holder (the caller journals it).
    pub fn acquire(
        store: &mut Store,
        store_path: &Path,
        id: i64,
    ) -> Result<(CampaignLock, Option<LockHolder>), StoreError> {
        let me = this_process();
        let how = store.lock_campaign(id, &me, is_dead)?;
        let guard = CampaignLock {
            store_path: store_path.to_owned(),
            campaign_id: id,
            me,
            released: false,
        };
        Ok((
            guard,
            match how {
                Acquired::TookOver(h) => Some(h),
                Acquired::Free | Acquired::Again => None,
            },
        ))
    }

    /// Let go of the campaign now (blocking: one short SQLite write).
    pub fn release(mut self) -> Result<(), StoreError> {
        self.released = true;
        Store::open(&self.store_path)?.unlock_campaign(self.campaign_id, &self.me)?;
        Ok(())
    }
}

impl Drop for CampaignLock {
    fn drop(&mut self) {
        if !self.released {
            if let Ok(mut s) = Store::open(&self.store_path) {
                let _ = s.unlock_campaign(self.campaign_id, &self.me);
            }
        }
    }
}

/// This process as a lock holder.
pub fn this_process() -> LockHolder {
    let pid = std::process::id();
    LockHolder {
        pid,
        host: host_name(),
        pid_start: process_start(pid).unwrap_or(0),
        acquired_at_ms: SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_millis() as i64)
            .unwrap_or(0),
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
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("c.db");
        let mut s = Store::open(&path).expect("store");
        let id = crate::store::tests::setup(&mut s);
        let (guard, took) = CampaignLock::acquire(&mut s, &path, id).expect("first");
        assert!(took.is_none());
        let other = LockHolder {
            pid: 1,
            ..this_process()
        };
        match s.lock_campaign(id, &other, is_dead) {
            Err(StoreError::Locked { holder, .. }) => assert_eq!(holder.pid, std::process::id()),
            r => panic!("expected Locked, got {r:?}"),
        }
        drop(guard);
        assert_eq!(
            s.campaign_holder(id).expect("holder"),
            None,
            "released on drop"
        );
        let dead = LockHolder {
            pid: u32::MAX - 1,
            ..this_process()
        };
        s.lock_campaign(id, &dead, |_| false).expect("dead holder");
        let (_g, took) = CampaignLock::acquire(&mut s, &path, id).expect("take over");
        assert_eq!(took.map(|h| h.pid), Some(u32::MAX - 1));
    }
}
