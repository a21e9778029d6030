//! The merged-campaign figure of issue 20 (docs/design.md): whole campaigns on the simulated
//! cell over the real protocols (in process, fast timings), the paper's setup (OP, stage +y
//! 10 mm, the ball at the flange origin, base identified, `config/cell.sim.toml`'s tracker and
//! noise), per seed (campaign seed = simulation seed = S): (a) 100 random identification poses,
//! every pose measured; (b) `selection = "optimal"`, `stop_when = "predicted"` with the default
//! stop keys; both with the same 200 verification poses. Prints the identification poses each
//! measured and the verification error of (b) over (a), and the mean over the seeds.
//!
//! `cargo run --release --example stop_figure [SEEDS [FIRST]]` (default 6 seeds from 1; about
//! 20 s a seed on 2 cores). `STOP_FIGURE_PREFIXES=1` also runs (c) the stop campaign's plan and
//! measuring order with every pose measured and identifies on the first 24, 32, … 100
//! identification poses: what a stop there would have verified, with the stop rule's view at
//! each (parameters identified and held back, a-posteriori σ, prediction, gains).
//! `STOP_FIGURE_KNOWN=1`: the README's ball 60 mm above the flange, exactly where designed, and
//! the stage exactly along +y, both known (no setup error).
//! `STOP_FIGURE_KEYS='stop_remaining_gain = 0.02'`: more `[campaign]` keys for (b).
//! `STOP_FIGURE_ORIGIN=1`: the ball exactly at the flange origin and the stage exactly along
//! +y, both known (no tool-frame setup; the setup's sphere fit has no lever with the ball at
//! the flange origin).
//! A benchmark, not a test: it prints Markdown tables.

use std::path::Path;
use std::sync::Arc;

use cellcal::analysis::evaluate;
use cellcal::calibrate::setup::SetupResult;
use cellcal::calibrate::{calibrate, IdentifyReport};
use cellcal::campaign::engine::{campaign_identification, identify_options, predict_check};
use cellcal::campaign::session::{open_session, Session};
use cellcal::campaign::{run_campaign, CampaignCommand, FaultPolicy, Outcome};
use cellcal::cell::ScriptedPrompter;
use cellcal::config::parse_cell_config;
use cellcal::dataset::{split, to_measured, Observation, PoseSet};
use cellcal::sim::lock_world;
use cellcal::store::{identification_rows, Store};
use cellcal::units::human::fmt_fixed;

/// `config/cell.sim.toml`, fast timings, the ball at the flange origin (true: 0.4, −0.3, 0 mm),
/// campaign and simulation seed `seed`, and `campaign` keys.
fn config_text(seed: u64, campaign: &str) -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let base = std::fs::read_to_string(root.join("config/cell.sim.toml")).expect("cell.sim.toml");
    let robot = root.join("config/robots/staubli_tx60.toml");
    let mut text = base
        .replace(
            "robot = \"robots/staubli_tx60.toml\"",
            &format!("robot = {:?}", robot.display().to_string()),
        )
        .replace(
            "realistic = false\n",
            "realistic = false\nmove_speed_deg_s = 200000.0\nstage_speed_mm_s = 100000.0\n",
        )
        .replace("seed = 4802", &format!("seed = {seed}"))
        .replace("[campaign]\n", &format!("[campaign]\n{campaign}\n"));
    if std::env::var_os("STOP_FIGURE_ORIGIN").is_some() {
        // the paper's setup: the ball at the flange origin, the stage along +y, both known
        text = text
            .replace("tool_mm = [0.0, 0.0, 60.0]", "tool_mm = [0.0, 0.0, 0.0]")
            .replace("tool_mm = [0.4, -0.3, 60.0]", "tool_mm = [0.0, 0.0, 0.0]")
            .replace(
                "stage_misalignment_mrad = [1.5, 0.0, -2.5]",
                "stage_misalignment_mrad = [0.0, 0.0, 0.0]",
            )
            .replace("tool_frame = true ", "tool_frame = false ");
    }
    if std::env::var_os("STOP_FIGURE_KNOWN").is_some() {
        // the README's ball 60 mm up, but exactly where designed and the stage exactly along
        // +y, both known: no setup error
        text = text
            .replace("tool_mm = [0.4, -0.3, 60.0]", "tool_mm = [0.0, 0.0, 60.0]")
            .replace(
                "stage_misalignment_mrad = [1.5, 0.0, -2.5]",
                "stage_misalignment_mrad = [0.0, 0.0, 0.0]",
            )
            .replace("tool_frame = true ", "tool_frame = false ");
    }
    text
}

