//! `cellcal run`: a campaign from the terminal (plan, measure, store, identify); simulated
//! devices start in-process.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{anyhow, Context};

use cellcal::campaign::iso::is_iso_campaign;
use cellcal::campaign::session::{open_session, Resume, Session, SessionError};
use cellcal::campaign::stored::{stored_model_toml, stored_result};
use cellcal::campaign::{run_campaign, CampaignCommand, Control, Devices, FaultPolicy, Outcome};
use cellcal::cell::Prompter;
use cellcal::config::{load_cell_config, CellConfig, DeviceMode, StageMode};
use cellcal::iso9283::{format_table, IsoReport};
use cellcal::plan::CampaignEstimate;
use cellcal::progress::Progress;
use cellcal::report::summary_text;
use cellcal::sim::RunningSimCell;
use cellcal::store::Store;
use cellcal::units::human::fmt_estimate;

use super::identify::{poor_is_exit_3, write_file};
use super::{input, other, runtime, Failure};
use crate::signals::{StopSignal, StopSignals};
use crate::terminal::{ask_on_pause, print_events, Display, TerminalPrompter};

/// Arguments of `cellcal run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Cell configuration file (TOML).
    #[arg(long, default_value = "config/cell.sim.toml")]
    config: PathBuf,
    /// Allow motion and start at once (without it the campaign is only planned and stored).
    #[arg(long)]
    arm: bool,
    /// Write the result (the `cellcal identify` JSON contract) here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the corrected model here: a robot TOML with the identified absolute values
    /// that every command takes as `--robot` (as `GET /api/campaigns/{id}/model`).
    #[arg(long)]
    model_out: Option<PathBuf>,
    /// Store file (default: `store` of the configuration).
    #[arg(long)]
    store: Option<PathBuf>,
    /// Resume this stored campaign at its first unmeasured pose.
    #[arg(long)]
    campaign: Option<i64>,
    /// Progress on stderr: `bar` (a progress bar; plain lines while questions may be asked at
    /// the terminal), `lines` (a line per measured pose and per state change, written as it
    /// happens: for pipes, nohup and the journal) or `none`. Default: `bar` when stderr is a
    /// terminal, else `lines`.
    #[arg(long, value_enum)]
    progress: Option<ProgressMode>,
    /// Same as `--progress none`.
    #[arg(long, conflicts_with = "progress")]
    quiet: bool,
    /// What a fault that needs the operator does: `pause` (ask at the terminal: resume or
    /// abort) or `fail` (stop, resumable). Default: `pause` when stdin is a terminal.
    #[arg(long, value_parser = ["pause", "fail"])]
    on_fault: Option<String>,
    /// Resume `--campaign` although the configuration or robot model changed since it was
    /// created (the changed keys are journalled).
    #[arg(long, requires = "campaign")]
    accept_changed_config: bool,
    /// Resume `--campaign` even if the tracker or the robot moved since its last session:
    /// re-register the tracker frame (points of the old frame measured again at their
    /// joints, a new frame segment fitted to them) instead of stopping.
    #[arg(long, requires = "campaign")]
    reregister: bool,
}

/// The values of `--progress`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ProgressMode {
    /// A progress bar.
    Bar,
    /// A line per measured pose and per state change.
    Lines,
    /// No progress output.
    #[value(name = "none")]
    Off,
}

impl RunArgs {
    /// `--progress` (`none` with `--quiet`), else `bar` at a terminal and `lines` otherwise.
    fn progress_mode(&self) -> ProgressMode {
        match (self.quiet, self.progress) {
            (true, _) => ProgressMode::Off,
            (false, Some(m)) => m,
            (false, None) if std::io::stderr().is_terminal() => ProgressMode::Bar,
            (false, None) => ProgressMode::Lines,
        }
    }

    /// `--on-fault`, or `pause` when a person can answer at the terminal.
    fn fault_policy(&self) -> FaultPolicy {
        match self.on_fault.as_deref() {
            Some("pause") => FaultPolicy::Pause,
            Some(_) => FaultPolicy::Fail,
            None if std::io::stdin().is_terminal() => FaultPolicy::Pause,
            None => FaultPolicy::Fail,
        }
    }
}

/// Run a campaign headless (or with terminal prompts for a manual stage).
pub fn run(opts: RunArgs) -> Result<(), Failure> {
    let cfg = load_cell_config(&opts.config).map_err(input)?;
    if opts.arm {
        refuse_manual_without_terminal(&cfg, std::io::stdin().is_terminal())?;
    }
    let store_path = opts.store.clone().unwrap_or_else(|| cfg.store.clone());
    let rt = runtime()?;
    let result = rt.block_on(run_session(opts, cfg, store_path));
    // a technician question may still be blocked reading the terminal: do not wait for it
    rt.shutdown_background();
    result
}

