//! `cellcal` command line: clap and dispatch only; each command lives in `cli/<command>.rs`.
//! Exit code 2 = bad input.

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// `print!` of every command (it shadows the standard macro): to stdout through
/// [`cli::print_out`], which takes a closed stdout (its reader, e.g. `head`, went away) quietly
/// instead of panicking.
macro_rules! print {
    ($($arg:tt)*) => {
        $crate::cli::print_out(format_args!($($arg)*))
    };
}

/// `println!` of every command, as [`print!`] above.
macro_rules! println {
    () => {
        $crate::cli::print_out(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::cli::print_out(format_args!("{}\n", format_args!($($arg)*)))
    };
}

mod cli;
mod signals;
mod terminal;

use cli::Failure;

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
    Significance(cli::significance::SignificanceArgs),
    /// Simulate a measurement campaign (CSV + truth JSON) for dry runs and tests.
    SimulateData(Box<cli::simulate_data::SimArgs>),
    /// Choose identification poses by the I-optimal criterion and predict their verification error.
    SelectPoses(Box<cli::select_poses::SelectPosesArgs>),
    /// Run the simulated cell (tracker, robot, stage) from the `[sim]` table of a config file.
    Sim(cli::sim::SimCellArgs),
    /// Run a calibration campaign (plan, measure, store, identify); simulated devices start in-process.
    Run(cli::run::RunArgs),
    /// Run the campaign daemon: the REST API of one cell (`/api/...`, see docs/rest-api.md), until
    /// Ctrl-C / SIGTERM / SIGHUP (a running campaign is aborted: the robot stops, the campaign stays
    /// resumable).
    Serve(cli::serve::ServeArgs),
    /// Make a random REST API token: prints it once (`token: …`) and the `[[api.tokens]]`
    /// entry (name, role, SHA-256) to paste into the cell configuration.
    Token(cli::token::TokenArgs),
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
    Import(cli::import::ImportArgs),
    /// Dry run of a campaign: predicted verification error (Monte Carlo) for random and
    /// selected identification poses, campaign time, and the precision of the verification set.
    Predict(cli::predict::PredictArgs),
}

/// Log to stderr: `serve` at `info` unless `RUST_LOG` says otherwise (text or JSON lines),
/// every other command only what `RUST_LOG` asks for.
fn init_logging(command: &Command) {
    use tracing_subscriber::EnvFilter;
    let (default, json) = match command {
        Command::Serve(a) => ("info", a.log_format == "json"),
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
        Command::Significance(args) => cli::significance::run(args),
        Command::SimulateData(args) => cli::simulate_data::run(&args),
        Command::SelectPoses(args) => cli::select_poses::run(&args),
        Command::Sim(args) => cli::sim::run(args),
        Command::Run(args) => cli::run::run(args),
        Command::Serve(args) => cli::serve::run(args),
        Command::Token(args) => cli::token::run(args),
        Command::Export(args) => cli::export::run(args),
        Command::Compensate(args) => cli::compensate::run(args),
        Command::Report(args) => cli::report::run(args),
        Command::Iso9283(args) => cli::iso9283::run(args),
        Command::Import(args) => cli::import::run(args),
        Command::Predict(args) => cli::predict::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure(code, e)) => {
            eprintln!("cellcal: error: {e:#}");
            ExitCode::from(code)
        }
    }
}
