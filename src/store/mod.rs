//! The campaign store: an SQLite journal of campaigns, their plans, every raw tracker point,
//! completed poses, events and identification results. Only this module knows SQL.
//!
//! # Durability
//! The database runs in WAL mode with `synchronous=FULL` and foreign keys on. A pose is
//! committed by [`Store::commit_pose`] in one transaction (P1 row, P2 row, done mark): when it
//! returns `Ok`, the pose survives a crash or power loss; if the process dies before, nothing
//! of the pose is visible. A pose can be done only once (`pose_done` primary key), so a
//! resumed campaign never measures a pose twice: it measures the plan minus
//! [`Store::done_poses`].
//!
//! # Invariants
//! - The plan (poses, order and ident/verify split) is written with the campaign in one
//!   transaction, before any measurement, and never changes.
//! - Measurements are append-only: the store has no API to change or delete them, and
//!   triggers refuse `UPDATE` and `DELETE`. Corrections are new rows (e.g. a `discarded`
//!   point).
//! - Every table is `STRICT`; schema versions follow `PRAGMA user_version` (see [`schema`]);
//!   a file from a newer cellcal is refused ([`StoreError::SchemaTooNew`]).
//!
//! A `Store` is one connection: `Send`, not `Sync`. A shared writer is owned by a
//! [`StoreHandle`] (the only lock over a `Store`; nothing outside this module reaches it), the
//! readers of a file by a [`ReaderPool`].
//!
//! # Readers
//! [`StoreReader`] is a second kind of connection for readers (the daemon's GETs and event
//! replays): it never migrates and never writes (`query_only`; only `&self` methods of
//! [`Store`] are reachable through it), refuses a file whose schema is not exactly
//! [`schema_version`], and in WAL mode neither blocks the writer nor waits for it.

mod campaigns;
mod error;
mod estimates;
mod frames;
mod handle;
mod ident_checks;
mod kinds;
mod locks;
mod measurements;
pub mod records;
mod results;
pub mod schema;

#[cfg(test)]
mod reader_tests;
#[cfg(test)]
pub(crate) mod tests;

use std::path::Path;
use std::time::Duration;

use rusqlite::{Connection, OpenFlags, OptionalExtension};

pub use campaigns::INITIAL_STATE;
pub use error::StoreError;
pub use estimates::EntryAfter;
pub use frames::{map_point, to_first_frame, FrameRef, FrameTransform, JointPoint};
pub use handle::{ReaderPool, StoreHandle};
pub use kinds::{CampaignKind, ISO9283_KIND};
pub use locks::{Acquired, LockHolder};
pub use measurements::{
    identification_rows, MeasuredPoint, MeasuredPose, SetupPoint, IMPORTED_STATE,
};
pub use records::{
    CampaignRow, JournalEntry, JournalEvent, NewCampaign, PlannedPose, PointKind, PointRecord,
    PoseMeasurement, StoredState,
};

use error::Ctx;

/// How long a statement waits for another connection's lock before failing.
pub const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// The schema version this build writes (number of migrations).
pub fn schema_version() -> i64 {
    schema::known_version()
}

