//! Campaign planning time on `config/cell.example.toml` at 300, 1000, 30 000 and 100 000
//! poses: sampling, the wrist side, the hub, the path check of every pose against it (ball at
//! P1 and P2), the measuring order by leg time (k-d tree nearest neighbour, then 2-opt) and the
//! routes of every move. Run with `cargo bench --bench plan`.

use std::path::Path;
use std::time::Duration;

use cellcal::campaign::session::plan_request;
use cellcal::config::load_cell_config;
use cellcal::model::load_robot;
use cellcal::plan::plan_campaign;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use nalgebra::Vector3;

fn bench_plan(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.example.toml");
    let cfg = load_cell_config(&path).expect("example config");
    let mut model = load_robot(&cfg.robot).expect("robot model");
    model.tool = Vector3::from(cfg.campaign.tool_mm);
    let mut group = c.benchmark_group("plan_campaign");
    group.sample_size(10);
    for poses in [300, 1000, 30_000, 100_000] {
        let mut req = plan_request(&cfg);
        req.poses = poses;
        req.ident = poses / 3;
        group.measurement_time(Duration::from_secs(if poses > 1000 { 30 } else { 5 }));
        group.bench_with_input(BenchmarkId::from_parameter(poses), &req, |b, req| {
            b.iter(|| plan_campaign(&model, req).expect("plans"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_plan);
criterion_main!(benches);
