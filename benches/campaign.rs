//! Orchestration overhead per pose: a campaign against the simulated cell with zero-delay
//! devices (instant robot and stage moves, no stage settle, instant tracker Initialize, instant
//! measurements: `measure_time_scale = 0`), real protocols over loopback and a pty, and a real
//! SQLite store (synchronous=FULL). The setup steps are off (they are once per campaign, not per
//! pose). Run with `cargo bench --bench campaign`.
//!
//! Floor by construction: one durable commit per pose (an fsync of the store's file system; the
//! store lives in the temporary directory, `TMPDIR`).

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use cellcal::campaign::session::open_session;
use cellcal::campaign::{run_campaign, CampaignCommand, Outcome};
use cellcal::cell::ScriptedPrompter;
use cellcal::config::parse_cell_config;
use criterion::{criterion_group, criterion_main, Criterion};

const POSES: usize = 40;

/// Replace `from` by `to` in `text`; panics when `from` is missing (the example config changed).
fn set(text: String, from: &str, to: &str) -> String {
    assert!(
        text.contains(from),
        "config/cell.sim.toml no longer contains {from:?}"
    );
    text.replacen(from, to, 1)
}

fn config(dir: &Path) -> (String, std::path::PathBuf) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut text = std::fs::read_to_string(root.join("config/cell.sim.toml")).expect("config");
    for (from, to) in [
        (
            "realistic = false\n",
            "realistic = false\nmove_speed_deg_s = 1.0e9\nstage_speed_mm_s = 1.0e9\nsettle_ms = 0\nstage_settle_ms = 0\n",
        ),
        ("measure_time_scale = 1.0", "measure_time_scale = 0.0"),
        ("tool_frame = true", "tool_frame = false"),
        ("base_registration = true", "base_registration = false"),
        ("initialize_delay_ms = 10 ", "initialize_delay_ms = 0 "),
        ("poses = 300", &format!("poses = {POSES}")),
        ("ident = 100", "ident = 30"),
        ("drift_every = 50", "drift_every = 0"),
    ] {
        text = set(text, from, to);
    }
    std::fs::create_dir_all(dir.join("robots")).expect("mkdir");
    std::fs::copy(
        root.join("config/robots/staubli_tx60.toml"),
        dir.join("robots/staubli_tx60.toml"),
    )
    .expect("copy");
    let p = dir.join("cell.toml");
    std::fs::write(&p, &text).expect("write");
    (text, p)
}

fn bench_overhead(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let mut g = c.benchmark_group("campaign");
    g.sample_size(10);
    g.bench_function(format!("per_pose_zero_delay_{POSES}_poses"), |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                let dir = tempfile::tempdir().expect("tempdir");
                let (text, path) = config(dir.path());
                let cfg = parse_cell_config(&text, &path).expect("config");
                total += rt.block_on(async {
                    let s = open_session(
                        cfg,
                        &dir.path().join("c.db"),
                        None,
                        Arc::new(ScriptedPrompter::exact()),
                    )
                    .await
                    .expect("session");
                    let ctx = s.ctx;
                    let mut devices = s.devices;
                    ctx.control.apply(&CampaignCommand::Arm);
                    ctx.control.apply(&CampaignCommand::Start);
                    let t = Instant::now();
                    let out = run_campaign(&ctx, &mut devices).await.expect("run");
                    let el = t.elapsed();
                    assert!(matches!(out, Outcome::Done(_)));
                    if let Some(sim) = s.sim {
                        sim.stop().await;
                    }
                    // per pose (the identification at the end is included, ~1 ms)
                    el / POSES as u32
                });
            }
            total
        })
    });
    g.finish();
}

criterion_group!(benches, bench_overhead);
criterion_main!(benches);