/// A manual stage's questions are answered at the terminal: without one (stdin from a file,
/// `/dev/null`, a pipe, systemd) the first question would read end-of-input as the
/// technician's abort. Refused before anything is planned, locked, armed or moved (exit 2).
fn refuse_manual_without_terminal(cfg: &CellConfig, terminal: bool) -> Result<(), Failure> {
    let kind = match cfg.stage.kind {
        StageMode::Serial => return Ok(()),
        StageMode::Manual => "manual",
        StageMode::ManualGauge => "manual_gauge",
    };
    if terminal {
        return Ok(());
    }
    Err(input(anyhow!(
        "{}: [stage] kind = \"{kind}\": a technician answers the stage's questions, but stdin \
         is not a terminal, so nobody could answer them; nothing was planned, armed or moved. \
         Run `cellcal run --arm` in a terminal, or start `cellcal serve --config {}` and answer \
         the questions on its page",
        cfg.path.display(),
        cfg.path.display()
    )))
}

/// Open (or resume) the campaign, and with `--arm` run it to its end. Not cancel-safe (as
/// `run_campaign`): a drop mid-run skips the robot stop and the final state; the stop signals
/// end it by an abort instead.
async fn run_session(opts: RunArgs, cfg: CellConfig, store_path: PathBuf) -> Result<(), Failure> {
    let on_fault = opts.fault_policy();
    let prompter: Arc<dyn Prompter> = Arc::new(TerminalPrompter);
    let resume = opts.campaign.map(|id| Resume {
        id,
        accept_changed_config: opts.accept_changed_config,
    });
    let session = match open_session(cfg, &store_path, resume, prompter).await {
        Ok(s) => s,
        Err(SessionError::Done(id)) => {
            let (json, model_out) = (opts.json.as_deref(), opts.model_out.as_deref());
            return print_stored_result(&store_path, id, json, model_out);
        }
        Err(e) => return Err(input(e)),
    };
    announce(&session, &store_path);
    let mut ctx = session.ctx;
    let id = ctx.campaign_id;
    if !opts.arm {
        let mut devices = session.devices;
        let places = device_places(&ctx.cfg, session.sim.as_ref());
        let failed = check_devices(&mut devices, &places).await;
        if let Some(sim) = session.sim {
            sim.stop().await;
        }
        println!(
            "campaign {id} is not armed: nothing moves. Run `cellcal run --config {} --store {} --campaign {id} --arm` to measure.",
            opts.config.display(),
            store_path.display()
        );
        if !failed.is_empty() {
            return Err(Failure(
                1,
                anyhow!(
                    "device check failed: {}. Fix it before arming (docs/hardware.md)",
                    failed.join(", ")
                ),
            ));
        }
        return Ok(());
    }
    ctx.on_fault = on_fault;
    let control = ctx.control.clone();
    if opts.reregister {
        control.apply(&CampaignCommand::Reregister);
    }
    control.apply(&CampaignCommand::Arm);
    control.apply(&CampaignCommand::Start);
    let mut devices = session.devices;
    let total = ctx.plan.poses.len();
    let display = display_for(
        opts.progress_mode(),
        devices.stage.is_manual(),
        on_fault,
        total,
    );
    let progress = Progress::for_campaign(&ctx);
    let mut printer = tokio::spawn(print_events(
        control.events.subscribe(),
        total,
        display,
        progress,
    ));
    if on_fault == FaultPolicy::Pause {
        tokio::spawn(ask_on_pause(control.events.subscribe(), control.clone()));
    }
    let caught = abort_on_stop_signals(&control)?;
    let outcome = run_campaign(&ctx, &mut devices).await.map_err(other)?;
    drop(ctx);
    // the printer ends after the final state's line (journalled before run_campaign returned)
    if tokio::time::timeout(PRINTER_DRAIN, &mut printer)
        .await
        .is_err()
    {
        printer.abort();
    }
    if let Some(sim) = session.sim {
        sim.stop().await;
    }
    let signal = caught.get().copied();
    finish(outcome, id, signal, &opts, &store_path)
}

/// How long the end of a run waits for the progress printer to write the final state's line.
const PRINTER_DRAIN: std::time::Duration = std::time::Duration::from_secs(2);

