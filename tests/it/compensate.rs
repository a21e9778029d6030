//! Compensation: compensated targets and programs put the TRUE robot where they should within
//! the calibration's accuracy (simulated data with a known truth, and a campaign on the
//! simulated cell whose corrected model comes from the daemon), where the nominal joints miss
//! by the robot's uncompensated error; the CSV contract and its bad input.

use cellcal::store::identification_rows;
use std::path::Path;

use cellcal::calibrate::{calibrate_result, BaseSource};
use cellcal::compensate::table::{parse_joints, parse_targets};
use cellcal::compensate::{Compensated, Compensator, Target};
use cellcal::dataset::split;
use cellcal::identify::ObsModel;
use cellcal::model::kinematics::{measured_point, measured_rotation};
use cellcal::model::rotation::{from_rotation_vector, log_so3};
use cellcal::model::{parse_robot, RobotModel};
use cellcal::report::corrected_model_toml;
use cellcal::simulate::SimConfig;
use nalgebra::Vector3;

use crate::cli::{cellcal, robot};
use crate::common::{options, paper_truth, sim, tx60};
use crate::serve::get_text;

/// The calibration's accuracy: compensated targets reach the true robot's pose this close
/// (mean, mm).
const ACCURACY_MM: f64 = 0.03;
/// The nominal joints miss by at least this much (mean, mm): without compensation the test
/// fails.
const UNCOMPENSATED_MIN_MM: f64 = 0.3;

/// The true robot's tool position at `q` as a target, with the flange orientation that
/// `orientation` gives `q` (none: a position-only target).
fn true_target(truth: &RobotModel, q: &[f64], orientation: Option<&RobotModel>) -> Target {
    Target {
        position_mm: measured_point(truth, q),
        rotation: orientation.map(|m| measured_rotation(m, q)),
    }
}

/// Joints at least 2° inside every limit, the elbow at least 0.1 rad from stretched (q3 = 0):
/// a target whose correction cannot run into a limit or across the elbow singularity.
pub(crate) fn well_inside(m: &RobotModel, q: &[f64]) -> bool {
    let margin = 2f64.to_radians();
    q[2].abs() >= 0.1
        && q.iter()
            .zip(&m.limits)
            .all(|(v, l)| *v >= l.min + margin && *v <= l.max - margin)
}

/// Mean distance (mm) of the true robot's tool at each row's `joints` from `want`.
fn mean_miss(
    truth: &RobotModel,
    rows: &[Compensated],
    want: &[Vector3<f64>],
    joints: impl Fn(&Compensated) -> &[f64],
) -> f64 {
    let sum: f64 = rows
        .iter()
        .zip(want)
        .map(|(c, p)| (measured_point(truth, joints(c)) - p).norm())
        .sum();
    sum / rows.len() as f64
}

/// Targets at the true tool positions of `qs` (orientation: see [`true_target`]), each solved
/// from its joints rounded to the degree (a program's hint), and both modes' errors on the true
/// robot: (compensated, nominal). A full pose comes back on the same branch: the compensated
/// joints a small correction of the true ones.
fn check_targets(
    comp: &Compensator,
    truth: &RobotModel,
    qs: &[Vec<f64>],
    orientation: Option<&RobotModel>,
) -> (f64, f64) {
    let mut rows = Vec::new();
    let mut want = Vec::new();
    for q in qs {
        let t = true_target(truth, q, orientation);
        let hint: Vec<f64> = q
            .iter()
            .map(|v| v.to_degrees().round().to_radians())
            .collect();
        let c = comp.targets(&[t], &hint).expect("compensates").remove(0);
        assert!(c.reachable && c.at_limit.is_empty(), "{c:?}");
        assert!(c.residual_mm < 1e-6 && c.residual_rad < 1e-9, "{c:?}");
        if orientation.is_some() {
            for (a, b) in c.q.iter().zip(q) {
                assert!((a - b).abs() < 0.01, "{:?} vs {q:?}", c.q);
            }
        }
        want.push(t.position_mm);
        rows.push(c);
    }
    (
        mean_miss(truth, &rows, &want, |c| &c.q),
        mean_miss(truth, &rows, &want, |c| &c.nominal_q),
    )
}

