//! [`ManualStage`]: a micrometer the technician turns, driven through a [`Prompter`]. Without a
//! gauge the technician types the reading; with an RS-232 gauge ([`GaugeReader`]) the
//! technician only confirms and the reading comes from the gauge.

use std::sync::Arc;

use async_trait::async_trait;
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncRead, AsyncWrite};
use tracing::{info, warn};
use zaber::{GaugeClient, GaugeError};

use super::{
    Answer, CellError, DeviceKind, FaultKind, Prompt, PromptContext, Prompter, Stage, CONFIRM_CLEAR,
};

/// The question asked before the robot moves again after a manual stage move.
const CLEAR_TEXT: &str = "Confirm that the cell is clear (no hand or tool at the stage or in the \
     robot's reach): the robot moves next";

/// Configuration of a [`ManualStage`] (serde: every field has a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ManualStageConfig {
    /// Largest accepted |reading − requested| (mm).
    pub tolerance_mm: f64,
    /// How many times the technician is asked before the move fails.
    pub max_tries: u32,
    /// After a move, the robot may not move again before the technician confirmed the cell
    /// clear ([`Stage::confirm_clear`]; `[stage] confirm_clear`).
    pub confirm_clear: bool,
}

impl Default for ManualStageConfig {
    fn default() -> Self {
        ManualStageConfig {
            tolerance_mm: 0.02,
            max_tries: 3,
            confirm_clear: true,
        }
    }
}

/// A position gauge read by the software (RS-232 micrometer or indicator).
#[async_trait]
pub trait GaugeReader: Send + Sync {
    /// One reading (mm).
    /// Must be cancel-safe: a dropped reading must not be returned by the next call.
    async fn read_mm(&mut self) -> Result<f64, GaugeError>;
}

#[async_trait]
impl<S: AsyncRead + AsyncWrite + Unpin + Send + Sync> GaugeReader for GaugeClient<S> {
    /// Cancel-safe (see [`GaugeClient::read_mm`]).
    async fn read_mm(&mut self) -> Result<f64, GaugeError> {
        GaugeClient::read_mm(self).await
    }
}

/// Classify a gauge error for the campaign.
pub fn classify_gauge(e: &GaugeError) -> FaultKind {
    match e {
        GaugeError::Timeout => FaultKind::Timeout,
        GaugeError::WrongUnit(_) | GaugeError::OutOfRange(_) | GaugeError::DeviceStatus(_) => {
            FaultKind::Device
        }
        GaugeError::Protocol(_) => FaultKind::Protocol,
        GaugeError::Disconnected | GaugeError::Io(_) => FaultKind::Disconnected,
    }
}

/// A manually set micrometer stage, optionally read back by a gauge.
pub struct ManualStage {
    prompter: Arc<dyn Prompter>,
    gauge: Option<Box<dyn GaugeReader>>,
    cfg: ManualStageConfig,
    /// The engine's context for the next move's questions.
    context: PromptContext,
}

impl std::fmt::Debug for ManualStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManualStage")
            .field("cfg", &self.cfg)
            .field("gauge", &self.gauge.is_some())
            .finish_non_exhaustive()
    }
}

/// Ask `text` about setting the stage to `target`; `retry` says why the last answer was refused.
/// Cancel-safe as the [`Prompter`] contract asks (no state changes of its own).
async fn ask(
    prompter: &Arc<dyn Prompter>,
    with_gauge: bool,
    target: f64,
    text: String,
    context: &PromptContext,
    retry: Option<String>,
) -> Result<Answer, CellError> {
    let prompt = Prompt {
        id: "stage_move".into(),
        text,
        expected_mm: (!with_gauge).then_some(target),
        context: PromptContext {
            retry_reason: retry,
            ..context.clone()
        },
    };
    let a = prompter.ask(prompt).await?;
    if a == Answer::Abort {
        return Err(stage_err(
            FaultKind::Aborted,
            format!("the technician aborted while setting the micrometer to {target:.3} mm"),
        ));
    }
    Ok(a)
}

fn stage_err(kind: FaultKind, msg: impl Into<String>) -> CellError {
    CellError::new(DeviceKind::Stage, kind, msg)
}

impl ManualStage {
    /// The technician types the micrometer reading.
    pub fn new(prompter: Arc<dyn Prompter>, cfg: ManualStageConfig) -> ManualStage {
        ManualStage {
            prompter,
            gauge: None,
            cfg,
            context: PromptContext::default(),
        }
    }

    /// The technician moves the micrometer and confirms; the reading comes from `gauge`.
    pub fn with_gauge(
        prompter: Arc<dyn Prompter>,
        gauge: Box<dyn GaugeReader>,
        cfg: ManualStageConfig,
    ) -> ManualStage {
        ManualStage {
            prompter,
            gauge: Some(gauge),
            cfg,
            context: PromptContext::default(),
        }
    }

    /// Open an RS-232 gauge on `port` and use it (see [`ManualStage::with_gauge`]).
    pub fn with_gauge_port(
        prompter: Arc<dyn Prompter>,
        port: &str,
        gauge_cfg: zaber::GaugeConfig,
        cfg: ManualStageConfig,
    ) -> Result<ManualStage, CellError> {
        let g = GaugeClient::open(port, gauge_cfg)
            .map_err(|e| stage_err(classify_gauge(&e), format!("gauge {port}: {e}")))?;
        Ok(ManualStage::with_gauge(prompter, Box::new(g), cfg))
    }

    /// The configuration.
    pub fn config(&self) -> &ManualStageConfig {
        &self.cfg
    }