/// Where each device is reached: the simulated cell's address for a simulated one, else the
/// configured address or serial device.
fn device_places(cfg: &CellConfig, sim: Option<&RunningSimCell>) -> [String; 3] {
    let simulated = |mode: DeviceMode| sim.filter(|_| mode == DeviceMode::Sim);
    let tracker = match simulated(cfg.tracker.mode) {
        Some(s) => s.tracker_addr.to_string(),
        None => cfg.tracker.address.clone(),
    };
    let robot = match simulated(cfg.robot_controller.mode) {
        Some(s) => s.robot_addr.to_string(),
        None => cfg.robot_controller.address.clone(),
    };
    let stage = match (simulated(cfg.stage.mode), cfg.stage.kind) {
        (Some(s), _) => s.stage_path.clone().unwrap_or_else(|| "manual".into()),
        (None, StageMode::Serial) => cfg.stage.serial_path.clone(),
        (None, StageMode::ManualGauge) => cfg.stage.gauge_path.clone(),
        (None, StageMode::Manual) => "manual".into(),
    };
    [tracker, robot, stage]
}

/// Without `--arm`: connect to every device and print what it says, without any motion (no
/// power, no homing, no tracker initialise or search); the devices whose check failed.
/// Not cancel-safe (nothing needs it: it runs to its end before the process exits).
async fn check_devices(devices: &mut Devices, places: &[String; 3]) -> Vec<&'static str> {
    println!("checking the devices (nothing moves):");
    let results = [
        ("tracker", devices.tracker.check().await),
        ("robot", devices.robot.check().await),
        ("stage", devices.stage.check().await),
    ];
    let mut failed = Vec::new();
    for ((name, r), place) in results.into_iter().zip(places) {
        match r {
            Ok(line) => println!("  {name} {place}: ok: {line}"),
            Err(e) => {
                println!("  {name} {place}: FAILED: {}", e.message);
                failed.push(name);
            }
        }
    }
    failed
}

/// The campaign's first lines: planned or resumed, and the simulated cell's addresses.
fn announce(session: &Session, store_path: &Path) {
    let (id, plan) = (session.ctx.campaign_id, &session.ctx.plan);
    if session.resumed {
        eprintln!("campaign {id}: resuming from {}", store_path.display());
    } else {
        eprintln!(
            "campaign {id}: {} poses planned ({} via points keep every path in the workspace), stored in {}",
            plan.poses.len(),
            plan.via_points,
            store_path.display()
        );
    }
    if let Some(e) = &session.ctx.estimate {
        for line in estimate_lines(e) {
            eprintln!("{line}");
        }
    }
    if let Some(sim) = &session.sim {
        eprintln!(
            "simulated cell: tracker {}, robot {}, stage {}",
            sim.tracker_addr,
            sim.robot_addr,
            sim.stage_path.as_deref().unwrap_or("manual")
        );
    }
}

/// The campaign time estimate for people: the summary, then where the time goes (the
/// technician's readings with a manual stage).
fn estimate_lines(e: &CampaignEstimate) -> [String; 2] {
    let technician = match e.technician_readings {
        0 => String::new(),
        n => format!(" ({n} technician readings)"),
    };
    [
        format!("estimated time: {}", e.summary()),
        format!(
            "  setup {}, robot motion {}, settling {}, tracker {}, stage {}{technician}",
            fmt_estimate(e.setup_s),
            fmt_estimate(e.motion_s),
            fmt_estimate(e.settle_s),
            fmt_estimate(e.measure_s),
            fmt_estimate(e.stage_s),
        ),
    ]
}

/// Progress: none with `--progress none`; a line per pose with `lines`; with `bar`, a line per
/// pose while a technician is asked, lines every tenth of the poses when a fault asks at the
/// terminal (a bar would overdraw the questions), else a bar.
fn display_for(mode: ProgressMode, manual: bool, on_fault: FaultPolicy, total: usize) -> Display {
    match mode {
        ProgressMode::Off => Display::Quiet,
        ProgressMode::Lines => Display::Lines { every: 1 },
        ProgressMode::Bar if manual => Display::Lines { every: 1 },
        ProgressMode::Bar if on_fault == FaultPolicy::Pause => Display::Lines {
            every: (total / 10).max(1),
        },
        ProgressMode::Bar => Display::Bar,
    }
}