/// A program computed on the nominal model: (compensated, uncompensated) mean miss of the
/// pose the nominal model promised.
fn check_program(comp: &Compensator, truth: &RobotModel, qs: &[Vec<f64>]) -> (f64, f64) {
    let rows: Vec<Compensated> = qs
        .iter()
        .map(|q| comp.program_point(q).expect("compensates"))
        .collect();
    assert!(rows.iter().all(|c| c.reachable));
    let want: Vec<Vector3<f64>> = qs
        .iter()
        .map(|q| measured_point(comp.nominal(), q))
        .collect();
    (
        mean_miss(truth, &rows, &want, |c| &c.q),
        mean_miss(truth, &rows, &want, |c| &c.nominal_q),
    )
}

fn assert_compensates(what: &str, (compensated, nominal): (f64, f64)) {
    eprintln!(
        "{what}: true robot misses by {compensated:.4} mm compensated, {nominal:.4} mm nominal"
    );
    assert!(
        compensated <= ACCURACY_MM && nominal >= UNCOMPENSATED_MIN_MM,
        "{what}: compensated {compensated:.4} mm (≤ {ACCURACY_MM}), nominal {nominal:.4} mm (≥ {UNCOMPENSATED_MIN_MM})"
    );
}

#[test]
fn compensated_targets_reach_the_true_robot_on_simulated_data() {
    let mut truth = paper_truth();
    truth.base_translation = Vector3::new(2100.0, -350.0, 120.0);
    truth.base_rotation = from_rotation_vector(&Vector3::new(0.01, -0.02, 2.5));
    truth.tool = Vector3::new(0.5, 40.0, 60.0);
    let data = sim(
        &truth,
        &SimConfig {
            poses: 200,
            ident: 100,
            ..SimConfig::default()
        },
    );
    let mut opts = options(ObsModel::Op, Vector3::y());
    opts.identify_base = true;
    let mut nominal = tx60();
    nominal.tool = truth.tool;
    let (report, _) = calibrate_result(
        &nominal,
        &data.observations,
        &opts,
        10.0,
        BaseSource::Identified,
    )
    .expect("identifies");
    let text = corrected_model_toml(&report, &nominal, &[], BaseSource::Identified).unwrap();
    let identified = parse_robot(&text, Path::new("identified.toml")).unwrap();
    let comp = Compensator::new(&tx60(), &identified).expect("a calibration of the TX60");
    let (_, verify) = split(&data.observations);
    let qs: Vec<Vec<f64>> = verify
        .iter()
        .map(|o| o.q.clone())
        .filter(|q| well_inside(&nominal, q))
        .collect();
    assert!(qs.len() >= 80, "{} targets", qs.len());
    assert_compensates(
        "full-pose targets",
        check_targets(&comp, &truth, &qs, Some(&truth)),
    );
    assert_compensates("position targets", check_targets(&comp, &truth, &qs, None));
    assert_compensates("nominal program", check_program(&comp, &truth, &qs));
}

#[test]
fn compensation_refuses_a_model_that_is_not_a_calibration_of_the_robot() {
    let nominal = tx60();
    let mut other = tx60();
    other.joints[2].d += 25.0;
    let e = Compensator::new(&nominal, &other).unwrap_err().to_string();
    assert!(
        e.contains("d3 differs from the nominal model's by 25.000 mm (limit 20 mm)"),
        "{e}"
    );
    let mut short = tx60();
    short.joints.pop();
    short.limits.pop();
    let e = Compensator::new(&nominal, &short).unwrap_err().to_string();
    assert_eq!(e, "the nominal model has 6 joints, the identified model 5");
}

