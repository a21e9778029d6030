//! One commander per cell: this process as the only one that may command a cell's devices.
//!
//! A campaign lock row ([`super::lock::CampaignLock`]) lives in one store, so it cannot keep two
//! stores (or two campaigns of one store) off one robot. The cell lock is host-wide instead: an
//! exclusive `flock` on a file in the lock directory, named by a digest of what identifies the
//! cell ([`CellKey`]: the robot controller's address for a real robot, the store file for the
//! simulated cell). The kernel lets go of the `flock` when its process ends, however it ends, so
//! a dead holder never blocks the cell. The holder writes who it is into the file
//! ([`CellHolder`]: pid, host, campaign, store) for a refused process to name; a clean release
//! removes the file, so a record found by the next holder was left by a process that died
//! holding the cell (the caller journals that).

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::lock::{is_dead, this_process};
use crate::config::{CellConfig, DeviceMode};

/// Env var naming the lock directory (overrides the configuration's `lock_dir`).
pub const LOCK_DIR_ENV: &str = "CELLCAL_LOCK_DIR";

/// The lock directory when neither [`LOCK_DIR_ENV`] nor `lock_dir` names one (on a host
/// without `/run/lock`: `cellcal-locks` in the temporary directory).
pub const DEFAULT_LOCK_DIR: &str = "/run/lock/cellcal";

/// Mode of a lock file: the holder record is no secret, and every member of the group that
/// commands the cell must be able to take the lock.
const LOCK_FILE_MODE: u32 = 0o664;

/// How long a refused process waits for the holder to write its record.
const RECORD_WAIT: Duration = Duration::from_secs(1);

/// What identifies a cell: whatever two commanders of the same devices have in common.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CellKey {
    /// A real robot controller, by its configured address (trimmed, lowercase; a socket
    /// address in its canonical form).
    Robot(String),
    /// The simulated cell of a store file (its canonical path).
    Store(PathBuf),
}

impl CellKey {
    /// The key of the cell `cfg` commands with the store at `store` (`None`: an in-memory store
    /// with a simulated robot, a cell no other process can reach).
    pub fn of(cfg: &CellConfig, store: Option<&Path>) -> Option<CellKey> {
        match cfg.robot_controller.mode {
            DeviceMode::Sim => store.map(|p| CellKey::Store(canonical_file(p))),
            _ => Some(CellKey::Robot(normalized_address(
                &cfg.robot_controller.address,
            ))),
        }
    }

    /// The lock file's name in the lock directory: a digest of the key.
    fn file_name(&self) -> String {
        let digest = Sha256::digest(self.to_string().as_bytes());
        let hex: String = digest[..16].iter().map(|b| format!("{b:02x}")).collect();
        format!("cell-{hex}.lock")
    }
}

impl std::fmt::Display for CellKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CellKey::Robot(a) => write!(f, "robot controller {a}"),
            CellKey::Store(p) => write!(f, "simulated cell of store {}", p.display()),
        }
    }
}

/// `a` trimmed and lowercase; a socket address (`10.0.0.2:5000`, `[::1]:5000`) in its
/// canonical form, so that two spellings of one address are one cell.
fn normalized_address(a: &str) -> String {
    let a = a.trim().to_ascii_lowercase();
    match a.parse::<std::net::SocketAddr>() {
        Ok(s) => s.to_string(),
        Err(_) => a,
    }
}

/// The canonical path of a file that may not exist yet (its directory canonicalised).
fn canonical_file(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    };
    match (dir.canonicalize(), p.file_name()) {
        (Ok(d), Some(n)) => d.join(n),
        _ => p.to_owned(),
    }
}

/// The process commanding a cell, as its lock file records it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CellHolder {
    /// Process id.
    pub pid: u32,
    /// Host name.
    pub host: String,
    /// The process's start time (clock ticks since boot).
    pub pid_start: u64,
    /// When it took the cell (ms since the Unix epoch).
    pub acquired_at_ms: i64,
    /// The campaign it runs (`None` while a new one is being planned).
    pub campaign: Option<i64>,
    /// Its store file.
    pub store: String,
    /// The cell ([`CellKey`] as text).
    pub cell: String,
}

impl std::fmt::Display for CellHolder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "pid {} on host {} (", self.pid, self.host)?;
        match self.campaign {
            Some(c) => write!(f, "campaign {c}")?,
            None => f.write_str("a campaign being planned")?,
        }
        write!(
            f,
            ", store {}, since {})",
            self.store,
            crate::units::human::fmt_local_time(self.acquired_at_ms)
        )
    }
}

