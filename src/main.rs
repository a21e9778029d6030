//! `cellcal` command line: thin clap layer over the library. Exit code 2 = bad input.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{anyhow, Context};
use clap::{Parser, Subcommand};
use nalgebra::Vector3;

mod cli;
mod run_cmd;
mod signals;
mod terminal;

use cellcal::analysis::significance;
use cellcal::campaign::FaultPolicy;
use cellcal::dataset::{parse_stage_axis, parse_vec3, write_csv};
use cellcal::model::checked_toml::parse_checked;
use cellcal::model::load_robot;
use cellcal::model::rotation::{from_rotation_vector, to_rotation_vector};
use cellcal::simulate::{self, truth, SimConfig, TrackerNoise};

#[derive(Parser)]
#[command(
    name = "cellcal",
    version = cellcal::build_info::LONG_VERSION,
    about = "Robot calibration cell: identify MDH errors from laser-tracker data"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Identify MDH parameter errors from a measurement CSV, or re-identify a stored campaign.
    Identify(Box<cli::identify::IdentifyArgs>),
    /// Significance indices of the MDH parameters (paper §2.2).
    Significance {
        /// Robot model file (TOML).
        #[arg(long)]
        robot: PathBuf,
        /// Random joint configurations.
        #[arg(long, default_value_t = 50)]
        samples: usize,
        /// RNG seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Write the JSON result here.
        #[arg(long, default_value = "significance.json")]
        json: PathBuf,
    },
    /// Simulate a measurement campaign (CSV + truth JSON) for dry runs and tests.
    SimulateData(Box<SimArgs>),
    /// Run the simulated cell (tracker, robot, stage) from the `[sim]` table of a config file.
    Sim {
        /// Cell configuration file (TOML); only `[sim]` and the top-level `robot` are read.
        #[arg(long)]
        config: PathBuf,
    },
    /// Run a calibration campaign (plan, measure, store, identify); simulated devices start in-process.
    Run {
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
        /// No progress bar.
        #[arg(long)]
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
    },
    /// Run the campaign daemon: the REST API of one cell (`/api/...`, see README), until
    /// Ctrl-C / SIGTERM / SIGHUP (a running campaign is aborted: the robot stops, the campaign stays
    /// resumable).
    Serve {
        /// Cell configuration file (TOML).
        #[arg(long, default_value = "config/cell.sim.toml")]
        config: PathBuf,
        /// Address to listen on (`127.0.0.1:0` picks a free port; the line `listening on
        /// http://ADDR` tells which).
        #[arg(long, default_value = "127.0.0.1:8080")]
        listen: String,
        /// Store file (default: `store` of the configuration).
        #[arg(long)]
        store: Option<PathBuf>,
        /// Log lines on stderr: `text` (human) or `json` (one object a line). Level from
        /// `RUST_LOG` (default `info`): campaign loads and state changes, device faults, every
        /// request answered 4xx/5xx; never a token.
        #[arg(long, value_parser = ["text", "json"], default_value = "text")]
        log_format: String,
    },
    /// Make a random REST API token: prints it once (`token: …`) and the `[[api.tokens]]`
    /// entry (name, role, SHA-256) to paste into the cell configuration.
    Token {
        /// Who will hold the token (named in refusals; the token itself is never stored).
        #[arg(long)]
        name: String,
        /// What it may do: `viewer` (reads, abort), `technician` (also answer, pause),
        /// `operator` (everything).
        #[arg(long, value_parser = ["viewer", "technician", "operator"])]
        role: String,
    },
    /// Write a stored campaign's measurements as an identify CSV (with its setup header).
    Export(cli::export::ExportArgs),
    /// Joints for the real robot (the identified model): from tool targets in the measurement
    /// frame, or from a program's joints computed on the nominal model.
    Compensate(cli::compensate::CompensateArgs),
    /// Write a stored campaign's calibration report: one self-contained HTML file with plots.
    Report(cli::report::ReportArgs),
    /// ISO 9283 pose accuracy (AP) and repeatability (RP) of a stored ISO campaign.
    Iso9283(cli::iso9283::Iso9283Args),
    /// Import an identify CSV as a new, fully measured campaign.
    Import {
        /// Store file.
        #[arg(long)]
        store: PathBuf,
        /// Robot model file (TOML).
        #[arg(long)]
        robot: PathBuf,
        /// Input CSV.
        #[arg(long)]
        data: PathBuf,
        /// Observation model recorded with the campaign.
        #[arg(long, default_value = "op")]
        model: String,
    },
}