#[test]
fn compensate_csv_files_name_bad_cells() {
    let t = parse_targets(
        "# tool poses\nid,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\na,1,2,3,0,0,90\n\nb,4,5,6,0,0,0\n",
    )
    .expect("parses");
    assert_eq!((t[0].id.as_str(), t[0].line, t[1].line), ("a", 3, 5));
    let r = t[0].value.rotation.expect("rotation");
    assert!((log_so3(&r) - Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2)).norm() < 1e-15);
    let p = parse_targets("X_mm, y_mm ,z_mm\n1,2,3\n").expect("parses");
    assert_eq!((p[0].id.as_str(), p[0].value.rotation), ("1", None));
    for (text, want) in [
        (
            "x_mm,y_mm,z_mm\n1,2,nan\n",
            "line 2, column `z_mm`: `nan` is not finite",
        ),
        (
            "x_mm,y_mm,z_mm\n1,2,3\n1,inf,3\n",
            "line 3, column `y_mm`: `inf` is not finite",
        ),
        (
            "x_mm,y_mm,z_mm\n1,two,3\n",
            "line 2, column `y_mm`: `two` is not a number",
        ),
        (
            "x_mm,y_mm,z_mm\n1,2\n",
            "line 2: 2 fields, but the header has 3",
        ),
        ("x_mm,y_mm\n1,2\n", "missing column `z_mm`"),
        (
            "x_mm,y_mm,z_mm,rx_deg\n1,2,3,4\n",
            "missing column `ry_deg`",
        ),
        ("x_mm,y_mm,z_mm,x_mm\n1,2,3,4\n", "duplicated column `x_mm`"),
        ("x_mm,y_mm,z_mm\n", "the file has a header but no data rows"),
        ("# nothing\n", "the file is empty (no header row)"),
    ] {
        assert_eq!(parse_targets(text).unwrap_err().to_string(), want, "{text}");
    }
    let j = parse_joints("q1_deg,q2_deg,q3_deg\n90,0,-45\n", 3).expect("degrees");
    assert_eq!(
        j[0].value,
        vec![
            std::f64::consts::FRAC_PI_2,
            0.0,
            -std::f64::consts::FRAC_PI_4
        ]
    );
    for (text, want) in [
        ("q1,q2\n1,2\n", "missing column `q3`"),
        (
            "q1,q2,q3,q1_deg,q2_deg,q3_deg\n1,2,3,4,5,6\n",
            "line 1: give the joints in rad (`q1`) or in degrees (`q1_deg`), not both",
        ),
        (
            "q1,q2,q3\n1,2,-inf\n",
            "line 2, column `q3`: `-inf` is not finite",
        ),
    ] {
        assert_eq!(
            parse_joints(text, 3).unwrap_err().to_string(),
            want,
            "{text}"
        );
    }
}

