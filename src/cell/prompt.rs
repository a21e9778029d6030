//! Prompters without a terminal: [`ScriptedPrompter`] (answers from a closure or a queue, for
//! headless runs and tests) and [`ChannelPrompter`] (prompts go out on a channel, answers come
//! back on a oneshot: the campaign engine and the REST API use it).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use async_trait::async_trait;
use tokio::sync::{mpsc, oneshot};

use super::{Answer, CellError, DeviceKind, FaultKind, Prompt, Prompter};

type AnswerFn = dyn Fn(&Prompt) -> Answer + Send + Sync;

enum Script {
    Func(Box<AnswerFn>),
    Queue(VecDeque<Answer>),
}

/// Answers prompts automatically and records every prompt it was asked.
pub struct ScriptedPrompter {
    script: Mutex<Script>,
    asked: Mutex<Vec<Prompt>>,
}

impl std::fmt::Debug for ScriptedPrompter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScriptedPrompter")
            .field("asked", &self.asked().len())
            .finish_non_exhaustive()
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl ScriptedPrompter {
    /// Answer every prompt with `f(prompt)`.
    pub fn from_fn(f: impl Fn(&Prompt) -> Answer + Send + Sync + 'static) -> ScriptedPrompter {
        ScriptedPrompter {
            script: Mutex::new(Script::Func(Box::new(f))),
            asked: Mutex::new(Vec::new()),
        }
    }

    /// Answer prompts from a queue, front first; an empty queue is an operator error (`Aborted`).
    pub fn from_answers(answers: impl IntoIterator<Item = Answer>) -> ScriptedPrompter {
        ScriptedPrompter {
            script: Mutex::new(Script::Queue(answers.into_iter().collect())),
            asked: Mutex::new(Vec::new()),
        }
    }

    /// The ideal technician: gives the expected number exactly, confirms the cell clear when
    /// asked to, otherwise confirms.
    pub fn exact() -> ScriptedPrompter {
        ScriptedPrompter::from_fn(|p| match p.expected_mm {
            Some(v) => Answer::Number(v),
            None if p.id == super::CONFIRM_CLEAR => Answer::Clear,
            None => Answer::Confirmed,
        })
    }

    /// Every prompt asked so far, oldest first.
    pub fn asked(&self) -> Vec<Prompt> {
        lock(&self.asked).clone()
    }
}

#[async_trait]
impl Prompter for ScriptedPrompter {
    /// Cancel-safe: no await, so it runs to completion or not at all.
    async fn ask(&self, prompt: Prompt) -> Result<Answer, CellError> {
        lock(&self.asked).push(prompt.clone());
        match &mut *lock(&self.script) {
            Script::Func(f) => Ok(f(&prompt)),
            Script::Queue(q) => q.pop_front().ok_or_else(|| {
                CellError::new(
                    DeviceKind::Operator,
                    FaultKind::Aborted,
                    format!("no scripted answer left for prompt `{}`", prompt.id),
                )
            }),
        }
    }
}

/// A prompt waiting for its answer (received from a [`ChannelPrompter`]).
#[derive(Debug)]
pub struct PendingPrompt {
    /// Sequence number, unique per prompter (1, 2, …).
    pub seq: u64,
    /// The question.
    pub prompt: Prompt,
    reply: oneshot::Sender<Answer>,
}

impl PendingPrompt {
    /// Answer the prompt; false if the asker is gone.
    pub fn answer(self, answer: Answer) -> bool {
        self.reply.send(answer).is_ok()
    }

    /// Whether the asker still waits for the answer: false once its question was dropped (an
    /// abort, the end of the run), so a front end stops offering it.
    pub fn is_open(&self) -> bool {
        !self.reply.is_closed()
    }
}

/// Sends prompts on an mpsc channel and waits for the answer on a oneshot.
#[derive(Debug, Clone)]
pub struct ChannelPrompter {
    tx: mpsc::Sender<PendingPrompt>,
    seq: Arc<AtomicU64>,
}

impl ChannelPrompter {
    /// A prompter and the receiving end that a front end (terminal, REST API) serves.
    pub fn new(capacity: usize) -> (ChannelPrompter, mpsc::Receiver<PendingPrompt>) {
        let (tx, rx) = mpsc::channel(capacity.max(1));
        (
            ChannelPrompter {
                tx,
                seq: Arc::new(AtomicU64::new(0)),
            },
            rx,
        )
    }
}

#[async_trait]
impl Prompter for ChannelPrompter {
    /// Cancel-safe as the [`Prompter`] contract asks: a dropped call drops the answer's receiver,
    /// so an answer to that question (matched by `seq`) reaches nobody and never a later question.
    async fn ask(&self, prompt: Prompt) -> Result<Answer, CellError> {
        let (reply, rx) = oneshot::channel();
        let seq = self.seq.fetch_add(1, Ordering::Relaxed) + 1;
        let id = prompt.id.clone();
        self.tx
            .send(PendingPrompt { seq, prompt, reply })
            .await
            .map_err(|_| {
                CellError::new(
                    DeviceKind::Operator,
                    FaultKind::Disconnected,
                    "no front end is listening for prompts",
                )
            })?;
        rx.await.map_err(|_| {
            CellError::new(
                DeviceKind::Operator,
                FaultKind::Disconnected,
                format!("prompt `{id}` was dropped without an answer"),
            )
        })
    }
}
