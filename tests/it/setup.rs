//! The cell setup math end to end: the tool-frame procedure planned on the nominal TX60 and
//! run on a true robot (docs/method.md §7 (paper Table 3) errors, base, tool, misaligned stage axis, AT960
//! noise, joint jitter), then base registration on well-spread campaign poses.
//!
//! Noise-free runs on an error-free robot must recover everything exactly; with the MDH errors
//! the nominal-model IK commands motions the true robot performs slightly differently, so the
//! recovered frame carries a small kinematic bias (measured below), and the base registration
//! is only as good as the nominal model.

use cellcal::analysis::evaluate;
use cellcal::identify::{identify, ObsModel};
use cellcal::measure::{
    base_from_tool_frame, plan_tool_frame, register_base, select_spread, solve_tool_frame,
    BaseRegistration, SetupMeasurement, ToolFrame, ToolFramePlanRequest,
};
use cellcal::model::ik::{flange_pose, solve_flange, IkOptions};
use cellcal::model::kinematics::Pose;
use cellcal::model::rotation::{from_rotation_vector, log_so3};
use cellcal::model::RobotModel;
use cellcal::plan::campaign::line_of_sight_ok;
use cellcal::plan::{plan_campaign, PlanRequest, Workspace};
use cellcal::simulate::{SimConfig, TrackerNoise};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::common::*;

/// Start of the home pose: flange at ~(310, 35, 465) mm (base frame), flange z within ~2° of
/// the tracker, elbow and wrist well away from their singularities; [`home`] aims it exactly.
const HOME_GUESS: [f64; 6] = [0.05, 1.0, -1.0, 0.1, 1.6, 0.1];
const TRAVEL: f64 = 10.0;
const JITTER: f64 = 1.2746e-5;

/// The true cell: robot (with base and tool), stage axis, tracker noise, jitter and RNG.
struct Cell {
    truth: RobotModel,
    u: Vector3<f64>,
    noise: Option<TrackerNoise>,
    jitter: f64,
    rng: ChaCha8Rng,
}

fn gauss3(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    Vector3::new(
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
    )
}

impl Cell {
    /// The test cell: Table 3 errors or none, AT960 noise or none, joint jitter or none.
    fn new(mdh_errors: bool, noisy: bool, seed: u64) -> Cell {
        Cell::with_jitter(mdh_errors, noisy, if noisy { JITTER } else { 0.0 }, seed)
    }

