//! `cellcal sim`: the simulated cell (tracker, robot, stage) on its own, until a stop signal.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};

use cellcal::config::parse_sim_config;
use cellcal::model::load_robot;

use super::{input, other, runtime, Failure};
use crate::signals;

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

/// The robotlink secret of `[robot_controller] secret_file` (relative to the config file), so
/// that a `cellcal run` with the same file can drive the simulated robot; without it a fresh
/// random secret that no other process knows.
fn sim_robot_secret(
    table: &toml::Table,
    dir: &Path,
    file: &Path,
) -> Result<robotlink::SharedSecret, Failure> {
    let secret_file = table
        .get("robot_controller")
        .and_then(|t| t.get("secret_file"));
    match secret_file {
        None => robotlink::SharedSecret::generate().map_err(other),
        Some(toml::Value::String(p)) => {
            robotlink::SharedSecret::read_file(&dir.join(p)).map_err(input)
        }
        Some(_) => Err(input(anyhow!(
            "{}: key `robot_controller.secret_file` must be a path string",
            file.display()
        ))),
    }
}

/// Arguments of `cellcal sim`.
#[derive(clap::Args)]
pub struct SimCellArgs {
    /// Cell configuration file (TOML); only `[sim]`, `[stage]` (the simulated stage follows
    /// its `kind` and Zaber address), the top-level `robot` and `robot_controller.secret_file`
    /// are read.
    #[arg(long)]
    config: PathBuf,
}

/// Start the simulated cell of the configuration's `[sim]`, print its addresses, wait for a
/// stop signal.
pub fn run(a: SimCellArgs) -> Result<(), Failure> {
    let config = a.config.as_path();
    let text = std::fs::read_to_string(config)
        .with_context(|| format!("{}: cannot read", config.display()))
        .map_err(input)?;
    let table: toml::Table = toml::from_str(&text)
        .with_context(|| format!("{}: invalid TOML", config.display()))
        .map_err(input)?;
    // [sim] by the cell configuration's parser and rules (every number of the file finite)
    let cfg = parse_sim_config(&text, config).map_err(input)?;
    let dir = config.parent().unwrap_or(Path::new("."));
    let robot_path = sim_robot_path(&table, dir, config)?;
    let robot = load_robot(&robot_path).map_err(input)?;
    let robot_secret = sim_robot_secret(&table, dir, config)?;
    let rt = runtime()?;
    let result = rt.block_on(async move {
        let mut signals = signals::StopSignals::install().map_err(other)?;
        let stop = async move {
            signals.next().await;
        };
        let cell = cellcal::sim::start_cell_with(robot, cfg, robot_secret, stop)
            .await
            .with_context(|| format!("{}: [sim]", config.display()))
            .map_err(input)?;
        let mut lines = vec![
            format!("tracker {}", cell.tracker_addr),
            match &cell.ur {
                Some(ur) => format!("robot ur {}", ur.host),
                None => format!("robot {}", cell.robot_addr),
            },
            format!("stage {}", cell.stage_path.as_deref().unwrap_or("manual")),
        ];
        if let Some(g) = &cell.gauge_path {
            lines.push(format!("gauge {g}"));
        }
        // a closed stdout does not stop the cell (main.rs' `println!`)
        for l in lines {
            println!("{l}");
        }
        let mut stopping = cell.stopping();
        let _ = stopping.wait_for(|v| *v).await;
        cell.stop().await;
        Ok(())
    });
    rt.shutdown_timeout(std::time::Duration::from_millis(500));
    result
}
