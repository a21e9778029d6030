//! Terminal front end of the campaign (binary only: the library never prints): the technician
//! prompter and the event printer with a progress bar.

use std::io::{BufRead, Write};

use async_trait::async_trait;
use indicatif::{ProgressBar, ProgressStyle};
use tokio::sync::broadcast;

use cellcal::campaign::{CampaignCommand, CampaignEvent, CampaignState, Control, Journalled};
use cellcal::cell::{Answer, CellError, DeviceKind, FaultKind, Prompt, Prompter, CONFIRM_CLEAR};
use cellcal::progress::Progress;
use cellcal::report::setup_summary_lines;

/// Asks the technician on the terminal; `a` (or end of input) aborts. The question that
/// releases the robot after a manual stage answer ([`CONFIRM_CLEAR`]) takes only its own key,
/// `c` (never a bare Enter, which answers the other questions).
pub struct TerminalPrompter;

/// The answer to a [`CONFIRM_CLEAR`] question: `c` confirms the cell clear, `a` aborts; `None`
/// for anything else (a bare Enter included).
fn parse_clear(line: &str) -> Option<Answer> {
    match line.trim() {
        "c" | "C" | "clear" => Some(Answer::Clear),
        "a" | "A" | "abort" => Some(Answer::Abort),
        _ => None,
    }
}

/// A typed answer: `a` aborts, an empty line confirms, else a reading in mm (`10.003` or
/// `10,003`); `None` when it is none of these.
fn parse_answer(line: &str) -> Option<Answer> {
    let t = line.trim();
    match t {
        "a" | "abort" | "A" => Some(Answer::Abort),
        "" => Some(Answer::Confirmed),
        _ => t
            .replacen(',', ".", 1)
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .map(Answer::Number),
    }
}

#[async_trait]
impl Prompter for TerminalPrompter {
    /// Cancel-safe as the [`Prompter`] contract asks, with one cost: a dropped question's blocking
    /// thread keeps reading stdin, so the next line typed answers it (and is dropped with it); the
    /// engine drops a question only on abort, which ends the terminal run.
    async fn ask(&self, prompt: Prompt) -> Result<Answer, CellError> {
        tokio::task::spawn_blocking(move || {
            let stdin = std::io::stdin();
            let clear = prompt.id == CONFIRM_CLEAR;
            loop {
                let hint = if clear {
                    "type c and Enter when the cell is clear, or a to abort"
                } else if prompt.expected_mm.is_some() {
                    "reading in mm, or a to abort"
                } else {
                    "Enter to confirm, or a to abort"
                };
                eprint!(
                    "\n[{}]\n{} [{hint}]: ",
                    prompt.context.describe(),
                    prompt.text
                );
                let _ = std::io::stderr().flush();
                let mut line = String::new();
                match stdin.lock().read_line(&mut line) {
                    Ok(0) | Err(_) => return Ok(Answer::Abort),
                    Ok(_) => {}
                }
                if clear {
                    match parse_clear(&line) {
                        Some(a) => return Ok(a),
                        None => eprintln!("the robot moves only after c (cell clear); a aborts"),
                    }
                    continue;
                }
                match parse_answer(&line) {
                    Some(Answer::Confirmed) if prompt.expected_mm.is_some() => {
                        eprintln!(
                            "please type the reading in mm (e.g. 10.003 or 10,003), or a to abort"
                        );
                    }
                    Some(a) => return Ok(a),
                    None => eprintln!(
                        "`{}` is not a number; type the reading in mm, or a to abort",
                        line.trim()
                    ),
                }
            }
        })
        .await
        .map_err(|e| CellError::new(DeviceKind::Operator, FaultKind::Aborted, e.to_string()))?
    }
}