#[derive(clap::Args)]
struct SimArgs {
    /// Robot model file (TOML), the nominal model.
    #[arg(long)]
    robot: PathBuf,
    /// Output CSV.
    #[arg(long)]
    out: PathBuf,
    /// Output truth JSON (default: OUT with .truth.json).
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Total poses.
    #[arg(long, default_value_t = 300)]
    poses: usize,
    /// Identification poses (the rest verify).
    #[arg(long, default_value_t = 100)]
    ident: usize,
    /// RNG seed.
    #[arg(long, default_value_t = 4802)]
    seed: u64,
    /// True errors: `paper` (METHOD.md §7), `random`, or a JSON/TOML file of name = value.
    #[arg(long, default_value = "paper")]
    errors: String,
    /// Seed of `--errors random`.
    #[arg(long, default_value_t = 1)]
    error_seed: u64,
    /// Stage axis in the flange frame: +x, -x, +y, -y, +z, -z or a vector X,Y,Z (normalised).
    #[arg(long, value_parser = parse_stage_axis, default_value = "+y", allow_hyphen_values = true)]
    stage_axis: Vector3<f64>,
    /// Stage travel (mm).
    #[arg(long, default_value_t = 10.0)]
    stage_travel_mm: f64,
    /// Stage axis misalignment, rotation vector X,Y,Z (mrad).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    stage_misalignment_mrad: Option<Vector3<f64>>,
    /// Systematic cross-travel deviation (mm per mm of travel).
    #[arg(long, default_value_t = 0.0)]
    stage_cross_mm_per_mm: f64,
    /// Stage repeatability σ (mm).
    #[arg(long, default_value_t = 0.0)]
    stage_repeatability_mm: f64,
    /// True ball position in the flange frame X,Y,Z (mm).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    tool_mm: Option<Vector3<f64>>,
    /// True base translation (robot base origin in the measurement frame) X,Y,Z (mm).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    base_translation_mm: Option<Vector3<f64>>,
    /// True base rotation vector X,Y,Z (deg).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    base_rotvec_deg: Option<Vector3<f64>>,
    /// Tracker position in the measurement frame X,Y,Z (mm); default (2550,0,0), or the origin when a base is given.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    tracker_pos_mm: Option<Vector3<f64>>,
    /// Joint jitter σ (rad).
    #[arg(long, default_value_t = 1.2746e-5)]
    joint_jitter_rad: f64,
    /// No tracker noise and no joint jitter.
    #[arg(long)]
    no_noise: bool,
    /// Fraction of poses that are gross outliers.
    #[arg(long, default_value_t = 0.0)]
    outliers: f64,
    /// Gross outlier size (mm).
    #[arg(long, default_value_t = 1.0)]
    outlier_mm: f64,
    /// Workspace box centre X,Y,Z (mm, robot base frame).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    box_center_mm: Option<Vector3<f64>>,
    /// Workspace box edge (mm).
    #[arg(long, default_value_t = 1000.0)]
    box_size_mm: f64,
}

/// A failure and its exit code.
struct Failure(u8, anyhow::Error);

fn input<E: Into<anyhow::Error>>(e: E) -> Failure {
    Failure(2, e.into())
}

fn other<E: Into<anyhow::Error>>(e: E) -> Failure {
    Failure(1, e.into())
}