    fn request_text(&self, target: f64) -> String {
        if self.gauge.is_some() {
            format!("Move the micrometer to {target:.3} mm and confirm")
        } else {
            format!("Set the micrometer to {target:.3} mm and enter the reading")
        }
    }
}

#[async_trait]
impl Stage for ManualStage {
    fn is_manual(&self) -> bool {
        true
    }

    /// Cancel-safe: it only reads the gauge.
    async fn prepare(&mut self) -> Result<(), CellError> {
        if let Some(g) = self.gauge.as_mut() {
            let v = g
                .read_mm()
                .await
                .map_err(|e| stage_err(classify_gauge(&e), format!("gauge not answering: {e}")))?;
            info!(reading_mm = v, "gauge answers");
        }
        Ok(())
    }

    fn set_prompt_context(&mut self, context: PromptContext) {
        self.context = context;
    }

    fn needs_clear(&self) -> bool {
        self.cfg.confirm_clear
    }

    /// Ask [`CONFIRM_CLEAR`] until the technician answers [`Answer::Clear`] (any other answer is
    /// asked again, with the reason; abort aborts). Cancel-safe: a drop withdraws the question
    /// (see [`Prompter`]) and confirms nothing.
    async fn confirm_clear(&mut self, context: PromptContext) -> Result<(), CellError> {
        if !self.cfg.confirm_clear {
            return Ok(());
        }
        let mut retry: Option<String> = None;
        for _ in 0..self.cfg.max_tries.max(1) {
            let text = match &retry {
                Some(why) => format!("{why}. {CLEAR_TEXT}"),
                None => CLEAR_TEXT.to_owned(),
            };
            let prompt = Prompt {
                id: CONFIRM_CLEAR.into(),
                text,
                expected_mm: None,
                context: PromptContext {
                    retry_reason: retry.take(),
                    ..context.clone()
                },
            };
            match self.prompter.ask(prompt).await? {
                Answer::Clear => {
                    info!("technician confirmed the cell clear");
                    return Ok(());
                }
                Answer::Abort => {
                    return Err(stage_err(
                        FaultKind::Aborted,
                        "the technician aborted instead of confirming the cell clear",
                    ))
                }
                _ => {
                    retry = Some(
                        "Only the separate \"cell clear\" confirmation releases the robot".into(),
                    )
                }
            }
        }
        Err(stage_err(
            FaultKind::Rejected,
            "the cell was not confirmed clear: the robot does not move",
        ))
    }

    /// With a gauge: one reading; without: nothing to ask before the campaign. Cancel-safe:
    /// it only reads the gauge.
    async fn check(&mut self) -> Result<String, CellError> {
        match self.gauge.as_mut() {
            Some(g) => {
                let v = g.read_mm().await.map_err(|e| {
                    stage_err(classify_gauge(&e), format!("gauge not answering: {e}"))
                })?;
                Ok(format!(
                    "manual micrometer read by its RS-232 gauge; the gauge reads {v:.3} mm"
                ))
            }
            None => Ok(
                "manual micrometer: the technician types its readings once the \
                        campaign runs (nothing to check before)"
                    .to_owned(),
            ),
        }
    }

    fn identity(&self) -> Option<String> {
        Some(match self.gauge {
            Some(_) => "manual micrometer read by its RS-232 gauge".to_owned(),
            None => "manual micrometer (the technician's readings)".to_owned(),
        })
    }

    /// Cancel-safe: a drop withdraws the question (see [`Prompter`]) or a gauge reading; the move's
    /// prompt context is used up, so a repeated move asks without it (claiming nothing).
    async fn move_to(&mut self, position_mm: f64) -> Result<f64, CellError> {
        // the context holds for this move only: a later move without one claims nothing
        let context = std::mem::take(&mut self.context);
        if !position_mm.is_finite() {
            return Err(stage_err(
                FaultKind::Rejected,
                "target is not a finite number",
            ));
        }
        let tol = self.cfg.tolerance_mm;
        let request = self.request_text(position_mm);
        let mut retry: Option<String> = None;
        for attempt in 1..=self.cfg.max_tries.max(1) {
            let text = match &retry {
                Some(why) => format!("{why}. {request}"),
                None => request.clone(),
            };
            let answer = ask(
                &self.prompter,
                self.gauge.is_some(),
                position_mm,
                text,
                &context,
                retry.take(),
            )
            .await?;
            let reading = match (self.gauge.as_mut(), answer) {
                (Some(g), _) => g.read_mm().await.map_err(|e| {
                    stage_err(classify_gauge(&e), format!("gauge reading failed: {e}"))
                })?,
                (None, Answer::Number(v)) if v.is_finite() => v,
                (None, _) => {
                    warn!(attempt, "manual stage: no number given");
                    retry = Some("A number is needed (the micrometer reading in mm)".into());
                    continue;
                }
            };
            let off = reading - position_mm;
            if off.abs() <= tol {
                info!(
                    target_mm = position_mm,
                    reading_mm = reading,
                    "manual stage set"
                );
                return Ok(reading);
            }
            warn!(
                attempt,
                target_mm = position_mm,
                reading_mm = reading,
                "manual stage out of tolerance"
            );
            let source = if self.gauge.is_some() {
                "The gauge reads"
            } else {
                "The reading"
            };
            retry = Some(format!(
                "{source} {reading:.3} mm, {:.3} mm from the requested {position_mm:.3} mm (tolerance {tol:.3} mm)",
                off.abs()
            ));
        }
        Err(stage_err(
            FaultKind::Rejected,
            format!(
                "no reading within {tol:.3} mm of {position_mm:.3} mm after {} tries",
                self.cfg.max_tries.max(1)
            ),
        ))
    }
}