/// SIGINT, SIGTERM and SIGHUP abort the run (the engine stops the robot and stores
/// `aborted`); the signal caught, for the exit code.
fn abort_on_stop_signals(
    control: &Control,
) -> Result<Arc<std::sync::OnceLock<StopSignal>>, Failure> {
    let mut signals = StopSignals::install().map_err(other)?;
    let abort = control.clone();
    let caught = Arc::new(std::sync::OnceLock::new());
    let seen = Arc::clone(&caught);
    tokio::spawn(async move {
        let sig = signals.next().await;
        let _ = seen.set(sig);
        abort.apply(&CampaignCommand::Abort);
    });
    Ok(caught)
}

/// Print and write what the run ended with; the exit code (3 for a poor result, the signal's
/// for an abort by one, 1 for a failure).
fn finish(
    outcome: Outcome,
    id: i64,
    signal: Option<StopSignal>,
    opts: &RunArgs,
    store_path: &Path,
) -> Result<(), Failure> {
    match outcome {
        Outcome::Done(report) => {
            print!("{}", summary_text(&report));
            if let Some(path) = &opts.json {
                let text = serde_json::to_string_pretty(&*report).map_err(other)?;
                write_file(path, &text)?;
            }
            if let Some(path) = &opts.model_out {
                write_model(store_path, id, path)?;
            }
            poor_is_exit_3(&report, &format!("campaign {id} is done, but its result"))
        }
        Outcome::Iso(report) => {
            print!("{}", format_table(&report));
            if let Some(path) = &opts.json {
                let text = serde_json::to_string_pretty(&*report).map_err(other)?;
                write_file(path, &text)?;
            }
            Ok(())
        }
        Outcome::Aborted => {
            let (code, by) = match signal {
                Some(sig) => (sig.exit_code(), format!(" by {}", sig.name())),
                None => (130, String::new()),
            };
            Err(Failure(
                code,
                anyhow!("campaign {id} aborted{by}; the robot was stopped. Resume with --campaign {id} --arm"),
            ))
        }
        Outcome::Failed(reason) => Err(Failure(
            1,
            anyhow!("campaign {id} stopped: {reason}. Resume with --campaign {id} --arm"),
        )),
    }
}

/// A done ISO 9283 campaign: print (and with `--json` write) its stored figures; it has no
/// corrected model.
fn print_stored_iso(
    id: i64,
    text: &str,
    json: Option<&Path>,
    model_out: Option<&Path>,
) -> Result<(), Failure> {
    if model_out.is_some() {
        return Err(input(anyhow!(
            "campaign {id} is an ISO 9283 campaign: it has no corrected model (--model-out)"
        )));
    }
    let report: IsoReport = serde_json::from_str(text)
        .with_context(|| format!("campaign {id}: the stored ISO 9283 figures do not parse"))
        .map_err(other)?;
    eprintln!("campaign {id} is done: nothing moves. Its stored ISO 9283 figures:");
    print!("{}", format_table(&report));
    if let Some(path) = json {
        write_file(path, text)?;
    }
    Ok(())
}

/// Write campaign `id`'s corrected model from the store to `path`.
fn write_model(store_path: &Path, id: i64, path: &Path) -> Result<(), Failure> {
    let store = Store::open(store_path).map_err(other)?;
    let text = stored_model_toml(&store, id)
        .map_err(other)?
        .ok_or_else(|| other(anyhow!("campaign {id} has no stored result")))?;
    write_file(path, &text)
}

/// A done campaign: nothing moves; print (and with `--json`, `--model-out` write) its stored
/// result.
fn print_stored_result(
    store_path: &Path,
    id: i64,
    json: Option<&Path>,
    model_out: Option<&Path>,
) -> Result<(), Failure> {
    let store = Store::open(store_path).map_err(other)?;
    let text = store
        .latest_result(id)
        .map_err(other)?
        .ok_or_else(|| other(anyhow!("campaign {id} is done but has no stored result")))?;
    if is_iso_campaign(&store, id).map_err(other)? {
        return print_stored_iso(id, &text, json, model_out);
    }
    let result = stored_result(&store, id)
        .with_context(|| format!("campaign {id}: the stored result"))
        .map_err(other)?
        .ok_or_else(|| other(anyhow!("campaign {id} is done but has no stored result")))?;
    let report = &result.report;
    eprintln!("campaign {id} is done: nothing moves. Its stored result:");
    print!("{}", summary_text(report));
    if let Some(path) = json {
        write_file(path, &result.identify_json().map_err(other)?)?;
    }
    if let Some(path) = model_out {
        write_model(store_path, id, path)?;
    }
    poor_is_exit_3(report, &format!("campaign {id}'s stored result"))
}
