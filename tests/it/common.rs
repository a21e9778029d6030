//! Shared helpers: the TX60, simulated campaigns and the noise floor.

use std::path::Path;

use cellcal::analysis::evaluate;
use cellcal::dataset::{split, to_measured, Observation};
use cellcal::identify::solver::Options;
use cellcal::identify::{IdentifyOptions, Measured, ObsConfig, ObsModel, PracticalBounds};
use cellcal::model::{parse_robot, RobotModel};
use cellcal::simulate::{self, truth, SimConfig, SimData};
use nalgebra::Vector3;

pub const TX60: &str = include_str!("../../config/robots/staubli_tx60.toml");

pub fn tx60() -> RobotModel {
    parse_robot(TX60, Path::new("staubli_tx60.toml")).expect("TX60 model loads")
}

pub fn paper_truth() -> RobotModel {
    truth::apply_errors(&tx60(), &truth::paper_errors()).expect("paper errors apply")
}

pub fn sim(truth: &RobotModel, cfg: &SimConfig) -> SimData {
    simulate::simulate(&tx60(), truth, cfg).expect("poses sampled")
}

pub fn options(model: ObsModel, axis: Vector3<f64>) -> IdentifyOptions {
    let mut obs = ObsConfig::new(model, 10.0);
    obs.stage_axis = axis;
    IdentifyOptions {
        obs,
        identify_base: false,
        identify_tool: false,
        robust: None,
        point_weights: None,
        solver: Options::default(),
        practical: PracticalBounds::default(),
    }
}

pub fn measured(rows: &[Observation], opts: &IdentifyOptions) -> (Vec<Measured>, Vec<Measured>) {
    let (i, v) = split(rows);
    (
        to_measured(&i, opts.obs.model, 10.0).expect("ident rows convert"),
        to_measured(&v, opts.obs.model, 10.0).expect("verify rows convert"),
    )
}

/// Mean verification position error of the true model: the noise floor (mm).
pub fn floor(truth: &RobotModel, verify: &[Measured], opts: &IdentifyOptions) -> f64 {
    evaluate(truth, verify, &opts.obs).position_mean_mm
}