/// Why the cell could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum CellLockError {
    /// Another live process commands the cell.
    #[error(
        "the cell ({cell}) is commanded by {}; one process commands a cell at a time: stop \
         that process first",
        holder.as_ref().map_or_else(|| "another process (its record is not readable)".to_owned(), ToString::to_string)
    )]
    Busy {
        /// The cell.
        cell: String,
        /// Who holds it, when its record could be read.
        holder: Option<Box<CellHolder>>,
    },
    /// The lock directory or file cannot be used.
    #[error(
        "cell lock {path}: {cause} (every process that may command this cell needs write \
         access to the lock directory: `lock_dir` in the configuration or {LOCK_DIR_ENV})"
    )]
    Io {
        /// The directory or file.
        path: PathBuf,
        /// What failed.
        cause: std::io::Error,
    },
}

/// The lock directory: [`LOCK_DIR_ENV`] when set (not empty), else the configuration's
/// `lock_dir`, else [`DEFAULT_LOCK_DIR`].
pub fn lock_dir(cfg: &CellConfig) -> PathBuf {
    match std::env::var_os(LOCK_DIR_ENV) {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => cfg.lock_dir.clone().unwrap_or_else(default_lock_dir),
    }
}

fn default_lock_dir() -> PathBuf {
    let d = PathBuf::from(DEFAULT_LOCK_DIR);
    match d.parent() {
        Some(p) if p.is_dir() => d,
        _ => std::env::temp_dir().join("cellcal-locks"),
    }
}

/// This process commands the cell while this is held; dropping it removes the record and lets
/// go (a crash lets go too, leaving the record behind).
#[derive(Debug)]
pub struct CellLock {
    file: File,
    path: PathBuf,
    me: CellHolder,
}

impl CellLock {
    /// Take the cell `key` in `dir` for this process (running `campaign`, if known, on the store
    /// `store`), or refuse naming the holder. Returns the lock and, when the previous holder
    /// died holding the cell, its record (the caller journals it). Blocking (file I/O; a refusal
    /// may wait up to a second for the holder's record).
    pub fn acquire(
        dir: &Path,
        key: &CellKey,
        store: &Path,
        campaign: Option<i64>,
    ) -> Result<(CellLock, Option<CellHolder>), CellLockError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |cause| CellLockError::Io { path, cause }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let path = dir.join(key.file_name());
        let p = this_process();
        let me = CellHolder {
            pid: p.pid,
            host: p.host,
            pid_start: p.pid_start,
            acquired_at_ms: p.acquired_at_ms,
            campaign,
            store: store.display().to_string(),
            cell: key.to_string(),
        };
        loop {
            let file = open_lock_file(&path).map_err(io(&path))?;
            match file.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    return Err(CellLockError::Busy {
                        cell: key.to_string(),
                        holder: wait_for_record(&path).map(Box::new),
                    })
                }
                Err(TryLockError::Error(e)) => return Err(io(&path)(e)),
            }
            // a holder that let go removed the file: a lock on the removed file is no lock
            if !names_file(&path, &file) {
                continue;
            }
            let mut lock = CellLock { file, path, me };
            let previous = lock.read_record();
            lock.write_record().map_err(io(&lock.path))?;
            return Ok((lock, previous));
        }
    }

    /// Record the campaign this process runs (once a new campaign is stored). Blocking.
    pub fn set_campaign(&mut self, campaign: i64) -> Result<(), CellLockError> {
        self.me.campaign = Some(campaign);
        self.write_record().map_err(|cause| CellLockError::Io {
            path: self.path.clone(),
            cause,
        })
    }

    /// This process as the lock file records it.
    pub fn holder(&self) -> &CellHolder {
        &self.me
    }

    /// The record a previous holder left, if any.
    fn read_record(&mut self) -> Option<CellHolder> {
        let mut text = String::new();
        self.file.seek(SeekFrom::Start(0)).ok()?;
        self.file.read_to_string(&mut text).ok()?;
        serde_json::from_str(&text).ok()
    }

    fn write_record(&mut self) -> std::io::Result<()> {
        let text = serde_json::to_string(&self.me).map_err(std::io::Error::other)?;
        self.file.set_len(0)?;
        self.file.seek(SeekFrom::Start(0))?;
        self.file.write_all(text.as_bytes())?;
        self.file.sync_data()
    }
}

