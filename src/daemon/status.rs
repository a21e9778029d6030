//! The one owner of a loaded run's changing facts: the engine's state (the observer writes it
//! from the journal), the technician question waiting for its answer (the prompt pump writes
//! it, commands take it) and, once the engine has returned, how the run ended. One `watch`
//! channel holds all three, so a command's reply waits on one thing ([`RunWatch::settled`]) and
//! the end is never seen without its outcome.

use std::fmt;
use std::sync::Arc;

use tokio::sync::watch;

use crate::cell::PendingPrompt;
use crate::store::StoredState;

/// How a run of this daemon ended: `done`, `aborted` or `failed: <reason>` (its
/// [`fmt::Display`], the view's `last_outcome`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RunOutcome {
    /// Every pose measured and the result stored.
    Done,
    /// Aborted by the operator.
    Aborted,
    /// Stopped by a fault or an error (the reason).
    Failed(String),
}

impl fmt::Display for RunOutcome {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RunOutcome::Done => f.write_str("done"),
            RunOutcome::Aborted => f.write_str("aborted"),
            RunOutcome::Failed(r) => write!(f, "failed: {r}"),
        }
    }
}

/// What a loaded run is doing.
#[derive(Debug, Default)]
pub(super) struct RunStatus {
    /// The engine's state in this run (`None` until it writes its first).
    pub(super) state: Option<StoredState>,
    /// The question waiting for the technician (kept after it is answered, until replaced).
    pub(super) prompt: Option<PendingPrompt>,
    /// How the run ended, once its engine has returned (and let go of campaign and cell).
    pub(super) outcome: Option<RunOutcome>,
}

/// The handle on a run's [`RunStatus`]: clones share it.
#[derive(Debug, Clone)]
pub(super) struct RunWatch {
    tx: Arc<watch::Sender<RunStatus>>,
}

impl RunWatch {
    /// A new run: no state, no question, not ended.
    pub(super) fn new() -> RunWatch {
        RunWatch {
            tx: Arc::new(watch::channel(RunStatus::default()).0),
        }
    }

    /// Read the status (briefly: writers wait meanwhile).
    pub(super) fn read<T>(&self, f: impl FnOnce(&RunStatus) -> T) -> T {
        f(&self.tx.borrow())
    }

    /// Change the status with `f`; waiters are woken when `f` returns true.
    pub(super) fn update<T>(&self, f: impl FnOnce(&mut RunStatus) -> (T, bool)) -> T {
        let mut out = None;
        self.tx.send_if_modified(|s| {
            let (v, changed) = f(s);
            out = Some(v);
            changed
        });
        match out {
            Some(v) => v,
            // send_if_modified always runs its closure
            None => unreachable!("send_if_modified ran no closure"),
        }
    }

    /// The engine's state is now `state`.
    pub(super) fn set_state(&self, state: StoredState) {
        self.tx.send_modify(|s| s.state = Some(state));
    }

    /// The run has ended with `outcome`.
    pub(super) fn end(&self, outcome: RunOutcome) {
        self.tx.send_modify(|s| s.outcome = Some(outcome));
    }

    /// Whether the run has ended.
    pub(super) fn has_ended(&self) -> bool {
        self.read(|s| s.outcome.is_some())
    }

    /// Until the run has ended. Cancel-safe (it only waits).
    pub(super) async fn ended(&self) {
        let mut rx = self.tx.subscribe();
        // every sender gone: nothing can end it later either
        let _ = rx.wait_for(|s| s.outcome.is_some()).await;
    }

    /// Until the engine's state is one `settled` accepts or the run has ended; with
    /// `or_asking`, also while a technician question is open (the engine waits for the
    /// technician, so nothing settles before their answer). Cancel-safe (it only waits).
    pub(super) async fn settled(&self, settled: fn(StoredState) -> bool, or_asking: bool) {
        let mut rx = self.tx.subscribe();
        let _ = rx
            .wait_for(|s| {
                s.outcome.is_some()
                    || s.state.is_some_and(settled)
                    || (or_asking && s.prompt.as_ref().is_some_and(PendingPrompt::is_open))
            })
            .await;
    }
}
