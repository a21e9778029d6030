//! `cellcal run`, `cellcal serve`, `cellcal import`: thin front ends over the campaign engine
//! and the store.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{anyhow, Context};

use cellcal::api::{self, Scheme};
use cellcal::campaign::session::{open_session, Resume, SessionError};
use cellcal::campaign::stored::stored_model_toml;
use cellcal::campaign::{run_campaign, CampaignCommand, FaultPolicy, Outcome};
use cellcal::cell::Prompter;
use cellcal::config::load_cell_config;
use cellcal::daemon::Daemon;
use cellcal::dataset::{parse_csv, Required};
use cellcal::model::load_robot;
use cellcal::report::{summary_text, IdentifyReport};
use cellcal::store::{NewCampaign, Store};

use crate::cli::access;
use crate::cli::identify::{poor_is_exit_3, write_file};
use crate::signals::StopSignals;
use crate::terminal::{ask_on_pause, print_events, Display, TerminalPrompter};
use crate::{input, other, Failure};

/// Options of `cellcal run`.
pub struct RunOptions {
    /// Cell configuration.
    pub config: PathBuf,
    /// Allow motion and start at once.
    pub arm: bool,
    /// Write the result JSON here.
    pub json: Option<PathBuf>,
    /// Write the corrected model (robot TOML) here.
    pub model_out: Option<PathBuf>,
    /// Store file (default: the configuration's).
    pub store: Option<PathBuf>,
    /// Resume this campaign.
    pub campaign: Option<i64>,
    /// No progress bar.
    pub quiet: bool,
    /// What an operator fault does (pause and ask at the terminal, or stop resumable).
    pub on_fault: FaultPolicy,
    /// Resume although the configuration or robot model changed since the campaign was created.
    pub accept_changed_config: bool,
    /// Re-register a moved tracker frame instead of stopping.
    pub reregister: bool,
}

/// The runtime of the campaign front ends (two workers: the engine and the store/front end).
pub(crate) fn runtime() -> Result<tokio::runtime::Runtime, Failure> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(other)
}

