//! The store's typed errors.

/// What can go wrong in the campaign store.
///
/// Each message names its cause (the SQLite or I/O error) and gives no `source()`: printed
/// with its causes the cause appears once, and `to_string()` has the whole message.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// SQLite failed while doing `op`.
    #[error("campaign store: {op}: {cause}")]
    Sqlite {
        /// The operation that failed (e.g. "commit pose").
        op: &'static str,
        /// The SQLite error.
        cause: rusqlite::Error,
    },
    /// No campaign has this id.
    #[error("no campaign with id {0}")]
    NoCampaign(i64),
    /// The pose was already committed; nothing was written.
    #[error("campaign {campaign}: pose {pose} is already measured")]
    AlreadyMeasured {
        /// Campaign id.
        campaign: i64,
        /// Pose index.
        pose: usize,
    },
    /// The pose index is not part of the campaign's plan; nothing was written.
    #[error("campaign {campaign}: pose {pose} is not in the plan")]
    NotInPlan {
        /// Campaign id.
        campaign: i64,
        /// Pose index.
        pose: usize,
    },
    /// The database was written by a newer cellcal.
    #[error(
        "the campaign database has schema version {found}, newer than the {known} this cellcal \
         knows; use a newer cellcal"
    )]
    SchemaTooNew {
        /// `PRAGMA user_version` of the file.
        found: i64,
        /// Number of migrations this code knows.
        known: i64,
    },
    /// Another live process drives this campaign.
    #[error("campaign {campaign} is being run by {holder}; stop that process first")]
    Locked {
        /// Campaign id.
        campaign: i64,
        /// Who holds it.
        holder: super::locks::LockHolder,
    },
    /// A reader opened a database its writer has not migrated to this cellcal's schema yet.
    #[error(
        "the campaign database has schema version {found}, older than the {known} this cellcal \
         reads; open it once for writing (e.g. `cellcal serve`) to migrate it"
    )]
    SchemaTooOld {
        /// `PRAGMA user_version` of the file.
        found: i64,
        /// Number of migrations this code knows.
        known: i64,
    },
    /// The database file cannot be created.
    #[error("cannot create the campaign database {path}: {cause}")]
    File {
        /// The file.
        path: std::path::PathBuf,
        /// What failed.
        cause: std::io::Error,
    },
    /// A stored value cannot be parsed back (edited or damaged database).
    #[error("corrupt value in the campaign database: {0}")]
    Corrupt(String),
    /// A store call on a blocking thread panicked or was cancelled ([`super::StoreHandle`]).
    #[error("store task failed: {0}")]
    Task(String),
    /// The caller passed a value the store refuses (e.g. a non-finite coordinate, a joint
    /// vector of the wrong length, duplicated pose indices); nothing was written.
    #[error("refused by the campaign store: {0}")]
    Invalid(String),
}

/// Attach the operation name to a rusqlite result.
pub(crate) trait Ctx<T> {
    /// Map a rusqlite error to [`StoreError::Sqlite`] naming `op`.
    fn ctx(self, op: &'static str) -> Result<T, StoreError>;
}

impl<T> Ctx<T> for Result<T, rusqlite::Error> {
    fn ctx(self, op: &'static str) -> Result<T, StoreError> {
        self.map_err(|cause| StoreError::Sqlite { op, cause })
    }
}
