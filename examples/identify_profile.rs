//! Profiling driver: `identify` on the benchmark's simulated data, `N` times in one process.
//!
//! `cargo build --release --example identify_profile`, then e.g.
//! `valgrind --tool=callgrind --collect-atstart=no --toggle-collect='cellcal::identify::identify'
//! target/release/examples/identify_profile op 100 1` (model, poses, calls, and `miss` to make
//! every call miss the memo of the structural identifiability check, as a first call does;
//! `terms` to identify compliance and harmonics too, `truth-terms` for a simulated robot that
//! has them).
//! Prints the best time per call over batches of ten calls and the estimates.

use cellcal::dataset::to_measured;
use cellcal::identify::{identify, IdentifyOptions, Nongeometric, ObsConfig, ObsModel};
use cellcal::model::{TermFamily, TermKind};
use cellcal::simulate::{self, truth, SimConfig};
use nalgebra::Vector3;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let model = ObsModel::parse(args.get(1).map_or("op", String::as_str)).expect("model");
    let n: usize = args.get(2).map_or(100, |s| s.parse().expect("poses"));
    let calls: usize = args.get(3).map_or(1, |s| s.parse().expect("calls"));
    // "miss": every call misses the structural memo (a joint limit moved by one ulp per call)
    let miss = args[4.min(args.len())..].iter().any(|s| s == "miss");
    // "terms": with compliance and harmonics (issue 21's time figure)
    let terms = args[4.min(args.len())..].iter().any(|s| s == "terms");
    // "truth-terms": the simulated robot has compliance and harmonic errors too
    let truth_terms = args[4.min(args.len())..].iter().any(|s| s == "truth-terms");
    let axis = if model == ObsModel::Np {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let mut nominal = cellcal::model::tx60();
    let mut truth = truth::apply_errors(&nominal, &truth::paper_errors()).expect("errors");
    if truth_terms {
        // a few tenths of a milliradian, as in the calibration's tests
        *truth.term_mut(1, TermKind::Compliance) = 4e-6;
        *truth.term_mut(2, TermKind::Compliance) = 6e-6;
        for j in 0..5 {
            for (k, v) in TermKind::ALL[1..].iter().zip([2e-4, -1e-4, 0.5e-4, 1e-4]) {
                *truth.term_mut(j, *k) = v * if j % 2 == 0 { 1.0 } else { -0.7 };
            }
        }
    }
    let cfg = SimConfig {
        poses: n,
        ident: n,
        seed: 4812,
        stage_axis: axis,
        ..SimConfig::default()
    };
    let data = simulate::simulate(&nominal, &truth, &cfg).expect("sim");
    let meas = to_measured(&data.observations, model, 10.0).expect("convert");
    let mut obs = ObsConfig::new(model, 10.0);
    obs.stage_axis = axis;
    let opts = IdentifyOptions {
        nongeometric: if terms {
            Nongeometric::of(&TermFamily::ALL)
        } else {
            Nongeometric::default()
        },
        ..IdentifyOptions::new(obs)
    };
    // best batch of 10 calls: least disturbed by other load on the machine
    let mut last = None;
    let mut best = f64::INFINITY;
    let mut done = 0;
    while done < calls {
        let batch = (calls - done).min(10);
        let t0 = std::time::Instant::now();
        for _ in 0..batch {
            if miss {
                let l = &mut nominal.limits[0].max;
                *l = f64::from_bits(l.to_bits() + 1);
            }
            last = Some(identify(&nominal, &meas, &opts).expect("identify"));
        }
        best = best.min(t0.elapsed().as_secs_f64() * 1e3 / batch as f64);
        done += batch;
    }
    let dt = best;
    if let Some(r) = last {
        println!(
            "{} {n} poses: {dt:.3} ms/call (best batch), {} iterations, cost {:e}, sigma0 {:.6e}",
            model.name(),
            r.iterations,
            r.final_cost,
            r.sigma0_mm
        );
        for e in &r.estimates {
            println!("{} {:e} {:?}", e.param.name(), e.error, e.std);
        }
    }
}