/// `cellcal compensate --robot TX60 --identified ID --MODE INPUT --out OUT`: exit code and
/// stderr.
pub(crate) fn compensate(
    identified: &Path,
    mode: &str,
    input: &Path,
    out: &Path,
) -> (Option<i32>, String) {
    let o = cellcal()
        .args(["compensate", "--robot"])
        .arg(robot())
        .arg("--identified")
        .arg(identified)
        .arg(mode)
        .arg(input)
        .arg("--out")
        .arg(out)
        .output()
        .expect("runs");
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// `cellcal compensate` end to end: both modes write the contract's columns; a bad file is
/// exit 2 naming line and column; an unreachable target is exit 3 with the file written.
#[test]
fn compensate_command_writes_the_joint_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut identified = tx60();
    identified.joints[1].a += 0.4;
    identified.joints[2].theta += 0.001;
    let id_path = dir.path().join("identified.toml");
    std::fs::write(
        &id_path,
        cellcal::model::file::write_robot(&identified, &[]),
    )
    .unwrap();
    let start = [0.0f64, 30.0, 90.0, 0.0, 45.0, 0.0].map(f64::to_radians);
    let mut targets = String::from("id,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\n");
    let mut program = String::from("q1,q2,q3,q4,q5,q6\n");
    for k in 0..5 {
        let q: Vec<f64> = start
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.05 * (k * (i + 1)) as f64)
            .collect();
        let p = measured_point(&identified, &q);
        let r = log_so3(&measured_rotation(&identified, &q)).map(f64::to_degrees);
        targets.push_str(&format!(
            "t{k},{},{},{},{},{},{}\n",
            p.x, p.y, p.z, r.x, r.y, r.z
        ));
        program.push_str(&format!(
            "{},{},{},{},{},{}\n",
            q[0], q[1], q[2], q[3], q[4], q[5]
        ));
    }
    let t_path = dir.path().join("t.csv");
    std::fs::write(&t_path, &targets).unwrap();
    let j_path = dir.path().join("j.csv");
    let (code, err) = compensate(&id_path, "--targets", &t_path, &j_path);
    assert_eq!(code, Some(0), "{err}");
    let j = std::fs::read_to_string(&j_path).unwrap();
    let mut lines = j.lines();
    assert_eq!(
        lines.next(),
        Some(
            "id,q1,q2,q3,q4,q5,q6,reachable,residual_mm,residual_deg,at_limit,\
             q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg"
        ),
        "the degrees come after the columns that were there first"
    );
    for (k, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells[0], format!("t{k}"));
        assert_eq!(
            &cells[7..11],
            ["true", "0.000000", "0.000000", ""],
            "{line}"
        );
        let q: Vec<f64> = cells[1..7].iter().map(|c| c.parse().unwrap()).collect();
        // q*_deg: the same joints in degrees, 6 decimals
        for (i, (deg, rad)) in cells[11..].iter().zip(&q).enumerate() {
            let (whole, decimals) = deg.split_once('.').expect("decimals");
            assert!(
                !whole.is_empty() && decimals.len() == 6,
                "q{}_deg {deg}",
                i + 1
            );
            let deg: f64 = deg.parse().expect("a number");
            assert!(
                (deg - rad.to_degrees()).abs() <= 5e-7,
                "q{}: {deg}° vs {rad} rad",
                i + 1
            );
        }
        assert_eq!(cells.len(), 17, "{line}");
        let want: Vec<f64> = start
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.05 * (k * (i + 1)) as f64)
            .collect();
        for (a, b) in q.iter().zip(&want) {
            assert!((a - b).abs() < 1e-9, "row {k}: {q:?} vs {want:?}");
        }
    }

    // a program computed on the nominal model
    let p_path = dir.path().join("p.csv");
    std::fs::write(&p_path, &program).unwrap();
    let (code, err) = compensate(&id_path, "--joints", &p_path, &j_path);
    assert_eq!(code, Some(0), "{err}");
    let j = std::fs::read_to_string(&j_path).unwrap();
    assert_eq!(j.lines().count(), 6);
    assert!(j.lines().skip(1).all(|l| l.contains(",true,")), "{j}");

    // bad input: exit 2 naming line and column
    std::fs::write(&t_path, targets.replacen("t1,", "t1,x", 1)).unwrap();
    let (code, err) = compensate(&id_path, "--targets", &t_path, &j_path);
    assert_eq!(code, Some(2));
    assert!(err.contains("t.csv: line 3, column `x_mm`: `x"), "{err}");

    // out of reach: exit 3, the row written as not reachable
    std::fs::write(&t_path, "x_mm,y_mm,z_mm\n0,0,5000\n").unwrap();
    let (code, err) = compensate(&id_path, "--targets", &t_path, &j_path);
    assert_eq!(code, Some(3), "{err}");
    let j = std::fs::read_to_string(&j_path).unwrap();
    assert!(j.lines().nth(1).unwrap().contains(",false,"), "{j}");
}

