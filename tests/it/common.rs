//! Shared helpers: the TX60, simulated campaigns and the noise floor.

use std::net::TcpListener;
use std::path::{Path, PathBuf};

use cellcal::analysis::evaluate;
use cellcal::dataset::{split, to_measured, Observation};
use cellcal::identify::{
    all_params, structural_set, DropKind, Identification, IdentifyOptions, Measured, ObsConfig,
    ObsModel,
};
use cellcal::model::RobotModel;
use cellcal::simulate::{self, truth, SimConfig, SimData};
use nalgebra::Vector3;

/// The nominal TX60: the library's built-in copy of `config/robots/staubli_tx60.toml`.
pub use cellcal::model::tx60;

pub fn paper_truth() -> RobotModel {
    truth::apply_errors(&tx60(), &truth::paper_errors()).expect("paper errors apply")
}

pub fn sim(truth: &RobotModel, cfg: &SimConfig) -> SimData {
    simulate::simulate(&tx60(), truth, cfg).expect("poses sampled")
}

pub fn options(model: ObsModel, axis: Vector3<f64>) -> IdentifyOptions {
    let mut obs = ObsConfig::new(model, 10.0);
    obs.stage_axis = axis;
    IdentifyOptions::new(obs)
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

/// The practical test held nothing back where the data determines every parameter: the
/// identified set is the structural one of `nominal` for these options.
pub fn assert_structural_set(id: &Identification, nominal: &RobotModel, opts: &IdentifyOptions) {
    assert_structural_set_but(id, nominal, opts, &[], &[]);
}

/// The identified set is the structural one of `nominal` for these options except the
/// parameters the practical test held back: all of `held`, and of the others at most those in
/// `borderline` (predicted σ within a few % of its bound).
pub fn assert_structural_set_but(
    id: &Identification,
    nominal: &RobotModel,
    opts: &IdentifyOptions,
    held: &[&str],
    borderline: &[&str],
) {
    let candidates = all_params(nominal.dof(), opts.identify_base, opts.identify_tool);
    let structural = structural_set(nominal, &opts.obs, &candidates);
    let practical: Vec<String> = id
        .identifiability
        .dropped
        .iter()
        .filter(|d| d.kind != DropKind::Structural)
        .map(|d| d.param.name())
        .collect();
    let model = opts.obs.model;
    let dropped = &id.identifiability.dropped;
    assert!(
        held.iter().all(|h| practical.iter().any(|p| p == h)),
        "{model:?}: {held:?} not held back: {dropped:?}"
    );
    assert!(
        practical
            .iter()
            .all(|p| held.contains(&p.as_str()) || borderline.contains(&p.as_str())),
        "{model:?}: held back {practical:?}: {dropped:?}"
    );
    let expected: Vec<_> = structural
        .identified
        .iter()
        .filter(|p| !practical.contains(&p.name()))
        .copied()
        .collect();
    // a held-back parameter may let a structurally dependent one in (α6 for θ6)
    let substitutes: Vec<_> = id
        .identifiability
        .identified
        .iter()
        .filter(|p| !structural.identified.contains(p))
        .collect();
    assert!(
        substitutes.is_empty() || !practical.is_empty(),
        "{model:?}: {substitutes:?}"
    );
    assert!(
        expected
            .iter()
            .all(|p| id.identifiability.identified.contains(p)),
        "{model:?}: {:?} vs {expected:?}",
        id.identifiability.identified
    );
}

/// The `[robot_controller]` table head of a real controller at `address` (robotlink v3) with
/// a fresh shared secret written to a private `robot.key` in `dir`; the simulated robot of the
/// same configuration (if any) authenticates with it too.
pub fn real_controller(dir: &Path, address: impl std::fmt::Display) -> String {
    use std::os::unix::fs::PermissionsExt;
    let key = dir.join("robot.key");
    let hex: String = (0..32)
        .map(|i| format!("{:02x}", (i * 37 + 11) % 256))
        .collect();
    std::fs::write(&key, hex).expect("write robot.key");
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    format!(
        "[robot_controller]\nmode = \"real\"\naddress = \"{address}\"\nsecret_file = {:?}",
        key.to_string_lossy()
    )
}

/// The `cellcal` binary as a plain process (`spawn`, signals, pipes); `cli::cellcal` is the
/// assert_cmd form.
pub fn cellcal_process() -> std::process::Command {
    std::process::Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
}

/// A loopback port nobody listens on now.
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port()
}

/// The real-robot data set of `robot` (`ur5`, `wam`) under `tests/data/realdata`.
pub fn realdata_dir(robot: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/realdata")
        .join(robot)
}

/// The `.rs` files under `dir`, sorted, recursively.
pub fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    paths.sort();
    for p in paths {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}