/// Log to stderr: `serve` at `info` unless `RUST_LOG` says otherwise (text or JSON lines),
/// every other command only what `RUST_LOG` asks for.
fn init_logging(command: &Command) {
    use tracing_subscriber::EnvFilter;
    let (default, json) = match command {
        Command::Serve { log_format, .. } => ("info", log_format == "json"),
        _ => ("error", false),
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
    let logs = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    if json {
        logs.json().init();
    } else {
        logs.init();
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging(&cli.command);
    let result = match cli.command {
        Command::Identify(args) => cli::identify::run(*args),
        Command::Significance {
            robot,
            samples,
            seed,
            json,
        } => run_significance(&robot, samples, seed, &json),
        Command::SimulateData(args) => run_simulate(&args),
        Command::Sim { config } => run_sim(&config),
        Command::Run {
            config,
            arm,
            json,
            model_out,
            store,
            campaign,
            quiet,
            on_fault,
            accept_changed_config,
            reregister,
        } => run_cmd::run(run_cmd::RunOptions {
            config,
            arm,
            json,
            model_out,
            store,
            campaign,
            quiet,
            on_fault: match on_fault.as_deref() {
                Some("pause") => FaultPolicy::Pause,
                Some(_) => FaultPolicy::Fail,
                None if std::io::stdin().is_terminal() => FaultPolicy::Pause,
                None => FaultPolicy::Fail,
            },
            accept_changed_config,
            reregister,
        }),
        Command::Serve {
            config,
            listen,
            store,
            log_format: _,
        } => run_cmd::serve(&config, &listen, store),
        Command::Token { name, role } => cli::token::run(&name, &role),
        Command::Export(args) => cli::export::run(args),
        Command::Compensate(args) => cli::compensate::run(args),
        Command::Report(args) => cli::report::run(args),
        Command::Iso9283(args) => cli::iso9283::run(args),
        Command::Import {
            store,
            robot,
            data,
            model,
        } => run_cmd::import(&store, &robot, &data, &model),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure(code, e)) => {
            eprintln!("cellcal: error: {e:#}");
            ExitCode::from(code)
        }
    }
}

fn run_significance(robot: &Path, samples: usize, seed: u64, json: &Path) -> Result<(), Failure> {
    if samples == 0 {
        return Err(input(anyhow!("--samples must be at least 1")));
    }
    let m = load_robot(robot).map_err(input)?;
    let rows = significance(&m, samples, seed);
    println!("Significance indices over {samples} random poses (perturbation 0.1 mm / 0.1 rad)");
    println!(
        "{:<8} {:>12} {:>12} {:>12} {:>12}",
        "param", "ē_p (mm)", "ē_n", "ē_o", "ē_a"
    );
    for r in &rows {
        println!(
            "{:<8} {:>12.5} {:>12.5} {:>12.5} {:>12.5}",
            r.name, r.e_p_mm, r.e_n, r.e_o, r.e_a
        );
    }
    let doc = serde_json::json!({ "samples": samples, "seed": seed, "parameters": rows });
    std::fs::write(json, serde_json::to_string_pretty(&doc).map_err(other)?)
        .with_context(|| format!("{}: cannot write", json.display()))
        .map_err(other)?;
    Ok(())
}

fn load_errors(spec: &str, dof: usize, seed: u64) -> anyhow::Result<truth::ErrorTable> {
    match spec {
        "paper" => {
            if dof != 6 {
                return Err(anyhow!("--errors paper needs a six-joint robot"));
            }
            Ok(truth::paper_errors())
        }
        "random" => Ok(truth::random_errors(dof, seed)),
        path => {
            let text =
                std::fs::read_to_string(path).with_context(|| format!("{path}: cannot read"))?;
            let table: truth::ErrorTable = if path.ends_with(".json") {
                serde_json::from_str(&text).with_context(|| path.to_owned())?
            } else {
                toml::from_str(&text).with_context(|| path.to_owned())?
            };
            Ok(table)
        }
    }
}

fn run_simulate(a: &SimArgs) -> Result<(), Failure> {
    let nominal = load_robot(&a.robot).map_err(input)?;
    if a.ident == 0 || a.ident > a.poses {
        return Err(input(anyhow!("--ident must be between 1 and --poses")));
    }
    if !(0.0..=0.5).contains(&a.outliers) {
        return Err(input(anyhow!(
            "--outliers must be a fraction between 0 and 0.5"
        )));
    }
    let errors = load_errors(&a.errors, nominal.dof(), a.error_seed).map_err(input)?;
    let mut true_model = truth::apply_errors(&nominal, &errors)
        .map_err(|e| input(anyhow!("--errors {}: {e}", a.errors)))?;
    let has_base = a.base_translation_mm.is_some() || a.base_rotvec_deg.is_some();
    if let Some(t) = a.tool_mm {
        true_model.tool = t;
    }
    if let Some(t) = a.base_translation_mm {
        true_model.base_translation = t;
    }
    if let Some(r) = a.base_rotvec_deg {
        true_model.base_rotation = from_rotation_vector(&(r * std::f64::consts::PI / 180.0));
    }
    let tracker_pos = a.tracker_pos_mm.unwrap_or(if has_base {
        Vector3::zeros()
    } else {
        Vector3::new(2550.0, 0.0, 0.0)
    });
    let mut cfg = SimConfig {
        poses: a.poses,
        ident: a.ident,
        seed: a.seed,
        tracker: (!a.no_noise).then(|| TrackerNoise::at960(tracker_pos)),
        joint_jitter_rad: if a.no_noise { 0.0 } else { a.joint_jitter_rad },
        stage_travel_mm: a.stage_travel_mm,
        stage_axis: a.stage_axis,
        stage_misalignment_rad: a.stage_misalignment_mrad.unwrap_or_else(Vector3::zeros) / 1000.0,
        stage_cross_mm_per_mm: a.stage_cross_mm_per_mm,
        stage_repeatability_mm: a.stage_repeatability_mm,
        outlier_fraction: a.outliers,
        outlier_mm: a.outlier_mm,
        ..SimConfig::default()
    };
    if let Some(c) = a.box_center_mm {
        cfg.workspace.center_mm = c;
    }
    cfg.workspace.size_mm = Vector3::repeat(a.box_size_mm);
    let sim = simulate::simulate(&nominal, &true_model, &cfg).map_err(input)?;
    let comment = format!(
        "cellcal simulate-data: robot {}, seed {}, errors {}, stage axis {:?} travel {} mm\nP2 = P1 + travel * R * u; q in rad; positions in mm (measurement frame)",
        nominal.name,
        a.seed,
        a.errors,
        cfg.stage_axis.as_slice(),
        cfg.stage_travel_mm
    );
    std::fs::write(
        &a.out,
        write_csv(&sim.observations, nominal.dof(), &comment),
    )
    .with_context(|| format!("{}: cannot write", a.out.display()))
    .map_err(other)?;
    let truth_path = a
        .truth
        .clone()
        .unwrap_or_else(|| a.out.with_extension("truth.json"));
    let doc = serde_json::json!({
        "robot": nominal.name,
        "seed": a.seed,
        "errors": errors,
        "true_mdh": true_model.joints.iter().map(|j| [j.theta, j.d, j.a, j.alpha, j.beta]).collect::<Vec<_>>(),
        "base": {
            "translation_mm": true_model.base_translation.as_slice(),
            "rotation_vector_rad": to_rotation_vector(&true_model.base_rotation).as_slice(),
        },
        "tool": { "translation_mm": true_model.tool.as_slice() },
        "noise": {
            "tracker_position_mm": tracker_pos.as_slice(),
            "tracker_sigma": if a.no_noise { "none".to_owned() } else { "(15 um + 6 um/m * range)/2 per axis".to_owned() },
            "joint_jitter_rad": cfg.joint_jitter_rad,
        },
        "stage": {
            "axis": cfg.stage_axis.as_slice(),
            "travel_mm": cfg.stage_travel_mm,
            "misalignment_rad": cfg.stage_misalignment_rad.as_slice(),
            "cross_mm_per_mm": cfg.stage_cross_mm_per_mm,
            "repeatability_mm": cfg.stage_repeatability_mm,
        },
        "outlier_poses": sim.outliers.iter().map(|i| i.to_string()).collect::<Vec<_>>(),
        "poses": a.poses,
        "ident": a.ident,
    });
    std::fs::write(
        &truth_path,
        serde_json::to_string_pretty(&doc).map_err(other)?,
    )
    .with_context(|| format!("{}: cannot write", truth_path.display()))
    .map_err(other)?;
    println!(
        "wrote {} poses ({} ident, {} verify) to {} and the truth to {}",
        a.poses,
        a.ident,
        a.poses - a.ident,
        a.out.display(),
        truth_path.display()
    );
    Ok(())
}

/// The part of a cell configuration file that `cellcal sim` reads.
#[derive(serde::Deserialize, serde::Serialize)]
struct SimFile {
    #[serde(default)]
    sim: cellcal::sim::SimWorldConfig,
}

/// The robot model path: top-level `robot = "PATH"` (or `[robot] model = "PATH"`), relative to
/// the config file; else the TX60 file relative to the working directory.
fn sim_robot_path(table: &toml::Table, dir: &Path, file: &Path) -> Result<PathBuf, Failure> {
    let v = match table.get("robot") {
        None => None,
        Some(toml::Value::String(s)) => Some(s.as_str()),
        Some(toml::Value::Table(t)) => match t.get("model") {
            None => None,
            Some(toml::Value::String(s)) => Some(s.as_str()),
            Some(_) => {
                return Err(input(anyhow!(
                    "{}: key `robot.model` must be a path string",
                    file.display()
                )))
            }
        },
        Some(_) => {
            return Err(input(anyhow!(
                "{}: key `robot` must be a path string",
                file.display()
            )))
        }
    };
    Ok(match v {
        Some(p) => dir.join(p),
        None => PathBuf::from("config/robots/staubli_tx60.toml"),
    })
}

fn run_sim(config: &Path) -> Result<(), Failure> {
    use std::io::Write;
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("{}: cannot read", config.display()))
        .map_err(input)?;
    let table: toml::Table = toml::from_str(&text)
        .with_context(|| format!("{}: invalid TOML", config.display()))
        .map_err(input)?;
    // every number finite and every array its exact length, in the whole file
    let mut cfg = parse_checked::<SimFile>(&text, config).map_err(input)?.sim;
    let dir = config.parent().unwrap_or(Path::new("."));
    if !matches!(cfg.errors.as_str(), "paper" | "random" | "none" | "") {
        cfg.errors = dir.join(&cfg.errors).to_string_lossy().into_owned();
    }
    let robot_path = sim_robot_path(&table, dir, config)?;
    let robot = load_robot(&robot_path).map_err(input)?;
    let rt = run_cmd::runtime()?;
    let result = rt.block_on(async move {
        let mut signals = signals::StopSignals::install().map_err(other)?;
        let stop = async move {
            signals.next().await;
        };
        let cell = cellcal::sim::start_cell(robot, cfg, stop)
            .await
            .with_context(|| format!("{}: [sim]", config.display()))
            .map_err(input)?;
        let mut out = std::io::stdout().lock();
        let mut lines = vec![
            format!("tracker {}", cell.tracker_addr),
            format!("robot {}", cell.robot_addr),
            format!("stage {}", cell.stage_path.as_deref().unwrap_or("manual")),
        ];
        if let Some(g) = &cell.gauge_path {
            lines.push(format!("gauge {g}"));
        }
        for l in lines {
            writeln!(out, "{l}").map_err(other)?;
        }
        out.flush().map_err(other)?;
        drop(out);
        let mut stopping = cell.stopping();
        let _ = stopping.wait_for(|v| *v).await;
        cell.stop().await;
        Ok(())
    });
    rt.shutdown_timeout(std::time::Duration::from_millis(500));
    result
}