/// Run a campaign headless (or with terminal prompts for a manual stage).
pub fn run(opts: RunOptions) -> Result<(), Failure> {
    let cfg = load_cell_config(&opts.config).map_err(input)?;
    let store_path = opts.store.clone().unwrap_or_else(|| cfg.store.clone());
    let rt = runtime()?;
    let result = rt.block_on(async move {
        let prompter: Arc<dyn Prompter> = Arc::new(TerminalPrompter);
        let resume = opts.campaign.map(|id| Resume {
            id,
            accept_changed_config: opts.accept_changed_config,
        });
        let session = match open_session(cfg, &store_path, resume, prompter).await {
            Ok(s) => s,
            Err(SessionError::Done(id)) => {
                return print_stored_result(&store_path, id, opts.json.as_deref(), opts.model_out.as_deref())
            }
            Err(e) => return Err(input(e)),
        };
        let mut ctx = session.ctx;
        ctx.on_fault = opts.on_fault;
        if opts.reregister {
            ctx.control.apply(&CampaignCommand::Reregister);
        }
        let mut devices = session.devices;
        let id = ctx.campaign_id;
        let total = ctx.plan.poses.len();
        if session.resumed {
            eprintln!("campaign {id}: resuming from {}", store_path.display());
        } else {
            eprintln!(
                "campaign {id}: {total} poses planned ({} via points keep every path in the workspace), stored in {}",
                ctx.plan.via_points,
                store_path.display()
            );
        }
        if let Some(sim) = &session.sim {
            eprintln!(
                "simulated cell: tracker {}, robot {}, stage {}",
                sim.tracker_addr,
                sim.robot_addr,
                sim.stage_path.as_deref().unwrap_or("manual")
            );
        }
        if !opts.arm {
            println!(
                "campaign {id} is not armed: nothing moves. Run `cellcal run --config {} --store {} --campaign {id} --arm` to measure.",
                opts.config.display(),
                store_path.display()
            );
            return Ok(());
        }
        let control = ctx.control.clone();
        control.apply(&CampaignCommand::Arm);
        control.apply(&CampaignCommand::Start);
        let manual = devices.stage.is_manual();
        let display = if opts.quiet {
            Display::Quiet
        } else if manual {
            Display::Lines { every: 1 }
        } else if opts.on_fault == FaultPolicy::Pause {
            Display::Lines {
                every: (total / 10).max(1),
            }
        } else {
            Display::Bar
        };
        let printer = tokio::spawn(print_events(control.events.subscribe(), total, display));
        if opts.on_fault == FaultPolicy::Pause {
            tokio::spawn(ask_on_pause(control.events.subscribe(), control.clone()));
        }
        // SIGINT, SIGTERM and SIGHUP abort: the engine stops the robot and stores `aborted`
        let mut signals = StopSignals::install().map_err(other)?;
        let abort = control.clone();
        let caught = Arc::new(std::sync::OnceLock::new());
        let seen = Arc::clone(&caught);
        tokio::spawn(async move {
            let sig = signals.next().await;
            let _ = seen.set(sig);
            abort.apply(&CampaignCommand::Abort);
        });
        let outcome = run_campaign(&ctx, &mut devices).await.map_err(other)?;
        drop(ctx);
        printer.abort();
        if let Some(sim) = session.sim {
            sim.stop().await;
        }
        match outcome {
            Outcome::Done(report) => {
                print!("{}", summary_text(&report));
                if let Some(path) = &opts.json {
                    let text = serde_json::to_string_pretty(&*report).map_err(other)?;
                    write_file(path, &text)?;
                }
                if let Some(path) = &opts.model_out {
                    write_model(&store_path, id, path)?;
                }
                poor_is_exit_3(&report, &format!("campaign {id} is done, but its result"))
            }
            Outcome::Iso(report) => {
                print!("{}", cellcal::iso9283::format_table(&report));
                if let Some(path) = &opts.json {
                    let text = serde_json::to_string_pretty(&*report).map_err(other)?;
                    write_file(path, &text)?;
                }
                Ok(())
            }
            Outcome::Aborted => {
                let (code, by) = match caught.get() {
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
    });
    // a technician question may still be blocked reading the terminal: do not wait for it
    rt.shutdown_background();
    result
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
    let text = Store::open(store_path)
        .and_then(|s| s.latest_result(id))
        .map_err(other)?
        .ok_or_else(|| other(anyhow!("campaign {id} is done but has no stored result")))?;
    let report = IdentifyReport::from_json(&text)
        .with_context(|| format!("campaign {id}: the stored result does not parse"))
        .map_err(other)?;
    eprintln!("campaign {id} is done: nothing moves. Its stored result:");
    print!("{}", summary_text(&report));
    if let Some(path) = json {
        write_file(path, &text)?;
    }
    if let Some(path) = model_out {
        write_model(store_path, id, path)?;
    }
    poor_is_exit_3(&report, &format!("campaign {id}'s stored result"))
}

/// `cellcal serve`: the campaign daemon and its REST API until Ctrl-C / SIGTERM.
pub fn serve(config: &Path, listen: &str, store: Option<PathBuf>) -> Result<(), Failure> {
    let cfg = load_cell_config(config).map_err(input)?;
    let addr: std::net::SocketAddr = listen
        .parse()
        .map_err(|e| input(anyhow!("--listen `{listen}`: {e}")))?;
    let api_cfg = cfg.api.clone();
    access::check_exposure(addr, &api_cfg)?;
    let tls = match &api_cfg.tls {
        Some((cert, key)) => Some(api::tls::server_config(cert, key).map_err(input)?),
        None => None,
    };
    let scheme = if tls.is_some() {
        Scheme::Https
    } else {
        Scheme::Http
    };
    let store_path = store.unwrap_or_else(|| cfg.store.clone());
    let rt = runtime()?;
    rt.block_on(async move {
        let daemon = Arc::new(Daemon::new(cfg, &store_path).map_err(input)?);
        let listener = std::net::TcpListener::bind(addr)
            .with_context(|| format!("cannot listen on {addr}"))
            .map_err(other)?;
        let bound = listener.local_addr().map_err(other)?;
        let (tokens, one_time) = access::accepted_tokens(&api_cfg)?;
        println!("listening on {}://{bound}", scheme.as_str());
        if let Some(token) = one_time {
            println!("open {}://{bound}/?token={token}", scheme.as_str());
        }
        tracing::info!(store = %store_path.display(), "campaign store");
        let mut signals = StopSignals::install().map_err(other)?;
        let app = api::router(
            Arc::clone(&daemon),
            access::gate(tokens, scheme, bound, &api_cfg),
        );
        let handle = axum_server::Handle::new();
        let server = api::serve(listener, app, tls, handle.clone());
        tokio::pin!(server);
        tokio::select! {
            r = &mut server => r.map_err(other)?,
            _ = signals.next() => {
                tracing::info!("stopping: aborting the loaded campaign");
                daemon.shutdown().await;
                handle.graceful_shutdown(Some(std::time::Duration::from_secs(5)));
                let _ = tokio::time::timeout(std::time::Duration::from_secs(6), server).await;
            }
        }
        Ok(())
    })
}

/// `cellcal import`: a CSV data set as a new, fully measured campaign.
pub fn import(store: &Path, robot: &Path, data: &Path, model: &str) -> Result<(), Failure> {
    let m = load_robot(robot).map_err(input)?;
    let text = std::fs::read_to_string(data)
        .with_context(|| format!("{}: cannot read", data.display()))
        .map_err(input)?;
    let rows = parse_csv(&text, m.dof(), Required::default())
        .with_context(|| data.display().to_string())
        .map_err(input)?;
    let mut s = Store::open(store).map_err(input)?;
    let now = cellcal::wall_clock::now_unix_ms();
    let id = s
        .import_observations(
            &NewCampaign {
                name: format!("import {}", data.display()),
                created_at_ms: now,
                model: model.to_owned(),
                seed: 0,
                config_toml: String::new(),
                robot_toml: std::fs::read_to_string(robot).unwrap_or_default(),
            },
            &rows,
        )
        .map_err(input)?;
    println!(
        "imported {} poses as campaign {id} into {}",
        rows.len(),
        store.display()
    );
    Ok(())
}