/// A whole campaign on the simulated cell (the real protocols, the world's hidden truth); its
/// corrected model fetched from the daemon (`GET /api/campaigns/{id}/model`, the bytes `run
/// --model-out` writes) compensates targets and a program onto the world's true robot.
#[test]
fn a_campaign_on_the_simulated_cell_compensates_the_true_robot() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let text = crate::campaign::config_text("", "", "").replace("poses = 300", "poses = 160");
    let f = rt.block_on(crate::campaign::run_in_process(&text));
    drop(rt);
    let dir = f.store.parent().expect("store dir").to_owned();
    let server = crate::serve::start(&dir.join("cell.toml"), &f.store);
    let (status, kind, model) = get_text(
        &server,
        &format!("/api/campaigns/{}/model", f.id),
        Some(&server.token),
    );
    assert_eq!(
        (status, kind.as_str()),
        (200, "text/plain; charset=utf-8"),
        "{model}"
    );
    assert!(
        model.contains("model's frame is the measurement (laser tracker) frame"),
        "{model}"
    );
    let (status, _, body) = get_text(&server, "/api/campaigns/999/model", Some(&server.token));
    assert_eq!(
        (status, body.as_str()),
        (404, "{\"error\":\"no campaign 999\"}")
    );
    let (status, created) =
        crate::serve::post(&server, "/api/campaigns", "{\"poses\": 40, \"ident\": 30}");
    assert_eq!(status, 201, "{created}");
    let fresh = created["id"].as_i64().expect("id");
    let (status, _, body) = get_text(
        &server,
        &format!("/api/campaigns/{fresh}/model"),
        Some(&server.token),
    );
    assert_eq!(status, 404);
    assert_eq!(
        body,
        format!("{{\"error\":\"campaign {fresh} has no result yet\"}}")
    );
    drop(server);

    // `run --model-out` on the done campaign writes the same bytes
    let out_path = dir.join("identified.toml");
    cellcal()
        .args(["run", "--config"])
        .arg(dir.join("cell.toml"))
        .arg("--store")
        .arg(&f.store)
        .args(["--campaign", &f.id.to_string(), "--model-out"])
        .arg(&out_path)
        .assert()
        .success();
    assert_eq!(std::fs::read_to_string(&out_path).unwrap(), model);

    let identified = parse_robot(&model, Path::new("identified.toml")).expect("loads");
    let comp = Compensator::new(&tx60(), &identified).expect("a calibration of the TX60");
    let rows = cellcal::store::Store::open(&f.store)
        .unwrap()
        .measured(f.id)
        .map(identification_rows)
        .unwrap();
    let (_, verify) = split(&rows);
    let qs: Vec<Vec<f64>> = verify
        .iter()
        .map(|o| o.q.clone())
        .filter(|q| well_inside(&f.nominal, q))
        .collect();
    assert!(qs.len() >= 40, "{} targets", qs.len());
    // full poses take the orientation the cell's model gives the flange: the cell measures
    // the flange frame as the nominal model realises it (the tool-frame setup), not the true
    // MDH flange frame (`tests/it/setup.rs`), so the truth's flange orientation is no target
    assert_compensates(
        "cell: full-pose targets",
        check_targets(&comp, &f.truth, &qs, Some(comp.identified())),
    );
    assert_compensates(
        "cell: position targets",
        check_targets(&comp, &f.truth, &qs, None),
    );
    assert_compensates("cell: nominal program", check_program(&comp, &f.truth, &qs));
}

/// The paper's true robot with lumped masses on the arm, a compliance on the loaded joints and
/// harmonics on five joints (docs/method.md §10): together they move the tool by ~0.17 mm.
fn truth_with_terms() -> RobotModel {
    use cellcal::model::{Mass, TermKind};
    let mut truth = paper_truth();
    truth.masses = [
        (2, [-150.0, 0.0, 120.0], 8.4),
        (3, [0.0, -80.0, 40.0], 6.0),
        (5, [0.0, 0.0, 20.0], 1.5),
        (6, [0.0, 0.0, 60.0], 2.0),
    ]
    .into_iter()
    .map(|(frame, at, kg)| Mass {
        frame,
        at: Vector3::from(at),
        kg,
    })
    .collect();
    for (j, c) in [(1, 1e-5), (2, 1.5e-5), (3, 5e-5), (4, 8e-5)] {
        *truth.term_mut(j, TermKind::Compliance) = c;
    }
    for (j, kind, v) in [
        (0, TermKind::SinQ, 5e-4),
        (1, TermKind::Cos2Q, -4e-4),
        (2, TermKind::SinQ, 3e-4),
        (2, TermKind::Sin2Q, 3e-4),
        (3, TermKind::CosQ, -5e-4),
        (4, TermKind::Cos2Q, 6e-4),
    ] {
        *truth.term_mut(j, kind) = v;
    }
    truth
}

/// Joints of the `--joints` or `--targets` output file `path` (rad, columns q1…q6).
pub(crate) fn output_joints(path: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .expect("written")
        .lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .skip(1)
                .take(6)
                .map(|c| c.parse().expect("a number"))
                .collect()
        })
        .collect()
}

/// Largest and mean distance (mm) of the true robot's tool at `joints` from `want`.
pub(crate) fn misses(truth: &RobotModel, joints: &[Vec<f64>], want: &[Vector3<f64>]) -> (f64, f64) {
    let d: Vec<f64> = joints
        .iter()
        .zip(want)
        .map(|(q, p)| (measured_point(truth, q) - p).norm())
        .collect();
    let max = d.iter().copied().fold(0.0, f64::max);
    (max, d.iter().sum::<f64>() / d.len() as f64)
}

