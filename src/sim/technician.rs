//! [`SimTechnician`]: in a simulated cell with a manual micrometer, whatever the technician
//! answers is what their hand did: a typed reading sets the simulated micrometer to that value
//! (a confirmation without a number sets it to the requested value).

use async_trait::async_trait;
use std::sync::Arc;

use super::world::{lock_world, SharedWorld};
use crate::cell::{Answer, CellError, Prompt, Prompter};

/// Wraps the real prompter (terminal, web, scripted) and moves the simulated micrometer.
pub struct SimTechnician {
    inner: Arc<dyn Prompter>,
    world: SharedWorld,
}

impl SimTechnician {
    /// Ask through `inner`; stage answers move the micrometer of `world`.
    pub fn new(inner: Arc<dyn Prompter>, world: SharedWorld) -> SimTechnician {
        SimTechnician { inner, world }
    }
}

#[async_trait]
impl Prompter for SimTechnician {
    /// Cancel-safe as the [`Prompter`] contract asks: the micrometer moves only after the answer,
    /// with no await after it.
    async fn ask(&self, prompt: Prompt) -> Result<Answer, CellError> {
        let expected = prompt.expected_mm;
        let stage = prompt.id.starts_with("stage");
        let answer = self.inner.ask(prompt).await?;
        if stage {
            let set = match (&answer, expected) {
                (Answer::Number(v), _) => Some(*v),
                (Answer::Confirmed, Some(e)) => Some(e),
                _ => None,
            };
            if let Some(v) = set {
                lock_world(&self.world).set_manual_stage_mm(v);
            }
        }
        Ok(answer)
    }
}
