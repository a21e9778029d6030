//! The store's owners: [`StoreHandle`] owns the one writer connection behind its lock (as
//! mini-redis' `Db` owns its state), [`ReaderPool`] the reading connections. No module outside
//! `store/` reaches the lock: every caller passes a closure (run on a blocking thread by the
//! async methods) or calls a typed operation.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

use super::error::StoreError;
use super::records::{JournalEntry, JournalEvent};
use super::{Store, StoreReader};

/// The shared writer of one store: clones share the connection; calls are serialised.
///
/// A poisoned lock (a closure panicked) is taken over: every store write is one SQLite
/// transaction, rolled back when its guard dropped in the panic, so the connection is sound.
#[derive(Debug, Clone)]
pub struct StoreHandle {
    writer: Arc<Mutex<Store>>,
}

impl StoreHandle {
    /// The handle that owns `store` from now on.
    pub fn new(store: Store) -> StoreHandle {
        StoreHandle {
            writer: Arc::new(Mutex::new(store)),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Store> {
        self.writer.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Run `f` on the writer on this thread, holding the lock while it runs. Blocking: for
    /// blocking threads and synchronous code only, never on the async runtime's workers.
    pub fn blocking<R>(&self, f: impl FnOnce(&mut Store) -> R) -> R {
        f(&mut self.lock())
    }

    /// Run `f` on the writer on a blocking thread. Cancel-safe in effect: the call runs to its
    /// end even when this future is dropped (its result is then lost, its writes are not).
    pub async fn call<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Store) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, StoreError> {
        let me = self.clone();
        tokio::task::spawn_blocking(move || me.blocking(f))
            .await
            .map_err(|e| StoreError::Task(e.to_string()))?
    }

    /// Journal `event` for campaign `id` at `at_ms` and hand the stored entry to `publish`
    /// while still holding the lock, so entries reach `publish` in journal order and each is
    /// stored before anyone sees it. Returns the sequence number. Cancel-safe as
    /// [`StoreHandle::call`]: a dropped call still journals and publishes exactly once.
    pub async fn journal<E: JournalEvent + Send + 'static>(
        &self,
        id: i64,
        at_ms: i64,
        event: E,
        publish: impl FnOnce(JournalEntry<E>) + Send + 'static,
    ) -> Result<i64, StoreError> {
        self.call(move |s| {
            let seq = s.add_event(id, at_ms, &event)?;
            publish(JournalEntry { seq, at_ms, event });
            Ok(seq)
        })
        .await
    }
}

/// Readers kept open for reuse (more may be open at once; the surplus is closed).
const IDLE_READERS: usize = 4;

/// Reading connections to one store file ([`StoreReader`]), opened on demand and kept for
/// reuse: readers never take the writer's lock and never write.
#[derive(Debug)]
pub struct ReaderPool {
    path: PathBuf,
    idle: Mutex<Vec<StoreReader>>,
}

impl ReaderPool {
    /// A pool for the migrated store at `path`, with one reader opened now (so a file this
    /// cellcal cannot read is refused at once). Blocking.
    pub fn open(path: &Path) -> Result<Arc<ReaderPool>, StoreError> {
        let first = Store::open_reader(path)?;
        Ok(Arc::new(ReaderPool {
            path: path.to_owned(),
            idle: Mutex::new(vec![first]),
        }))
    }

    /// The store file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn idle(&self) -> MutexGuard<'_, Vec<StoreReader>> {
        self.idle.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Run `f` on an idle reader (or a new one) on this thread. Blocking.
    pub fn blocking<T>(
        &self,
        f: impl FnOnce(&Store) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let idle = self.idle().pop();
        let reader = match idle {
            Some(r) => r,
            None => Store::open_reader(&self.path)?,
        };
        let out = f(&reader);
        let mut idle = self.idle();
        if idle.len() < IDLE_READERS {
            idle.push(reader);
        }
        out
    }

    /// Run `f` on a reader on a blocking thread. Cancel-safe: it only reads.
    pub async fn read<T: Send + 'static>(
        self: &Arc<Self>,
        f: impl FnOnce(&Store) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, StoreError> {
        let me = Arc::clone(self);
        tokio::task::spawn_blocking(move || me.blocking(f))
            .await
            .map_err(|e| StoreError::Task(e.to_string()))?
    }
}