/// Switch to WAL. Only the writer sets the journal mode: changing it needs the write lock, and
/// SQLite answers BUSY at once (without the busy handler, to avoid a deadlock) while another
/// connection opens the same new file, so the switch is retried for up to [`BUSY_TIMEOUT`].
/// The resulting mode is "wal", or "memory" for an in-memory database.
fn set_wal(conn: &Connection) -> Result<(), StoreError> {
    let deadline = std::time::Instant::now() + BUSY_TIMEOUT;
    loop {
        match conn.pragma_update_and_check(None, "journal_mode", "WAL", |r| r.get::<_, String>(0)) {
            Ok(_) => return Ok(()),
            Err(rusqlite::Error::SqliteFailure(e, _))
                if e.code == rusqlite::ErrorCode::DatabaseBusy
                    && std::time::Instant::now() < deadline =>
            {
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => return Err(e).ctx("set journal_mode=WAL"),
        }
    }
}

/// An open campaign database.
#[derive(Debug)]
pub struct Store {
    conn: Connection,
}

impl Store {
    /// Create or open the database at `path`, set WAL, `synchronous=FULL`, foreign keys and
    /// the busy timeout, and apply pending migrations.
    /// A new file is created mode 0600 whatever the umask (SQLite gives its `-wal` and `-shm`
    /// files the database file's mode).
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        create_private(path)?;
        let conn = Connection::open(path).ctx("open the database file")?;
        Store::init(conn)
    }

    /// A private in-memory database (tests, dry runs). Journal mode is `memory` there.
    pub fn open_in_memory() -> Result<Store, StoreError> {
        let conn = Connection::open_in_memory().ctx("open an in-memory database")?;
        Store::init(conn)
    }

    fn init(mut conn: Connection) -> Result<Store, StoreError> {
        conn.busy_timeout(BUSY_TIMEOUT)
            .ctx("set the busy timeout")?;
        set_wal(&conn)?;
        conn.pragma_update(None, "synchronous", "FULL")
            .ctx("set synchronous=FULL")?;
        conn.pragma_update(None, "foreign_keys", "ON")
            .ctx("enable foreign keys")?;
        schema::migrate(&mut conn)?;
        Ok(Store { conn })
    }

    /// The database file (`None` for an in-memory database).
    pub fn path(&self) -> Option<&Path> {
        self.conn.path().filter(|p| !p.is_empty()).map(Path::new)
    }

    /// The file's `PRAGMA user_version` (equals [`schema_version`] once open).
    pub fn user_version(&self) -> Result<i64, StoreError> {
        schema::user_version(&self.conn)
    }

    /// `NoCampaign` unless the campaign exists.
    fn ensure_campaign(conn: &Connection, id: i64) -> Result<(), StoreError> {
        let found: Option<i64> = conn
            .query_row("SELECT id FROM campaigns WHERE id = ?1", [id], |r| r.get(0))
            .optional()
            .ctx("look up a campaign")?;
        match found {
            Some(_) => Ok(()),
            None => Err(StoreError::NoCampaign(id)),
        }
    }

    /// A reading connection to the existing database at `path` (see [`StoreReader`]).
    pub fn open_reader(path: &Path) -> Result<StoreReader, StoreError> {
        let conn = Connection::open_with_flags(
            path,
            // no CREATE: a reader never makes a database
            OpenFlags::SQLITE_OPEN_READ_WRITE | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .ctx("open the database file for reading")?;
        conn.busy_timeout(BUSY_TIMEOUT)
            .ctx("set the busy timeout")?;
        conn.pragma_update(None, "query_only", "ON")
            .ctx("set query_only")?;
        let found = schema::user_version(&conn)?;
        let known = schema::known_version();
        if found > known {
            return Err(StoreError::SchemaTooNew { found, known });
        }
        if found < known {
            return Err(StoreError::SchemaTooOld { found, known });
        }
        Ok(StoreReader(Store { conn }))
    }

    /// Raw connection for tests that must bypass the API (STRICT, triggers, crashes).
    #[cfg(test)]
    pub(crate) fn raw(&mut self) -> &mut Connection {
        &mut self.conn
    }
}

/// Create `path` empty with mode 0600 (whatever the umask) unless it exists.
fn create_private(path: &Path) -> Result<(), StoreError> {
    use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
    let created = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path);
    let io = |cause| StoreError::File {
        path: path.to_owned(),
        cause,
    };
    match created {
        Ok(f) => f
            .set_permissions(std::fs::Permissions::from_mode(0o600))
            .map_err(io),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => Err(io(e)),
    }
}

/// A read-only connection: no migration, no write transaction, only `&self` [`Store`] methods.
///
/// Opened by [`Store::open_reader`] on a database the writer has already migrated. It is
/// read-write at the file level only so that WAL readers can use the shared-memory index;
/// `PRAGMA query_only` makes SQLite refuse every write on it.
#[derive(Debug)]
pub struct StoreReader(Store);

impl std::ops::Deref for StoreReader {
    type Target = Store;

    fn deref(&self) -> &Store {
        &self.0
    }
}