impl Drop for CellLock {
    fn drop(&mut self) {
        // remove the record while still holding the lock; closing the file lets go
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Open (or create, mode [`LOCK_FILE_MODE`] whatever the umask) the lock file.
fn open_lock_file(path: &Path) -> std::io::Result<File> {
    let file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(LOCK_FILE_MODE)
        .open(path)?;
    let meta = file.metadata()?;
    if meta.len() == 0 && meta.permissions().mode() & 0o777 != LOCK_FILE_MODE {
        // best effort: a file of another owner keeps its mode
        let _ = file.set_permissions(std::fs::Permissions::from_mode(LOCK_FILE_MODE));
    }
    Ok(file)
}

/// Whether `path` still names the open `file`.
fn names_file(path: &Path, file: &File) -> bool {
    match (std::fs::metadata(path), file.metadata()) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// The live holder's record, waiting briefly while it is not written yet (or still names a
/// dead predecessor).
fn wait_for_record(path: &Path) -> Option<CellHolder> {
    let deadline = std::time::Instant::now() + RECORD_WAIT;
    let mut last = None;
    loop {
        let read = std::fs::read_to_string(path)
            .ok()
            .and_then(|t| serde_json::from_str::<CellHolder>(&t).ok());
        if let Some(h) = &read {
            let alive = !is_dead(&crate::store::LockHolder {
                pid: h.pid,
                host: h.host.clone(),
                pid_start: h.pid_start,
                acquired_at_ms: h.acquired_at_ms,
            });
            if alive {
                return read;
            }
        }
        last = read.or(last);
        if std::time::Instant::now() >= deadline {
            return last;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(dir: &Path) -> CellKey {
        CellKey::Store(dir.join("c.db"))
    }

    #[test]
    fn a_second_commander_is_refused_naming_the_holder_until_the_first_lets_go() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = dir.path().join("c.db");
        let (mut first, previous) =
            CellLock::acquire(dir.path(), &key(dir.path()), &store, None).expect("first");
        assert_eq!(previous, None);
        first.set_campaign(7).expect("record the campaign");
        // a second open file description is a second would-be commander, even in this process
        match CellLock::acquire(dir.path(), &key(dir.path()), &store, Some(8)) {
            Err(CellLockError::Busy {
                holder: Some(h), ..
            }) => {
                assert_eq!(h.pid, std::process::id());
                assert_eq!(h.campaign, Some(7));
                let text = CellLockError::Busy {
                    cell: key(dir.path()).to_string(),
                    holder: Some(h),
                }
                .to_string();
                assert!(text.contains("campaign 7"), "{text}");
                assert!(
                    text.contains(&format!("pid {}", std::process::id())),
                    "{text}"
                );
            }
            r => panic!("expected Busy, got {r:?}"),
        }
        drop(first);
        let (_again, previous) = CellLock::acquire(dir.path(), &key(dir.path()), &store, None)
            .expect("free after the release");
        assert_eq!(previous, None, "a clean release leaves no record");
    }

    #[test]
    fn a_record_left_by_a_dead_holder_is_taken_over_and_returned() {
        let dir = tempfile::tempdir().expect("tempdir");
        let k = key(dir.path());
        let dead = CellHolder {
            pid: u32::MAX - 1,
            host: this_process().host,
            pid_start: 1,
            acquired_at_ms: 5,
            campaign: Some(3),
            store: "c.db".into(),
            cell: k.to_string(),
        };
        // what a process that died holding the cell leaves: its record, no lock
        std::fs::write(
            dir.path().join(k.file_name()),
            serde_json::to_string(&dead).expect("json"),
        )
        .expect("write");
        let (_lock, previous) =
            CellLock::acquire(dir.path(), &k, &dir.path().join("c.db"), None).expect("taken");
        assert_eq!(previous, Some(dead));
    }

    #[test]
    fn two_spellings_of_one_robot_address_are_one_cell() {
        assert_eq!(normalized_address(" 127.0.0.1:5000 "), "127.0.0.1:5000");
        assert_eq!(normalized_address("[::1]:05000"), "[::1]:5000");
        assert_eq!(normalized_address("Robot.Cell:5000"), "robot.cell:5000");
        let dir = tempfile::tempdir().expect("tempdir");
        let a = dir.path().join("x").join("..").join("c.db");
        std::fs::create_dir_all(dir.path().join("x")).expect("mkdir");
        assert_eq!(
            CellKey::Store(canonical_file(&a)).file_name(),
            CellKey::Store(canonical_file(&dir.path().join("c.db"))).file_name()
        );
    }
}
