//! Criterion benchmark of `cellcal identify`'s whole pipeline from the file, and of its phases,
//! on a 10 000-pose OP data set (all poses ident, as `cellcal simulate-data --poses 10000
//! --ident 10000` writes it, rotation columns included): read + parse (`read_csv`, as the
//! command reads it), split + convert (`split_measured`), identify (its joint table included),
//! the metrics before and after (from the shared joint table, as `calibrate` does), and the
//! whole of it (`calibrate` on the rows `read_csv` reads). Run with
//! `cargo bench --bench pipeline`.

use std::hint::black_box;
use std::path::Path;

use cellcal::analysis::metrics::evaluate_pair;
use cellcal::calibrate::calibrate;
use cellcal::dataset::{read_csv, split_measured, write_csv, Required};
use cellcal::identify::{identify, IdentifyOptions, JointTrig, ObsConfig, ObsModel};
use cellcal::model::tx60;
use cellcal::simulate::{self, truth, SimConfig};
use criterion::{criterion_group, criterion_main, Criterion};

const POSES: usize = 10_000;
const OP: Required = Required {
    p2: true,
    rotation: false,
    rotation_unused: true,
};

/// The simulated OP campaign as a CSV file in `dir`.
fn write_data(dir: &Path) -> std::path::PathBuf {
    let nominal = tx60();
    let truth = truth::apply_errors(&nominal, &truth::paper_errors()).expect("errors");
    let cfg = SimConfig {
        poses: POSES,
        ident: POSES,
        ..SimConfig::default()
    };
    let data = simulate::simulate(&nominal, &truth, &cfg).expect("sim");
    let path = dir.join("op10k.csv");
    std::fs::write(&path, write_csv(&data.observations, 6, "pipeline bench")).expect("write");
    path
}

fn bench_pipeline(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = write_data(dir.path());
    let robot = tx60();
    let opts = IdentifyOptions::new(ObsConfig::new(ObsModel::Op, 10.0));
    let read = || read_csv(&path, 6, OP).expect("read").1;
    let rows = read();
    let (ident, _) = split_measured(&rows, ObsModel::Op, 10.0).expect("convert");
    let id = identify(&robot, &ident, &opts).expect("identify");

    let mut g = c.benchmark_group("pipeline_op_10k");
    g.sample_size(20);
    g.bench_function("read_parse", |b| b.iter(read));
    g.bench_function("split_convert", |b| {
        b.iter(|| split_measured(black_box(&rows), ObsModel::Op, 10.0).expect("convert"))
    });
    g.bench_function("identify", |b| {
        b.iter(|| identify(&robot, black_box(&ident), &opts).expect("identify"))
    });
    g.bench_function("metrics", |b| {
        let trig = JointTrig::of(&ident);
        b.iter(|| {
            let t = Some(&trig);
            evaluate_pair(&id.initial, &id.corrected, black_box(&ident), t, &opts.obs)
        })
    });
    g.bench_function("whole_from_file", |b| {
        b.iter(|| calibrate(&robot, &read(), &opts, 10.0).expect("calibrate"))
    });
    g.finish();
}

criterion_group!(benches, bench_pipeline);
criterion_main!(benches);