/// One finished campaign.
struct Done {
    report: IdentifyReport,
    /// Verification mean after (mm).
    after_mm: f64,
    /// The true robot against the same verification readings (mm).
    floor_mm: f64,
    /// Identification poses measured.
    ident: usize,
    /// Every stored row, the identification recipe (nominal, options, travel).
    rows: Vec<Observation>,
    recipe: (
        cellcal::model::RobotModel,
        cellcal::identify::IdentifyOptions,
        f64,
    ),
    /// Keeps the campaign's directory until dropped.
    store: tempfile::TempDir,
}

async fn campaign(text: &str) -> Done {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg_path = dir.path().join("cell.toml");
    std::fs::write(&cfg_path, text).expect("write");
    let cfg = parse_cell_config(text, &cfg_path).expect("config");
    let db = dir.path().join("c.db");
    let Session {
        mut ctx,
        mut devices,
        sim,
        lock,
        ..
    } = open_session(cfg, &db, None, Arc::new(ScriptedPrompter::exact()))
        .await
        .expect("session");
    ctx.on_fault = FaultPolicy::Fail;
    ctx.control.apply(&CampaignCommand::Arm);
    ctx.control.apply(&CampaignCommand::Start);
    let outcome = run_campaign(&ctx, &mut devices).await.expect("campaign");
    drop(lock);
    let Outcome::Done(report) = outcome else {
        panic!("campaign did not finish: {outcome:?}");
    };
    let sim = sim.expect("simulated cell");
    let truth = lock_world(&sim.world).true_model().clone();
    sim.stop().await;
    let id = ctx.campaign_id;
    let s = Store::open(&db).expect("store");
    let rows = identification_rows(s.measured(id).expect("rows"));
    let setup = SetupResult::load(&s, id).expect("setup");
    let recipe = campaign_identification(&ctx.cfg, &ctx.nominal, setup.as_ref());
    let opts = identify_options(&ctx.cfg);
    let (_, verify) = split(&rows);
    let verify = to_measured(&verify, opts.obs.model, ctx.cfg.stage.travel_mm).expect("verify");
    let floor_mm = evaluate(&truth, &verify, &opts.obs).position_mean_mm;
    let after_mm = report
        .metrics
        .verify
        .as_ref()
        .expect("verify metrics")
        .after
        .position_mean_mm;
    Done {
        ident: report.metrics.ident.after.poses,
        report: *report,
        after_mm,
        floor_mm,
        rows,
        recipe,
        store: dir,
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let args: Vec<u64> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("SEEDS FIRST: numbers"))
        .collect();
    let seeds = args.first().copied().unwrap_or(6);
    let first = args.get(1).copied().unwrap_or(1);
    let prefixes = std::env::var_os("STOP_FIGURE_PREFIXES").is_some();
    let started = std::time::Instant::now();
    let mut ratio = Vec::new();
    let mut floor_ratio = Vec::new();
    let mut poses = Vec::new();
    let mut lines = Vec::new();
    for seed in first..first + seeds {
        let random = campaign(&config_text(seed, "")).await;
        let keys = format!(
            "selection = \"optimal\"\nstop_when = \"predicted\"\n{}",
            std::env::var("STOP_FIGURE_KEYS").unwrap_or_default()
        );
        let stop = campaign(&config_text(seed, &keys)).await;
        let r = stop.after_mm / random.after_mm;
        // over each campaign's own noise floor: the noise of the readings cancels
        let rf = (stop.after_mm / stop.floor_mm) / (random.after_mm / random.floor_mm);
        let why = stop
            .report
            .ident_stop
            .as_ref()
            .map(|s| {
                format!(
                    "{} ({})",
                    s.reason.as_str(),
                    s.history
                        .iter()
                        .map(|c| {
                            format!(
                                "{}: {} {}/{}{}",
                                c.after_poses,
                                fmt_fixed(c.predicted_mm, 5),
                                c.gain.map_or("-".into(), |g| fmt_fixed(100.0 * g, 1)),
                                c.remaining_gain
                                    .map_or("-".into(), |g| fmt_fixed(100.0 * g, 1)),
                                if c.held_back.is_empty() {
                                    String::new()
                                } else {
                                    format!(" held back {}", c.held_back.join(" "))
                                }
                            )
                        })
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })
            .unwrap_or_default();
        let line = format!(
            "| {seed} | {} | {} | {} | {} | {} | {} | {why} |",
            random.ident,
            fmt_fixed(random.after_mm, 5),
            stop.ident,
            fmt_fixed(stop.after_mm, 5),
            fmt_fixed(r, 3),
            fmt_fixed(rf, 3),
        );
        eprintln!("{line} ({:.0} s)", started.elapsed().as_secs_f64());
        lines.push(line);
        ratio.push(r);
        floor_ratio.push(rf);
        poses.push(stop.ident as f64);
        if prefixes {
            prefix_table(seed, &random).await;
        }
        drop((random.store, stop.store));
    }
    println!("{seeds} seeds ({:.0} s)\n", started.elapsed().as_secs_f64());
    println!("| seed | random: ident poses | verification (mm) | optimal + stop: ident poses | verification (mm) | × 100 random | × 100 random over the noise floors | stop (check: predicted mm) |");
    println!("|---|---|---|---|---|---|---|---|");
    for l in &lines {
        println!("{l}");
    }
    println!(
        "| mean | 100 | | {} | | {} | {} | {} × fewer identification readings |",
        fmt_fixed(mean(&poses), 1),
        fmt_fixed(mean(&ratio), 3),
        fmt_fixed(mean(&floor_ratio), 3),
        fmt_fixed(100.0 / mean(&poses), 2),
    );
}

/// (c): the optimal plan measured in full; the identification on each ranked prefix.
async fn prefix_table(seed: u64, random: &Done) {
    // the stop campaign's plan and measuring order (identification poses first, in blocks),
    // every pose measured: its first poses are what the stop campaign measured
    let full = campaign(&config_text(
        seed,
        "selection = \"optimal\"\nstop_when = \"predicted\"\nstop_min_gain = 0.0\nstop_remaining_gain = 0.0",
    ))
    .await;
    let (nominal, opts, travel) = &full.recipe;
    let index = |o: &Observation| o.id.parse::<usize>().expect("pose index");
    let mut ident: Vec<&Observation> = full
        .rows
        .iter()
        .filter(|o| o.set == PoseSet::Ident)
        .collect();
    ident.sort_by_key(|o| index(o));
    let verify_q: Vec<Vec<f64>> = full
        .rows
        .iter()
        .filter(|o| o.set == PoseSet::Verify)
        .map(|o| o.q.clone())
        .collect();
    let random_over_floor = random.after_mm / random.floor_mm;
    let mut out = Vec::new();
    for n in [24, 32, 40, 48, 56, 64, 80, 100] {
        let rows: Vec<Observation> = full
            .rows
            .iter()
            .filter(|o| o.set == PoseSet::Verify || index(o) < n)
            .cloned()
            .collect();
        let Ok((rep, id)) = calibrate(nominal, &rows, opts, *travel) else {
            out.push(format!("{n}: failed"));
            continue;
        };
        let after = rep
            .metrics
            .verify
            .as_ref()
            .expect("verify")
            .after
            .position_mean_mm;
        let q = |v: &[&Observation]| v.iter().map(|o| o.q.clone()).collect::<Vec<_>>();
        let p = predict_check(
            &id,
            *travel,
            &verify_q,
            &q(&ident[..n]),
            10,
            &q(&ident[n..]),
        );
        let gains = p.map_or("-".into(), |p| {
            format!(
                "params {} held back {:?} rejected {} sigma0 {} pred {} block {} rest {}",
                id.identifiability.identified.len(),
                p.held_back,
                id.rejected.len(),
                fmt_fixed(id.sigma0_mm, 4),
                fmt_fixed(p.now.mean_mm, 5),
                p.block_gain()
                    .map_or("-".into(), |g| fmt_fixed(100.0 * g, 1)),
                p.remaining_gain()
                    .map_or("-".into(), |g| fmt_fixed(100.0 * g, 1))
            )
        });
        out.push(format!(
            "| {seed} | {n} | {} | floor {} / random {} | {} | {} | {gains} |",
            fmt_fixed(after, 5),
            fmt_fixed(full.floor_mm, 5),
            fmt_fixed(random.floor_mm, 5),
            fmt_fixed(after / random.after_mm, 3),
            fmt_fixed((after / full.floor_mm) / random_over_floor, 3),
        ));
    }
    eprintln!("{}", out.join("\n"));
}
