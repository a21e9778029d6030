//! `cellcal predict`: the dry run of a campaign before anyone enters the cell: predicted
//! verification error (Monte Carlo, `cellcal::predict`) for random and for selected
//! identification poses, the campaign's time, and how precisely a verification set of a given
//! size measures the verification error.

use std::path::PathBuf;

use anyhow::{anyhow, Context};

use cellcal::config::load_cell_config;
use cellcal::model::load_robot;
use cellcal::plan::plan_campaign;
use cellcal::plan::selection::Selection;
use cellcal::predict::{
    campaign_time, ident_poses, monte_carlo, IdentPoses, PredictError, Prediction, Setup,
};
use cellcal::units::human::{fmt_fixed, fmt_mm, fmt_mrad};

use super::{input, other, Failure};

/// How the identification poses are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SelectionArg {
    /// Random poses in the workspace box, as a campaign samples them.
    Random,
    /// Poses chosen for what they teach the identification (`plan::selection`).
    Optimal,
}

/// Arguments of `cellcal predict`.
#[derive(clap::Args)]
pub struct PredictArgs {
    /// The cell configuration.
    #[arg(long)]
    config: PathBuf,
    /// Identification poses (default: `[campaign] ident`).
    #[arg(long)]
    poses: Option<usize>,
    /// Predict only this choice of identification poses (default: both).
    #[arg(long, value_enum)]
    selection: Option<SelectionArg>,
    /// Monte Carlo trials per choice.
    #[arg(long, default_value_t = 20)]
    trials: usize,
    /// Seed of the Monte Carlo (default: `[campaign] seed`).
    #[arg(long)]
    seed: Option<u64>,
    /// Verification poses per trial (default: `[campaign] poses` − `ident`).
    #[arg(long)]
    verify: Option<usize>,
    /// Also write the prediction as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Verification-set sizes whose standard error is listed beside the configured one.
const SET_SIZES: [usize; 4] = [25, 50, 100, 200];
/// Most trials a dry run takes.
const MAX_TRIALS: usize = 10_000;

/// A length in mm with 4 decimals (µm differences between designs matter here).
fn mm4(v: f64) -> String {
    format!("{} mm", fmt_fixed(v, 4))
}

/// Run the dry run and print it.
pub fn run(a: PredictArgs) -> Result<(), Failure> {
    let cfg = load_cell_config(&a.config).map_err(input)?;
    let nominal = load_robot(&cfg.robot).map_err(input)?;
    let mut setup = Setup::of_config(&cfg, &nominal);
    if let Some(v) = a.verify {
        setup.verify = v;
    }
    let poses = a.poses.unwrap_or(cfg.campaign.ident);
    if poses == 0 {
        return Err(input(anyhow!("--poses must be at least 1")));
    }
    if setup.verify == 0 {
        return Err(input(anyhow!(
            "--verify must be at least 1 (the configuration has no verification poses)"
        )));
    }
    if !(1..=MAX_TRIALS).contains(&a.trials) {
        return Err(input(anyhow!(
            "--trials must be between 1 and {MAX_TRIALS}"
        )));
    }
    let seed = a.seed.unwrap_or(cfg.campaign.seed);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let which: &[SelectionArg] = match a.selection {
        Some(SelectionArg::Random) => &[SelectionArg::Random],
        Some(SelectionArg::Optimal) => &[SelectionArg::Optimal],
        None => &[SelectionArg::Random, SelectionArg::Optimal],
    };
    println!(
        "predict: {}, robot {}, model {}, {poses} identification poses, {} verification poses, {} trials (seed {seed})",
        a.config.display(),
        setup.nominal.name,
        setup.opts.obs.model.name(),
        setup.verify,
        a.trials,
    );
    let noise = match &setup.tracker {
        Some(t) => format!(
            "AT960 σ = ({} µm + {} µm/m · range)/{} per axis, tracker at ({}, {}, {}) mm",
            fmt_fixed(t.a_um, 1),
            fmt_fixed(t.b_um_per_m, 1),
            fmt_fixed(t.k, 0),
            fmt_fixed(t.position_mm.x, 0),
            fmt_fixed(t.position_mm.y, 0),
            fmt_fixed(t.position_mm.z, 0)
        ),
        None => "none".to_owned(),
    };
    println!(
        "assumed: true MDH errors random, σ {} mm (lengths), {} mrad (angles); tracker noise {noise}; joint repeatability σ {} mrad",
        fmt_mm(setup.errors.length_mm),
        fmt_mrad(setup.errors.angle_rad),
        fmt_fixed(setup.joint_jitter_rad * 1e3, 4),
    );
    let mut results = Vec::new();
    let mut times = Vec::new();
    for &s in which {
        let selection = match s {
            SelectionArg::Random => Selection::Random,
            SelectionArg::Optimal => Selection::Optimal,
        };
        let label = selection.name();
        let req = setup.plan_request(selection, poses, cfg.campaign.seed);
        let plan = plan_campaign(&setup.nominal, &req).map_err(input)?;
        let ident = ident_poses(&plan);
        let p = monte_carlo(&setup, IdentPoses::Given(&ident), a.trials, seed, threads).map_err(
            |e| match e {
                PredictError::Identify(_) => input(anyhow!(
                    "{e} (are {poses} identification poses enough for model {}?)",
                    setup.opts.obs.model.name()
                )),
                e => input(e),
            },
        )?;
        println!(
            "{label} poses: verification mean error {} ± {} over trials, {} × the noise floor {} (model error {}){}",
            mm4(p.mean_mm()),
            mm4(p.spread_mm()),
            fmt_fixed(p.ratio_to_floor(), 3),
            mm4(p.floor_mm()),
            mm4(p.model_mean_mm()),
            if p.failed > 0 {
                format!("; {} of {} trials failed to identify", p.failed, a.trials)
            } else {
                String::new()
            }
        );
        let time = campaign_time(&cfg, &setup, &req, &plan);
        results.push((label, p));
        times.push((label, time));
    }
    for (label, time) in &times {
        println!("campaign time, {label} poses: {}", time.summary());
    }
    if let Some((_, p)) = results.first() {
        let sizes: Vec<String> = SET_SIZES
            .iter()
            .map(|&v| format!("{v}: ± {}", mm4(p.standard_error_mm(v))))
            .collect();
        println!(
            "verification set: {} poses measure the mean error to ± {} (standard error; one pose scatters by {}); {}",
            setup.verify,
            mm4(p.standard_error_mm(setup.verify)),
            mm4(p.pose_sd_mm()),
            sizes.join(", ")
        );
    }
    if let Some(path) = &a.json {
        let mut doc = json_doc(&setup, poses, a.trials, seed, &results);
        for (label, time) in &times {
            doc["designs"][*label]["campaign_time"] = serde_json::to_value(time).map_err(other)?;
        }
        std::fs::write(path, serde_json::to_string_pretty(&doc).map_err(other)?)
            .with_context(|| format!("{}: cannot write", path.display()))
            .map_err(other)?;
    }
    Ok(())
}

/// The prediction as JSON (mm).
fn json_doc(
    setup: &Setup,
    poses: usize,
    trials: usize,
    seed: u64,
    results: &[(&str, Prediction)],
) -> serde_json::Value {
    let designs: serde_json::Map<String, serde_json::Value> = results
        .iter()
        .map(|(label, p)| {
            let sizes: serde_json::Map<String, serde_json::Value> = SET_SIZES
                .iter()
                .chain([&setup.verify])
                .map(|&v| (v.to_string(), p.standard_error_mm(v).into()))
                .collect();
            (
                (*label).to_owned(),
                serde_json::json!({
                    "verify_mean_mm": p.mean_mm(),
                    "verify_spread_mm": p.spread_mm(),
                    "noise_floor_mm": p.floor_mm(),
                    "ratio_to_floor": p.ratio_to_floor(),
                    "model_error_mm": p.model_mean_mm(),
                    "pose_sd_mm": p.pose_sd_mm(),
                    "standard_error_mm": sizes,
                    "trials_failed": p.failed,
                }),
            )
        })
        .collect();
    serde_json::json!({
        "model": setup.opts.obs.model.name(),
        "ident_poses": poses,
        "verify_poses": setup.verify,
        "trials": trials,
        "seed": seed,
        "error_sigma_length_mm": setup.errors.length_mm,
        "error_sigma_angle_rad": setup.errors.angle_rad,
        "designs": designs,
    })
}