/// `cellcal compensate` with an identified model file that has compliance and harmonics (and
/// the masses they were identified with): the compensated joints put the TRUE robot (with the
/// terms) on the targets within a micrometre, for tool targets and for a nominal program; the
/// same model without its terms (the geometric part only) misses by the terms' effect.
#[test]
fn compensated_joints_account_for_compliance_and_harmonics() {
    let dir = tempfile::tempdir().expect("tempdir");
    let truth = truth_with_terms();
    let geometric = RobotModel {
        terms: Vec::new(),
        ..truth.clone()
    };
    let write = |name: &str, m: &RobotModel| {
        let path = dir.path().join(name);
        std::fs::write(&path, cellcal::model::file::write_robot(m, &[])).unwrap();
        path
    };
    let (with_terms, without) = (write("terms.toml", &truth), write("geo.toml", &geometric));
    assert_eq!(
        parse_robot(&std::fs::read_to_string(&with_terms).unwrap(), &with_terms)
            .unwrap()
            .terms,
        truth.terms,
        "the file carries the terms"
    );

    // a path of tool poses of the true robot, from the default start on
    let start = [0.0f64, 30.0, 90.0, 0.0, 45.0, 0.0].map(f64::to_radians);
    let mut targets = String::from("id,x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg\n");
    let mut program = String::from("q1,q2,q3,q4,q5,q6\n");
    let (mut want, mut promised, mut effect) = (Vec::new(), Vec::new(), 0.0);
    let n = 12;
    for k in 0..n {
        let q: Vec<f64> = start
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.02 * (k * (i + 1)) as f64 - 0.1)
            .collect();
        let p = measured_point(&truth, &q);
        let r = log_so3(&measured_rotation(&truth, &q)).map(f64::to_degrees);
        targets.push_str(&format!(
            "t{k},{},{},{},{},{},{}\n",
            p.x, p.y, p.z, r.x, r.y, r.z
        ));
        program.push_str(&format!(
            "{},{},{},{},{},{}\n",
            q[0], q[1], q[2], q[3], q[4], q[5]
        ));
        effect += (p - measured_point(&geometric, &q)).norm() / n as f64;
        want.push(p);
        promised.push(measured_point(&tx60(), &q));
    }
    let (t_path, p_path) = (dir.path().join("t.csv"), dir.path().join("p.csv"));
    std::fs::write(&t_path, &targets).unwrap();
    std::fs::write(&p_path, &program).unwrap();
    let out = dir.path().join("j.csv");

    let (code, err) = compensate(&with_terms, "--targets", &t_path, &out);
    assert_eq!(code, Some(0), "{err}");
    let (max, _) = misses(&truth, &output_joints(&out), &want);
    let (code, err) = compensate(&without, "--targets", &t_path, &out);
    assert_eq!(code, Some(0), "{err}");
    let (_, geometric_mean) = misses(&truth, &output_joints(&out), &want);
    eprintln!(
        "targets: the terms move the tool by {effect:.4} mm (mean); compensated with them the \
         true robot misses by {max:.2e} mm (max), with the geometric part only by \
         {geometric_mean:.4} mm (mean)"
    );
    assert!(effect > 0.1, "the terms' effect: {effect} mm");
    assert!(max < 1e-3, "compensated with the terms: {max} mm");
    assert!(
        geometric_mean > 0.5 * effect,
        "geometric only: {geometric_mean} mm, the terms' effect {effect} mm"
    );

    // a program computed on the nominal model: the true robot goes where it promised
    let (code, err) = compensate(&with_terms, "--joints", &p_path, &out);
    assert_eq!(code, Some(0), "{err}");
    let (max, _) = misses(&truth, &output_joints(&out), &promised);
    let (code, err) = compensate(&without, "--joints", &p_path, &out);
    assert_eq!(code, Some(0), "{err}");
    let (_, geometric_mean) = misses(&truth, &output_joints(&out), &promised);
    eprintln!("program: {max:.2e} mm (max) with the terms, {geometric_mean:.4} mm (mean) without");
    assert!(max < 1e-3, "compensated with the terms: {max} mm");
    assert!(
        geometric_mean > 0.5 * effect,
        "geometric only: {geometric_mean} mm"
    );
}