    fn with_jitter(mdh_errors: bool, noisy: bool, jitter: f64, seed: u64) -> Cell {
        let mut truth = if mdh_errors { paper_truth() } else { tx60() };
        // tracker at the origin of its frame, ~2.5 m in front of the robot (base x towards it)
        truth.base_rotation = from_rotation_vector(&Vector3::new(0.01, -0.02, 3.1));
        truth.base_translation = Vector3::new(2500.0, 50.0, -400.0);
        truth.tool = Vector3::new(3.0, -12.0, 62.0);
        Cell {
            truth,
            u: from_rotation_vector(&Vector3::new(0.004, 0.0, -0.006)) * Vector3::y(),
            noise: noisy.then(|| TrackerNoise::at960(Vector3::zeros())),
            jitter,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Move to `q` (with jitter) and measure the ball at stage offsets `s` (mm).
    fn measure(&mut self, q: &[f64], stage: &[f64]) -> Vec<Vector3<f64>> {
        let qj: Vec<f64> = q
            .iter()
            .map(|v| {
                let g: f64 = StandardNormal.sample(&mut self.rng);
                v + self.jitter * g
            })
            .collect();
        let f = flange_pose(&self.truth, &qj);
        stage
            .iter()
            .map(|s| {
                let p = self.truth.base_rotation
                    * f.transform_point(&(self.truth.tool + self.u * *s))
                    + self.truth.base_translation;
                match self.noise {
                    Some(n) => p + gauss3(&mut self.rng) * n.sigma_mm(&p),
                    None => p,
                }
            })
            .collect()
    }

    /// True flange rotation and origin at `q` in the tracker frame.
    fn flange(&self, q: &[f64]) -> (nalgebra::Matrix3<f64>, Vector3<f64>) {
        let f = flange_pose(&self.truth, q);
        (
            self.truth.base_rotation * f.r,
            self.truth.base_rotation * f.p + self.truth.base_translation,
        )
    }
}

/// The home pose: `HOME_GUESS` turned (nominal IK, about the flange origin) so that flange z
/// points exactly at the tracker, as a technician would jog it.
fn home(cell: &Cell) -> Vec<f64> {
    let tracker = cell.truth.base_rotation.transpose() * (-cell.truth.base_translation);
    let f = flange_pose(&tx60(), &HOME_GUESS);
    let z = f.r.column(2).into_owned();
    let to = (tracker - f.p).normalize();
    let turn =
        from_rotation_vector(&(z.cross(&to).normalize() * z.dot(&to).clamp(-1.0, 1.0).acos()));
    let target = Pose {
        r: turn * f.r,
        p: f.p,
    };
    solve_flange(&tx60(), &HOME_GUESS, &target, &IkOptions::default())
        .expect("home aims at the tracker")
        .q
}

/// Plan on the nominal model, measure on the true cell, solve.
fn run_tool_frame(cell: &mut Cell, req: &ToolFramePlanRequest) -> ToolFrame {
    let plan = plan_tool_frame(&tx60(), &home(cell), req).expect("setup targets plan");
    // a 1.5" SMR accepts ±30°: every target keeps the ball facing the tracker
    let los = PlanRequest {
        line_of_sight_max_rad: 30f64.to_radians(),
        ..campaign_request(cell, &cell.truth.tool)
    };
    for t in &plan {
        assert!(
            line_of_sight_ok(&tx60(), &t.q_rad, &los),
            "{}",
            t.mark.label()
        );
    }
    let meas: Vec<SetupMeasurement> = plan
        .iter()
        .map(|t| {
            let stage: &[f64] = if t.measure_p2 { &[0.0, TRAVEL] } else { &[0.0] };
            let pts = cell.measure(&t.q_rad, stage);
            SetupMeasurement {
                mark: t.mark,
                p1: pts[0],
                p2: pts.get(1).copied(),
            }
        })
        .collect();
    solve_tool_frame(&meas).expect("tool frame solves")
}

/// Errors of a tool frame against the truth: (tool mm, stage axis rad, axes rad, origin mm).
fn frame_errors(cell: &Cell, tf: &ToolFrame) -> (f64, f64, f64, f64) {
    let (r, o) = cell.flange(&home(cell));
    (
        (tf.tool_mm - cell.truth.tool).norm(),
        tf.stage_axis.cross(&cell.u).norm().asin(),
        log_so3(&(tf.rotation() * r.transpose())).norm(),
        (tf.origin_mm - o).norm(),
    )
}

/// A campaign request for this cell (tracker position in the base frame).
fn campaign_request(cell: &Cell, tool: &Vector3<f64>) -> PlanRequest {
    PlanRequest {
        workspace: Workspace::default(),
        poses: 60,
        ident: 60,
        seed: 11,
        tracker_mm: cell.truth.base_rotation.transpose() * (-cell.truth.base_translation),
        line_of_sight_max_rad: 0.6,
        tool_mm: *tool,
        selection: cellcal::plan::selection::Selection::Random,
        design: cellcal::plan::selection::DesignSetup::default(),
        drift_every: 0,
        ident_block: None,
        speed_pct: 20.0,
        move_speed_rad_s: None,
        settle_s: 1.5,
        stage_offset_mm: Vector3::zeros(),
    }
}

/// Campaign poses the tracker can see (nominal model).
fn campaign_poses(cell: &Cell, tool: &Vector3<f64>) -> Vec<Vec<f64>> {
    plan_campaign(&tx60(), &campaign_request(cell, tool))
        .expect("campaign plans")
        .poses
        .into_iter()
        .map(|p| p.q_rad)
        .collect()
}

#[test]
fn exact_cell_is_recovered_exactly() {
    let mut cell = Cell::new(false, false, 1);
    let tf = run_tool_frame(&mut cell, &ToolFramePlanRequest::default());
    let (tool, axis, rot, origin) = frame_errors(&cell, &tf);
    assert!(tool < 1e-8, "tool {tool:e} mm");
    assert!(axis < 1e-12, "stage axis {axis:e} rad");
    assert!(rot < 1e-11, "flange axes {rot:e} rad");
    assert!(origin < 1e-8, "origin {origin:e} mm");
    assert!((tf.stage_travel_mm - TRAVEL).abs() < 1e-9);
    assert!(tf.sphere.rms_mm < 1e-9 && tf.jog_rms_mm < 1e-9);

    // base registration on spread poses with the recovered tool: exact
    let mut nominal = tx60();
    nominal.tool = tf.tool_mm;
    let poses = campaign_poses(&cell, &tf.tool_mm);
    let chosen = select_spread(&nominal, &poses, 6);
    let pairs: Vec<_> = chosen
        .iter()
        .map(|&i| (poses[i].clone(), cell.measure(&poses[i], &[0.0])[0]))
        .collect();
    let reg = register_base(&nominal, &pairs).expect("registers");
    assert!(reg.rms_mm < 1e-8, "rms {}", reg.rms_mm);
    assert!((reg.base.r - cell.truth.base_rotation).norm() < 1e-11);
    assert!((reg.base.p - cell.truth.base_translation).norm() < 1e-8);
    // and the one-pose estimate from the tool frame
    let b = base_from_tool_frame(&nominal, &home(&cell), &tf);
    assert!((b.r - cell.truth.base_rotation).norm() < 1e-10);
    assert!((b.p - cell.truth.base_translation).norm() < 1e-7);
}

/// Base registration with the recovered tool on six well-spread campaign poses.
fn register(cell: &mut Cell, tf: &ToolFrame) -> BaseRegistration {
    let mut nominal = tx60();
    nominal.tool = tf.tool_mm;
    let poses = campaign_poses(cell, &tf.tool_mm);
    let chosen = select_spread(&nominal, &poses, 6);
    let pairs: Vec<_> = chosen
        .iter()
        .map(|&i| (poses[i].clone(), cell.measure(&poses[i], &[0.0])[0]))
        .collect();
    register_base(&nominal, &pairs).expect("registers")
}

/// Rotation (rad) and translation (mm) error of a registration against the true base.
fn base_errors(cell: &Cell, reg: &BaseRegistration) -> (f64, f64) {
    (
        log_so3(&(reg.base.r * cell.truth.base_rotation.transpose())).norm(),
        (reg.base.p - cell.truth.base_translation).norm(),
    )
}

#[test]
fn kinematic_errors_alone_bias_the_frame_slightly() {
    // noise-free, but the nominal IK drives a robot with the Table 3 errors: the procedure
    // measures the flange frame as the nominal model realises it on the true robot (origin at
    // the nominal d6/a6 in the true wrist, axes turned by the wrist offsets), not the true MDH
    // flange frame; the identification absorbs the difference (see the next tests)
    let mut cell = Cell::new(true, false, 1);
    let tf = run_tool_frame(&mut cell, &ToolFramePlanRequest::default());
    let (tool, axis, rot, origin) = frame_errors(&cell, &tf);
    let reg = register(&mut cell, &tf);
    let (brot, btr) = base_errors(&cell, &reg);
    eprintln!(
        "kinematic bias vs the raw truth: tool {tool:.4} mm, stage axis {axis:.2e} rad, axes \
         {rot:.2e} rad, origin {origin:.4} mm; sphere rms {:.4} mm, jog angle − 90° {:.2e} rad, \
         rotation-angle rms {:.2e} rad; base registration rms {:.3} mm max {:.3} mm, rotation \
         {brot:.2e} rad, translation {btr:.3} mm",
        tf.sphere.rms_mm,
        tf.jog_axes_angle_rad - std::f64::consts::FRAC_PI_2,
        tf.rotation_angle_rms_rad.unwrap_or(f64::NAN),
        reg.rms_mm,
        reg.max_mm,
    );
    assert!(tool < 0.5 && origin < 0.5, "tool {tool} origin {origin} mm");
    assert!(
        axis < 1e-2 && rot < 1e-2,
        "stage axis {axis}, axes {rot} rad"
    );
    assert!(tf.sphere.rms_mm < 0.02, "sphere rms {}", tf.sphere.rms_mm);
    assert!(reg.rms_mm < 1.0 && brot < 2e-3 && btr < 1.5);
}

/// Accuracy of the noisy procedure over seeds, against the noise-free run on the same robot.
struct NoisyStats {
    tool_rms: f64,
    tool_max: f64,
    axis_rms: f64,
    axis_max: f64,
    axes_rms: f64,
}

fn noisy_stats(jitter: f64, label: &str) -> NoisyStats {
    // reference: the same procedure without noise on the same true robot (the frame the
    // procedure can measure at all; its bias against the raw truth is the previous test's)
    let req = ToolFramePlanRequest::default();
    let reference = run_tool_frame(&mut Cell::new(true, false, 1), &req);
    let seeds = 20;
    let (mut t_sq, mut a_sq, mut r_sq, mut raw_sq) = (0.0, 0.0, 0.0, 0.0);
    let (mut t_max, mut a_max) = (0.0f64, 0.0f64);
    let (mut reg_rms, mut reg_rot, mut reg_tr) = (0.0f64, 0.0f64, 0.0f64);
    let (mut gain, mut cond, mut sphere_rms) = (0.0, 0.0, 0.0f64);
    for seed in 0..seeds {
        let mut cell = Cell::with_jitter(true, true, jitter, 100 + seed);
        let tf = run_tool_frame(&mut cell, &req);
        let tool = (tf.tool_mm - reference.tool_mm).norm();
        let axis = tf.stage_axis.cross(&reference.stage_axis).norm().asin();
        let rot = log_so3(&(tf.rotation() * reference.rotation().transpose())).norm();
        raw_sq += frame_errors(&cell, &tf).0.powi(2);
        t_sq += tool * tool;
        a_sq += axis * axis;
        r_sq += rot * rot;
        t_max = t_max.max(tool);
        a_max = a_max.max(axis);
        gain = tf.sphere.centre_noise_gain;
        cond = tf.sphere.condition;
        sphere_rms = sphere_rms.max(tf.sphere.rms_mm);
        assert!((tf.jog_axes_angle_rad - std::f64::consts::FRAC_PI_2).abs() < 3e-3);
        assert!((tf.stage_travel_mm - TRAVEL).abs() < 0.05);
        assert!(sphere_rms < 0.05, "sphere rms {sphere_rms}");
        let reg = register(&mut cell, &tf);
        let (brot, btr) = base_errors(&cell, &reg);
        reg_rms = reg_rms.max(reg.rms_mm);
        reg_rot = reg_rot.max(brot);
        reg_tr = reg_tr.max(btr);
    }
    let n = seeds as f64;
    let (t_rms, a_rms, r_rms) = ((t_sq / n).sqrt(), (a_sq / n).sqrt(), (r_sq / n).sqrt());
    eprintln!(
        "{label}, {seeds} seeds, vs the noise-free run: tool rms {t_rms:.4} max {t_max:.4} mm; \
         stage axis rms {a_rms:.2e} max {a_max:.2e} rad; flange axes rms {r_rms:.2e} rad; \
         (tool vs raw truth rms {:.4} mm); sphere condition {cond:.1}, centre gain {gain:.2}, \
         max sphere rms {sphere_rms:.4} mm; base registration: max rms {reg_rms:.3} mm, max \
         rotation error {reg_rot:.2e} rad, max translation error {reg_tr:.3} mm",
        (raw_sq / n).sqrt()
    );
    // reg_rms is the nominal model's own error at the spread poses chosen from the plan (1.00 mm
    // at worst since plans keep one wrist side and hub-routable poses), not a setup error
    assert!(reg_rms < 1.2 && reg_rot < 2e-3 && reg_tr < 1.5);
    NoisyStats {
        tool_rms: t_rms,
        tool_max: t_max,
        axis_rms: a_rms,
        axis_max: a_max,
        axes_rms: r_rms,
    }
}

#[test]
fn noisy_procedure_meets_the_setup_tolerances() {
    // AT960 noise only (~14 µm per point at ~2 m): the sphere centre carries ≈ 6 × σ
    let s = noisy_stats(0.0, "AT960 noise");
    assert!(
        s.tool_rms < 0.1 && s.tool_max < 0.2,
        "tool {} / {}",
        s.tool_rms,
        s.tool_max
    );
    assert!(
        s.axis_rms < 2e-3 && s.axis_max < 3e-3,
        "axis {} / {}",
        s.axis_rms,
        s.axis_max
    );
    assert!(s.axes_rms < 2e-3, "flange axes {}", s.axes_rms);
    // plus joint jitter (ISO 9283 RP 0.02 mm): ≈ 18 µm per point, tool ≈ 0.1 mm
    let s = noisy_stats(JITTER, "AT960 noise + joint jitter");
    assert!(
        s.tool_rms < 0.13 && s.tool_max < 0.25,
        "tool {} / {}",
        s.tool_rms,
        s.tool_max
    );
    assert!(
        s.axis_rms < 2e-3 && s.axis_max < 3e-3,
        "axis {} / {}",
        s.axis_rms,
        s.axis_max
    );
    assert!(s.axes_rms < 2e-3, "flange axes {}", s.axes_rms);
}

#[test]
fn setup_results_let_the_calibration_reach_the_floor() {
    // the measured tool and stage axis (noisy, kinematically biased) are good enough: an OP
    // identification with them fixed (base identified) reaches the noise floor as with the truth
    let mut cell = Cell::new(true, true, 7);
    let tf = run_tool_frame(&mut cell, &ToolFramePlanRequest::default());
    let cfg = SimConfig {
        tracker: Some(TrackerNoise::at960(Vector3::zeros())),
        stage_axis: cell.u,
        ..SimConfig::default()
    };
    let data = sim(&cell.truth, &cfg);
    let run = |model: ObsModel, tool: Vector3<f64>, axis: Vector3<f64>| {
        let mut opts = options(model, axis);
        opts.identify_base = true;
        let mut nominal = tx60();
        nominal.tool = tool;
        let (ident, verify) = measured(&data.observations, &opts);
        let id = identify(&nominal, &ident, &opts).expect("identification runs");
        // OP: the stage axis a few mrad off +y makes β6 formally identifiable, but no pose set
        // separates it from a6: held at nominal. Position only: θ6 acts through the 12 mm tool
        // offset alone, predicted σ 0.50–0.52 mrad with a6 (at its bound). Every other
        // parameter is identified
        let (held, borderline): (&[&str], &[&str]) = match model {
            ObsModel::Op => (&["beta6"], &[]),
            _ => (&[], &["theta6"]),
        };
        assert_structural_set_but(&id, &nominal, &opts, held, borderline);
        let after = evaluate(&id.corrected, &verify, &opts.obs).position_mean_mm;
        let fl = floor(&cell.truth, &verify, &options(model, cell.u));
        (after, fl)
    };
    for (model, ratio) in [(ObsModel::Op, 1.10), (ObsModel::Position, 1.15)] {
        let (with_setup, fl) = run(model, tf.tool_mm, tf.stage_axis);
        let (with_truth, _) = run(model, cell.truth.tool, cell.u);
        eprintln!(
            "{model:?} verification after calibration: with the setup tool/axis \
             {with_setup:.5} mm, with the true ones {with_truth:.5} mm, floor {fl:.5} mm"
        );
        assert!(
            with_setup <= ratio * fl,
            "{model:?}: {with_setup} vs floor {fl}"
        );
    }
}
