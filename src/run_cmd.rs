//! `cellcal run`, `cellcal serve`, `cellcal export`, `cellcal import`: thin front ends over the campaign engine
//! and the store.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{anyhow, Context};

use cellcal::api::{self, Scheme};
use cellcal::campaign::session::open_session;
use cellcal::campaign::{run_campaign, CampaignCommand, FaultPolicy, Outcome};
use cellcal::cell::Prompter;
use cellcal::config::load_cell_config;
use cellcal::daemon::Daemon;
use cellcal::dataset::{parse_csv, write_csv, Required};
use cellcal::model::load_robot;
use cellcal::report::summary_text;
use cellcal::store::{NewCampaign, Store};

use crate::cli::access;
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
    /// Store file (default: the configuration's).
    pub store: Option<PathBuf>,
    /// Resume this campaign.
    pub campaign: Option<i64>,
    /// No progress bar.
    pub quiet: bool,
    /// What an operator fault does (pause and ask at the terminal, or stop resumable).
    pub on_fault: FaultPolicy,
}

/// The runtime of the campaign front ends (two workers: the engine and the store/front end).
fn runtime() -> Result<tokio::runtime::Runtime, Failure> {
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
    rt.block_on(async move {
        let prompter: Arc<dyn Prompter> = Arc::new(TerminalPrompter);
        let session = open_session(cfg, &store_path, opts.campaign, prompter)
            .await
            .map_err(input)?;
        let mut ctx = session.ctx;
        ctx.on_fault = opts.on_fault;
        let mut devices = session.devices;
        let id = ctx.campaign_id;
        let total = ctx.plan.poses.len();
        if session.resumed {
            eprintln!("campaign {id}: resuming from {}", store_path.display());
        } else {
            eprintln!("campaign {id}: {total} poses planned, stored in {}", store_path.display());
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
        let abort = control.clone();
        tokio::spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                abort.apply(&CampaignCommand::Abort);
            }
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
                    std::fs::write(path, text)
                        .with_context(|| format!("{}: cannot write", path.display()))
                        .map_err(other)?;
                }
                Ok(())
            }
            Outcome::Aborted => Err(Failure(
                130,
                anyhow!("campaign {id} aborted; the robot was stopped. Resume with --campaign {id} --arm"),
            )),
            Outcome::Failed(reason) => Err(Failure(
                1,
                anyhow!("campaign {id} stopped: {reason}. Resume with --campaign {id} --arm"),
            )),
        }
    })
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
        eprintln!("campaign store {}", store_path.display());
        let app = api::router(
            Arc::clone(&daemon),
            access::gate(tokens, scheme, bound, &api_cfg),
        );
        let handle = axum_server::Handle::new();
        let server = api::serve(listener, app, tls, handle.clone());
        tokio::pin!(server);
        tokio::select! {
            r = &mut server => r.map_err(other)?,
            _ = shutdown_signal() => {
                eprintln!("stopping: aborting the loaded campaign");
                daemon.shutdown().await;
                handle.graceful_shutdown(Some(std::time::Duration::from_secs(5)));
                let _ = tokio::time::timeout(std::time::Duration::from_secs(6), server).await;
            }
        }
        Ok(())
    })
}

/// Ctrl-C or SIGTERM.
async fn shutdown_signal() {
    let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
        Ok(s) => s,
        Err(_) => {
            let _ = tokio::signal::ctrl_c().await;
            return;
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = term.recv() => {}
    }
}

/// `cellcal export`: a campaign's measurements in the identify CSV format.
pub fn export(store: &Path, campaign: Option<i64>, out: &Path) -> Result<(), Failure> {
    let s = Store::open(store).map_err(input)?;
    let id = match campaign {
        Some(id) => id,
        None => s
            .latest_campaign()
            .map_err(input)?
            .ok_or_else(|| input(anyhow!("{}: no campaign", store.display())))?,
    };
    let rows = s.observations(id).map_err(input)?;
    let dof = rows.first().map(|r| r.q.len()).unwrap_or(6);
    let comment = format!("cellcal export: campaign {id} from {}", store.display());
    std::fs::write(out, write_csv(&rows, dof, &comment))
        .with_context(|| format!("{}: cannot write", out.display()))
        .map_err(other)?;
    println!(
        "wrote {} poses of campaign {id} to {}",
        rows.len(),
        out.display()
    );
    Ok(())
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
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0);
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
