//! Criterion benchmarks: identification at 100 / 1 000 / 10 000 poses for each model, and
//! forward kinematics + Jacobian per pose. Run with `cargo bench`.

use std::hint::black_box;

use cellcal::calibrate::calibrate;
use cellcal::dataset::to_measured;
use cellcal::identify::observation::residual_jacobian;
use cellcal::identify::{all_params, identify, IdentifyOptions, Nongeometric, ObsConfig, ObsModel};
use cellcal::model::{TermFamily, TermKind};
use cellcal::simulate::{self, truth, SimConfig};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use nalgebra::Vector3;

fn setup(
    n: usize,
    axis: Vector3<f64>,
) -> (
    cellcal::model::RobotModel,
    Vec<cellcal::dataset::Observation>,
) {
    let nominal = cellcal::model::tx60();
    let truth = truth::apply_errors(&nominal, &truth::paper_errors()).expect("errors");
    let cfg = SimConfig {
        poses: n,
        ident: n,
        seed: 4812,
        stage_axis: axis,
        ..SimConfig::default()
    };
    let data = simulate::simulate(&nominal, &truth, &cfg).expect("sim");
    (nominal, data.observations)
}

fn bench_identify(c: &mut Criterion) {
    let mut g = c.benchmark_group("identify");
    g.sample_size(10);
    for model in [
        ObsModel::Position,
        ObsModel::Np,
        ObsModel::Op,
        ObsModel::Full,
    ] {
        let axis = if model == ObsModel::Np {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let (nominal, rows) = setup(10_000, axis);
        for n in [100usize, 1000, 10_000] {
            let mut obs = ObsConfig::new(model, 10.0);
            obs.stage_axis = axis;
            let opts = IdentifyOptions::new(obs);
            let meas = to_measured(&rows[..n], model, 10.0).expect("convert");
            g.bench_with_input(BenchmarkId::new(model.name(), n), &meas, |b, m| {
                b.iter(|| identify(&nominal, black_box(m), &opts).expect("identify"))
            });
        }
    }
    g.finish();
}

fn bench_pose(c: &mut Criterion) {
    let (nominal, rows) = setup(100, Vector3::y());
    let meas = to_measured(&rows, ObsModel::Full, 10.0).expect("convert");
    let params = all_params(6, false, false);
    let mut g = c.benchmark_group("per_pose");
    for model in [ObsModel::Position, ObsModel::Op, ObsModel::Full] {
        let cfg = ObsConfig::new(model, 10.0);
        let rows = model.rows();
        let mut res = vec![0.0; rows];
        let mut jac = vec![0.0; rows * params.len()];
        g.bench_function(format!("fk_jacobian_30_{}", model.name()), |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % meas.len();
                residual_jacobian(&nominal, &meas[i], &cfg, &params, &mut res, &mut jac);
                black_box(&jac);
            })
        });
    }
    g.bench_function("fk_only", |b| {
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % meas.len();
            black_box(cellcal::model::forward(&nominal, &meas[i].q));
        })
    });
    g.finish();
}

/// Issue 21's time figure: OP at 10 000 poses on the TX60 with its masses, the geometric
/// identification against the one with both term families (`identify`), and the whole
/// `calibrate` (which with terms also fits the geometric model to judge them); `identify` again
/// on a simulated robot that has compliance and harmonics too (`…_truth_terms`).
fn bench_nongeometric(c: &mut Criterion) {
    let (_, rows) = setup(10_000, Vector3::y());
    let nominal =
        cellcal::model::load_robot(std::path::Path::new("config/robots/staubli_tx60.toml"))
            .expect("robot file");
    let mut truth = truth::apply_errors(&nominal, &truth::paper_errors()).expect("errors");
    // a few tenths of a milliradian, as in the calibration's tests
    *truth.term_mut(1, TermKind::Compliance) = 4e-6;
    *truth.term_mut(2, TermKind::Compliance) = 6e-6;
    for j in 0..5 {
        for (k, v) in TermKind::ALL[1..].iter().zip([2e-4, -1e-4, 0.5e-4, 1e-4]) {
            *truth.term_mut(j, *k) = v * if j % 2 == 0 { 1.0 } else { -0.7 };
        }
    }
    let cfg = SimConfig {
        poses: 10_000,
        ident: 10_000,
        seed: 4812,
        stage_axis: Vector3::y(),
        ..SimConfig::default()
    };
    let with_terms = simulate::simulate(&nominal, &truth, &cfg).expect("sim");
    let mut g = c.benchmark_group("nongeometric_10000_op");
    g.sample_size(10);
    for (name, families) in [
        ("geometric", Vec::new()),
        ("compliance_harmonics", TermFamily::ALL.to_vec()),
    ] {
        let opts = IdentifyOptions {
            nongeometric: Nongeometric::of(&families),
            ..IdentifyOptions::new(ObsConfig::new(ObsModel::Op, 10.0))
        };
        let meas = to_measured(&rows, ObsModel::Op, 10.0).expect("convert");
        g.bench_function(format!("identify_{name}"), |b| {
            b.iter(|| identify(&nominal, black_box(&meas), &opts).expect("identify"))
        });
        g.bench_function(format!("calibrate_{name}"), |b| {
            b.iter(|| calibrate(&nominal, black_box(&rows), &opts, 10.0).expect("calibrate"))
        });
        let meas = to_measured(&with_terms.observations, ObsModel::Op, 10.0).expect("convert");
        g.bench_function(format!("identify_{name}_truth_terms"), |b| {
            b.iter(|| identify(&nominal, black_box(&meas), &opts).expect("identify"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench_identify, bench_pose, bench_nongeometric);
criterion_main!(benches);