/// The operator at the terminal: when the campaign pauses for a fault, show why and wait for
/// Enter (resume), `r` (resume and re-register a moved tracker frame) or `a` (abort).
/// Cancel-safe: the command is applied without an await after the answer; a drop while waiting for
/// the answer leaves its blocking thread reading stdin (that line is then ignored).
pub async fn ask_on_pause(mut rx: broadcast::Receiver<Journalled>, control: Control) {
    loop {
        let reason = match rx.recv().await.map(|j| j.event) {
            Ok(CampaignEvent::State {
                state: CampaignState::Paused { reason },
            }) => reason,
            Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
            Err(broadcast::error::RecvError::Closed) => return,
        };
        let answer = tokio::task::spawn_blocking(move || {
            let offer = if reason.contains("re-register") {
                ", r to re-register"
            } else {
                ""
            };
            eprint!("\nCampaign paused: {reason}\nFix the cause, then press Enter to resume{offer}, or type a to abort: ");
            let _ = std::io::stderr().flush();
            let mut line = String::new();
            match std::io::stdin().lock().read_line(&mut line) {
                Ok(0) | Err(_) => CampaignCommand::Abort,
                Ok(_) if !offer.is_empty() && matches!(line.trim(), "r" | "R") => {
                    CampaignCommand::Reregister
                }
                Ok(_) => match parse_answer(&line) {
                    Some(Answer::Abort) => CampaignCommand::Abort,
                    _ => CampaignCommand::Resume,
                },
            }
        })
        .await
        .unwrap_or(CampaignCommand::Abort);
        control.apply(&answer);
    }
}

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Display {
    /// A progress bar (nobody is asked anything at this terminal); the other events' lines
    /// above it.
    Bar,
    /// The progress lines (`progress: …`, [`Progress`]), written as they happen: a pose line
    /// every `every` poses, every other event's line; questions at the terminal are never
    /// overdrawn.
    Lines {
        /// Print a pose line every this many poses (and the last).
        every: usize,
    },
    /// No progress: only faults, stops and a run's failed or aborted end.
    Quiet,
}

/// Print campaign events until the run's final state (`done`, `aborted`, `failed`) or the
/// channel's end, each line of `progress` written (and flushed: stderr is unbuffered) as its
/// event arrives.
/// Cancel-safe: it only receives and prints.
pub async fn print_events(
    mut rx: broadcast::Receiver<Journalled>,
    total: usize,
    display: Display,
    mut progress: Progress,
) {
    let bar = if display == Display::Bar {
        ProgressBar::new(total as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} poses  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    // a line above the bar, or on its own
    let line = |text: &str| {
        if display == Display::Bar {
            bar.println(text);
        } else {
            eprintln!("{text}");
        }
    };
    loop {
        let j = match rx.recv().await {
            Ok(j) => j,
            Err(broadcast::error::RecvError::Lagged(_)) => continue,
            Err(broadcast::error::RecvError::Closed) => break,
        };
        let Some(text) = progress.line(&j) else {
            if matches!(j.event, CampaignEvent::Result { .. }) {
                bar.finish_and_clear();
            }
            continue;
        };
        let ends = j.event.ends_run();
        match (&j.event, display) {
            // the prompter asks the question itself
            (CampaignEvent::Prompt { .. }, _) => {}
            (CampaignEvent::Measured { done, total, .. }, Display::Lines { every }) => {
                if done % every.max(1) == 0 || done == total {
                    eprintln!("progress: {text}");
                }
            }
            (_, Display::Lines { .. }) => eprintln!("progress: {text}"),
            (CampaignEvent::Measured { done, .. }, _) => {
                bar.set_position(*done as u64);
            }
            (CampaignEvent::State { state }, _) => {
                let name = match state.reason() {
                    Some(reason) => format!("{}: {reason}", state.name()),
                    None => state.name().to_owned(),
                };
                bar.set_message(name.clone());
                if matches!(state, CampaignState::Failed { .. } | CampaignState::Aborted) {
                    line(&format!("campaign {name}"));
                }
            }
            (CampaignEvent::Fault { .. } | CampaignEvent::Stopped { .. }, _) => line(&text),
            (CampaignEvent::Drift { .. }, _) => bar.set_message(text),
            (_, Display::Quiet) => {}
            (_, _) => line(&text),
        }
        if let (CampaignEvent::Setup { result }, false) = (&j.event, display == Display::Quiet) {
            for detail in setup_summary_lines(result) {
                line(&detail);
            }
        }
        if ends {
            break;
        }
    }
    bar.finish_and_clear();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers() {
        assert_eq!(parse_answer("10.003\n"), Some(Answer::Number(10.003)));
        assert_eq!(parse_answer("10,003\n"), Some(Answer::Number(10.003)));
        assert_eq!(parse_answer("10,003,1"), None);
        assert_eq!(parse_answer("a\n"), Some(Answer::Abort));
        assert_eq!(parse_answer("\n"), Some(Answer::Confirmed));
        assert_eq!(parse_answer("ten"), None);
        assert_eq!(parse_answer("NaN"), None);
        assert_eq!(parse_clear("c\n"), Some(Answer::Clear));
        assert_eq!(
            parse_clear("\n"),
            None,
            "a bare Enter does not release the robot"
        );
        assert_eq!(parse_clear("10.0"), None);
        assert_eq!(parse_clear("a"), Some(Answer::Abort));
    }
}
