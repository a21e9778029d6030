//! The device adapters against the simulated cell, over loopback TCP and real ptys (real
//! drivers, no mocks): truth within noise, kinematics, stage direction, every configured fault
//! with its `FaultKind` and the recovery, the manual stage and the `cellcal sim` binary.

use std::future::Future;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::Duration;

use cellcal::cell::{
    Answer, CellError, ChannelPrompter, EmsconTracker, FaultKind, LinkRobot, ManualStage,
    ManualStageConfig, PromptContext, Robot, ScriptedPrompter, Stage, StagePosition, Tracker,
    ZaberStageAdapter,
};
use cellcal::config::RobotProtocol;
use cellcal::model::forward;
use cellcal::sim::{lock_world, start_cell, RunningSimCell, SimWorldConfig, StageMode};
use nalgebra::Vector3;

use crate::common::tx60;

/// Every test body runs under this bound: nothing waits for a person.
async fn bounded<T>(f: impl Future<Output = T>) -> T {
    tokio::time::timeout(Duration::from_secs(15), f)
        .await
        .expect("test finished within 15 s")
}

async fn cell(cfg: SimWorldConfig) -> RunningSimCell {
    start_cell(tx60(), cfg, std::future::pending())
        .await
        .expect("simulated cell starts")
}

async fn tracker(c: &RunningSimCell) -> EmsconTracker {
    let mut cfg = c.tracker_config();
    cfg.command_timeout_ms = 400;
    let mut t = EmsconTracker::new(cfg);
    t.prepare().await.expect("tracker prepares");
    t
}

async fn robot(c: &RunningSimCell) -> LinkRobot {
    let mut r = LinkRobot::new(c.robot_config());
    r.prepare(50.0).await.expect("robot prepares");
    r
}

async fn move_and_settle(r: &mut LinkRobot, q: &[f64]) -> Vec<f64> {
    r.move_joints(q).await.expect("move accepted");
    r.wait_settled(Duration::from_secs(5))
        .await
        .expect("robot settles")
}

fn assert_within(measured: Vector3<f64>, truth: Vector3<f64>, bound: f64, what: &str) {
    let d = measured - truth;
    assert!(
        d.iter().all(|v| v.abs() < bound),
        "{what}: measured {measured:?} vs true {truth:?}, diff {d:?} exceeds {bound} mm per axis"
    );
}

fn kind<T: std::fmt::Debug>(r: Result<T, CellError>) -> FaultKind {
    r.expect_err("a fault").kind
}

const Q: [f64; 6] = [0.3, -0.2, 1.4, 0.2, 0.8, -0.5];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tracker_measures_the_true_ball_within_noise_and_reproducibly() {
    bounded(async {
        let mut first = Vec::new();
        for _ in 0..2 {
            let c = cell(SimWorldConfig::default()).await;
            let mut t = tracker(&c).await;
            let p = t.measure().await.expect("measurement");
            let (truth, sigma) = {
                let mut w = lock_world(&c.world);
                let b = w.true_ball_mm();
                (b, w.sigma_mm(&b))
            };
            assert!(sigma > 0.005 && sigma < 0.05, "σ {sigma}");
            assert_within(p.p_mm, truth, 5.0 * sigma, "ball");
            assert!((p.std_mm[0] - sigma).abs() < 1e-9);
            first.push(p.p_mm);
            c.stop().await;
        }
        assert_eq!(first[0], first[1], "same seed, same measurement");
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn robot_move_changes_the_point_as_the_true_kinematics_predict() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut t = tracker(&c).await;
        let mut r = robot(&c).await;
        let before = t.measure().await.expect("measure before").p_mm;
        let readback = move_and_settle(&mut r, &Q).await;
        for (a, b) in readback.iter().zip(Q) {
            assert!((a - b).abs() < 1e-7, "read-back = commanded: {a} vs {b}");
        }
        let after = t.measure().await.expect("measure after").p_mm;
        let (model, q_true, sigma) = {
            let mut w = lock_world(&c.world);
            let b = w.true_ball_mm();
            (w.true_model().clone(), w.true_joints_rad(), w.sigma_mm(&b))
        };
        let jitter: f64 = q_true.iter().zip(Q).map(|(a, b)| (a - b).abs()).sum();
        assert!(jitter > 0.0 && jitter < 1e-3, "joint jitter {jitter}");
        let fl = *forward(&model, &q_true).flange();
        let predicted =
            model.base_rotation * fl.transform_point(&model.tool) + model.base_translation;
        assert_within(after, predicted, 5.0 * sigma, "after the move");
        assert!((after - before).norm() > 50.0, "the ball moved");
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stage_travel_moves_the_ball_along_the_rotated_real_axis() {
    bounded(async {
        let cfg = SimWorldConfig {
            stage_misalignment_mrad: [2.0, 0.0, 1.0],
            ..SimWorldConfig::default()
        };
        let c = cell(cfg).await;
        let mut t = tracker(&c).await;
        let mut r = robot(&c).await;
        move_and_settle(&mut r, &Q).await;
        let mut s = ZaberStageAdapter::new(c.stage_config().expect("zaber stage"));
        s.prepare().await.expect("stage homes");
        assert!(!s.is_manual());
        let r1 = s.move_to(0.0).await.expect("stage at 0");
        let p1 = t.measure().await.expect("P1").p_mm;
        let r2 = s.move_to(10.0).await.expect("stage at 10");
        assert!(
            r1.abs() < 1e-3 && (r2 - 10.0).abs() < 1e-3,
            "read-backs {r1} {r2}"
        );
        let p2 = t.measure().await.expect("P2").p_mm;
        let (expected, sigma) = {
            let mut w = lock_world(&c.world);
            let rot = w.true_flange().r;
            let b = w.true_ball_mm();
            (rot * w.stage_axis_actual() * 10.0, w.sigma_mm(&b))
        };
        assert_within(p2 - p1, expected, 5.0 * sigma * 2f64.sqrt(), "P2 − P1");
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tracker_faults_surface_as_their_kind_and_recover() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut t = tracker(&c).await;
        let faults = || c.tracker_faults.lock().expect("faults");

        faults().beam_break_before_measure = 1;
        assert_eq!(kind(t.measure().await), FaultKind::BeamBroken);
        t.relock(None).await.expect("re-lock");
        t.measure().await.expect("measure after re-lock");

        faults().beam_break_during_measure = 1;
        assert_eq!(kind(t.measure().await), FaultKind::BeamBroken);
        t.relock(None).await.expect("re-lock");
        t.measure().await.expect("measure after re-lock");

        lock_world(&c.world).faults.beam_break_probability = 1.0;
        assert_eq!(kind(t.measure().await), FaultKind::BeamBroken);
        lock_world(&c.world).faults.beam_break_probability = 0.0;
        t.relock(None).await.expect("re-lock");
        t.measure().await.expect("measure after random break");

        // the robot moves during the measurement: no target
        lock_world(&c.world)
            .start_move(Q.to_vec(), 1.0)
            .expect("slow move starts");
        assert_eq!(kind(t.measure().await), FaultKind::BeamBroken);
        lock_world(&c.world).stop();
        t.relock(None).await.expect("re-lock after the move");
        t.measure().await.expect("measure at rest");

        for (status, expected) in [(39, FaultKind::NotReady), (57, FaultKind::Device)] {
            faults().forced_status = Some(emscon::ForcedStatus {
                command: Some(49),
                status,
                count: 1,
            });
            assert_eq!(kind(t.measure().await), expected, "status {status}");
            t.measure().await.expect("measure after a forced status");
        }

        faults().no_reply = 1;
        assert_eq!(kind(t.measure().await), FaultKind::Timeout);
        t.measure().await.expect("measure after a timeout");

        faults()
            .malformed
            .push_back(emscon::Malformed::WrongCommandEcho);
        assert_eq!(kind(t.measure().await), FaultKind::Protocol);
        t.reconnect()
            .await
            .expect("reconnect after a protocol error");
        t.measure().await.expect("measure after reconnect");

        let n = lock_world(&c.world).measurements();
        lock_world(&c.world).faults.disconnect_after_measurements = n + 1;
        t.measure()
            .await
            .expect("the last measurement before the drop");
        assert_eq!(kind(t.measure().await), FaultKind::Disconnected);
        assert_eq!(kind(t.measure().await), FaultKind::Disconnected);
        lock_world(&c.world).faults.disconnect_after_measurements = 0;
        t.reconnect().await.expect("reconnect");
        t.measure().await.expect("measure after reconnect");
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn robot_faults_surface_as_their_kind_and_recover() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut r = robot(&c).await;
        let mut q = Q;

        let n = lock_world(&c.world).moves();
        lock_world(&c.world).faults.reject_move_n = n + 1;
        assert_eq!(kind(r.move_joints(&q).await), FaultKind::Rejected);
        move_and_settle(&mut r, &q).await;

        let beyond = [4.0, 0.0, 1.0, 0.0, 0.5, 0.0];
        assert_eq!(kind(r.move_joints(&beyond).await), FaultKind::Rejected);
        assert_eq!(kind(r.move_joints(&q[..5]).await), FaultKind::Rejected);

        c.robot_faults.lock().expect("faults").never_settle = 1;
        q[0] += 0.1;
        r.move_joints(&q).await.expect("move accepted");
        assert_eq!(
            kind(r.wait_settled(Duration::from_millis(200)).await),
            FaultKind::Timeout
        );
        r.stop().await.expect("stop");
        q[0] += 0.1;
        move_and_settle(&mut r, &q).await;

        let n = lock_world(&c.world).moves();
        lock_world(&c.world).faults.estop_after_moves = n + 1;
        q[1] += 0.3;
        r.move_joints(&q).await.expect("move accepted");
        assert_eq!(
            kind(r.wait_settled(Duration::from_secs(2)).await),
            FaultKind::EmergencyStop
        );
        assert_eq!(kind(r.prepare(50.0).await), FaultKind::EmergencyStop);
        lock_world(&c.world).set_estop(false);
        r.prepare(50.0)
            .await
            .expect("power on after the E-stop is released");
        move_and_settle(&mut r, &q).await;

        c.robot_faults
            .lock()
            .expect("faults")
            .disconnect_during_move = 1;
        q[2] -= 0.2;
        r.move_joints(&q).await.expect("move accepted");
        let mut lost = None;
        for _ in 0..100 {
            match r.joints().await {
                Err(e) => {
                    lost = Some(e.kind);
                    break;
                }
                Ok(_) => tokio::time::sleep(Duration::from_millis(10)).await,
            }
        }
        assert_eq!(lost, Some(FaultKind::Disconnected));
        r.reconnect().await.expect("reconnect");
        move_and_settle(&mut r, &q).await;
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn robot_reconnect_after_a_power_loss_leaves_power_off() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut r = robot(&c).await;
        move_and_settle(&mut r, &Q).await;
        lock_world(&c.world).set_power(false).expect("power off");
        r.reconnect().await.expect("reconnect");
        let client = r.client().expect("connected");
        assert!(
            !client.state().await.expect("STATE").power,
            "reconnect powered on"
        );
        let e = client.move_joints([10.0; 6], None).await;
        assert!(
            matches!(e, Err(robotlink::RobotError::PowerOff(_))),
            "{e:?}"
        );
        assert_eq!(kind(r.move_joints(&Q).await), FaultKind::EmergencyStop);
        // Only prepare (the operator's start/resume) switches power on.
        r.prepare(50.0).await.expect("prepare");
        assert!(lock_world(&c.world).power());
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn robot_abort_after_a_dropped_wait_stops_the_arm_within_200_ms() {
    // The campaign engine's abort: the move/WAIT future is dropped, then Robot::stop.
    bounded(async {
        let c = cell(SimWorldConfig {
            move_speed_deg_s: Some(40.0),
            ..SimWorldConfig::default()
        })
        .await;
        let mut r = LinkRobot::new(c.robot_config());
        r.prepare(100.0).await.expect("robot prepares");
        let start = lock_world(&c.world).readback_joints_rad();
        let mut q = start.clone();
        q[0] += 2.5; // 143° ≈ 3.6 s at 40 °/s
        r.move_joints(&q).await.expect("move accepted");
        let w = tokio::time::timeout(
            Duration::from_millis(300),
            r.wait_settled(Duration::from_secs(10)),
        )
        .await;
        assert!(w.is_err(), "WAIT ended early: {w:?}");
        let sent = std::time::Instant::now();
        r.stop().await.expect("stop");
        let latency = sent.elapsed();
        eprintln!("STOP latency through LinkRobot on the simulated cell: {latency:?}");
        assert!(latency < Duration::from_millis(200), "{latency:?}");
        assert!(!lock_world(&c.world).is_moving());
        let q1 = lock_world(&c.world).true_joints_rad();
        tokio::time::sleep(Duration::from_millis(50)).await;
        let q2 = lock_world(&c.world).true_joints_rad();
        assert_eq!(q1, q2, "the arm is frozen");
        assert!(q1[0] > start[0] && q1[0] < q[0] - 1.0, "stopped at {q1:?}");
        // The connection is in step: the next requests succeed.
        let j = r.joints().await.expect("joints");
        assert!((j[0] - q1[0]).abs() < 1e-6);
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stage_settle_time_is_added_to_every_stage_move() {
    bounded(async {
        let c = cell(SimWorldConfig {
            stage_speed_mm_s: Some(1.0e9),
            stage_settle_ms: 60,
            ..SimWorldConfig::default()
        })
        .await;
        let mut s = ZaberStageAdapter::new(c.stage_config().expect("zaber stage"));
        s.prepare().await.expect("stage homes");
        let t = std::time::Instant::now();
        s.move_to(5.0).await.expect("move");
        assert!(
            t.elapsed() >= Duration::from_millis(60),
            "{:?}",
            t.elapsed()
        );
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stage_faults_surface_as_their_kind_and_recover() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut cfg = c.stage_config().expect("zaber stage");
        cfg.move_timeout_ms = 300;
        let mut s = ZaberStageAdapter::new(cfg);
        let sim = c.stage_sim.clone().expect("stage sim");

        assert_eq!(kind(s.move_to(5.0).await), FaultKind::Rejected, "not homed");
        s.prepare().await.expect("home");
        sim.faults().reject = 1;
        assert_eq!(kind(s.move_to(5.0).await), FaultKind::Rejected);
        s.move_to(5.0).await.expect("move after a rejection");
        assert_eq!(kind(s.move_to(500.0).await), FaultKind::Rejected, "range");

        sim.faults().stall = 1;
        assert_eq!(kind(s.move_to(10.0).await), FaultKind::Timeout);
        s.prepare().await.expect("home after a stall");
        s.move_to(10.0).await.expect("move after the stall");

        sim.faults().fault = 1;
        assert_eq!(kind(s.move_to(2.0).await), FaultKind::Device);
        s.prepare().await.expect("prepare clears the fault");
        sim.faults().overshoot = 1;
        assert_eq!(kind(s.move_to(3.0).await), FaultKind::Device);
        let back = s.move_to(4.0).await.expect("move after faults");
        assert!((back - 4.0).abs() < 1e-3);
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stage_limit_and_displacement_warnings_are_device_faults() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut s = ZaberStageAdapter::new(c.stage_config().expect("zaber stage"));
        let sim = c.stage_sim.clone().expect("stage sim");
        s.prepare().await.expect("home");
        sim.faults().limit_hit = 1;
        let e = s.move_to(9.0).await.expect_err("WL");
        assert_eq!(e.kind, FaultKind::Device, "{e}");
        assert!(e.message.contains("WL"), "{e}");
        s.prepare().await.expect("prepare clears and re-homes");
        s.move_to(9.0).await.expect("move after WL");
        sim.faults().displace = 1;
        let e = s.move_to(8.0).await.expect_err("WM");
        assert_eq!(e.kind, FaultKind::Device, "{e}");
        assert!(e.message.contains("WM"), "{e}");
        s.move_to(8.0).await.expect("move after WM was reported");
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stage_scale_comes_from_the_device_and_a_wrong_one_is_refused() {
    bounded(async {
        let c = cell(SimWorldConfig::default()).await;
        let mut cfg = c.stage_config().expect("zaber stage");
        cfg.microsteps_per_mm = None;
        let mut s = ZaberStageAdapter::new(cfg.clone());
        s.prepare().await.expect("scale from the device");
        let back = s.move_to(7.5).await.expect("move");
        assert!((back - 7.5).abs() < 1e-4, "{back}");
        s.close(); // the port is exclusive
        cfg.microsteps_per_mm = Some(1000.0);
        let mut wrong = ZaberStageAdapter::new(cfg);
        let e = wrong.prepare().await.expect_err("mismatch refused");
        assert_eq!(e.kind, FaultKind::Device, "{e}");
        assert!(e.message.contains("disagrees"), "{e}");
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn manual_stage_asks_validates_and_aborts() {
    bounded(async {
        let exact = Arc::new(ScriptedPrompter::exact());
        let mut s = ManualStage::new(exact.clone(), ManualStageConfig::default());
        assert!(s.is_manual());
        s.prepare().await.expect("prepare");
        assert_eq!(s.move_to(10.0).await.expect("accepted"), 10.0);
        let asked = exact.asked();
        assert_eq!(
            asked[0].text,
            "Set the micrometer to 10.000 mm and enter the reading"
        );
        assert_eq!(asked[0].expected_mm, Some(10.0));

        // no context given: none claimed (the robot's state is not known)
        assert_eq!(asked[0].context, PromptContext::default());

        let p = Arc::new(ScriptedPrompter::from_answers([
            Answer::Number(10.3),
            Answer::Confirmed,
            Answer::Number(10.005),
            Answer::Number(0.0),
        ]));
        let mut s = ManualStage::new(p.clone(), ManualStageConfig::default());
        let context = PromptContext {
            step: Some("pose".into()),
            pose: Some(3),
            poses_total: Some(20),
            position: Some(StagePosition::P2),
            robot_stopped: true,
            retry_reason: None,
        };
        s.set_prompt_context(context.clone());
        assert_eq!(s.move_to(10.0).await.expect("third answer"), 10.005);
        let asked = p.asked();
        assert_eq!(asked.len(), 3);
        // every ask of the move carries its context; a re-ask says why
        assert_eq!(asked[0].context, context);
        assert_eq!(
            asked[1].context.retry_reason.as_deref(),
            Some(
                "The reading 10.300 mm, 0.300 mm from the requested 10.000 mm (tolerance 0.020 mm)"
            )
        );
        assert_eq!(
            asked[2].context.retry_reason.as_deref(),
            Some("A number is needed (the micrometer reading in mm)")
        );
        assert_eq!(asked[2].context.pose, Some(3));
        assert_eq!(
            asked[0].context.describe(),
            "pose 3 of 20 · P2 · robot stopped — safe to approach"
        );
        // the context was for that move only
        s.move_to(0.0).await.expect("fourth answer");
        assert_eq!(p.asked()[3].context, PromptContext::default());
        assert!(p.asked()[3]
            .context
            .describe()
            .contains("robot state not known"));
        assert!(
            asked[1]
                .text
                .contains("10.300 mm, 0.300 mm from the requested 10.000 mm (tolerance 0.020 mm)"),
            "{}",
            asked[1].text
        );
        assert!(asked[2].text.starts_with("A number is needed"));

        let p = Arc::new(ScriptedPrompter::from_answers([Answer::Abort]));
        let mut s = ManualStage::new(p, ManualStageConfig::default());
        assert_eq!(
            s.move_to(10.0).await.expect_err("aborted").kind,
            FaultKind::Aborted
        );

        let p = Arc::new(ScriptedPrompter::from_answers(vec![Answer::Number(9.0); 3]));
        let mut s = ManualStage::new(p.clone(), ManualStageConfig::default());
        assert_eq!(
            s.move_to(10.0).await.expect_err("never in tolerance").kind,
            FaultKind::Rejected
        );
        assert_eq!(p.asked().len(), 3);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn manual_stage_reads_the_gauge_and_reprompts_out_of_tolerance() {
    bounded(async {
        let cfg = SimWorldConfig {
            stage_mode: StageMode::Manual,
            gauge: true,
            ..SimWorldConfig::default()
        };
        let c = cell(cfg).await;
        assert!(c.stage_path.is_none());
        let world = c.world.clone();
        let calls = Arc::new(AtomicU32::new(0));
        let n = calls.clone();
        // the technician: first 0.1 mm off, then right
        let p = Arc::new(ScriptedPrompter::from_fn(move |prompt| {
            let target = if prompt.text.contains("10.000") {
                10.0
            } else {
                0.0
            };
            let off = if n.fetch_add(1, Ordering::SeqCst) == 0 {
                0.1
            } else {
                0.0
            };
            lock_world(&world).set_manual_stage_mm(target + off);
            Answer::Confirmed
        }));
        let mut s = ManualStage::with_gauge_port(
            p.clone(),
            c.gauge_path.as_deref().expect("gauge pty"),
            c.gauge_config(),
            ManualStageConfig::default(),
        )
        .expect("gauge opens");
        s.prepare().await.expect("gauge answers");
        let v = s.move_to(10.0).await.expect("gauge in tolerance");
        assert!((v - 10.0).abs() < 1e-3, "gauge reading {v}");
        let asked = p.asked();
        assert_eq!(asked.len(), 2);
        assert_eq!(
            asked[0].text,
            "Move the micrometer to 10.000 mm and confirm"
        );
        assert_eq!(asked[0].expected_mm, None);
        assert!(
            asked[1].text.starts_with("The gauge reads 10.100 mm"),
            "{}",
            asked[1].text
        );
        c.stop().await;
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn channel_prompter_round_trips_and_reports_a_missing_front_end() {
    bounded(async {
        let (prompter, mut rx) = ChannelPrompter::new(4);
        let front = tokio::spawn(async move {
            let mut seqs = Vec::new();
            while let Some(p) = rx.recv().await {
                seqs.push(p.seq);
                let v = p.prompt.expected_mm.expect("a number is asked for");
                p.answer(Answer::Number(v));
            }
            seqs
        });
        let mut s = ManualStage::new(Arc::new(prompter.clone()), ManualStageConfig::default());
        assert_eq!(s.move_to(5.0).await.expect("answered"), 5.0);
        assert_eq!(s.move_to(0.0).await.expect("answered"), 0.0);
        drop(s);
        drop(prompter);
        assert_eq!(front.await.expect("front end"), vec![1, 2]);

        let (prompter, rx) = ChannelPrompter::new(1);
        drop(rx);
        let mut s = ManualStage::new(Arc::new(prompter), ManualStageConfig::default());
        assert_eq!(
            s.move_to(1.0).await.expect_err("nobody listens").kind,
            FaultKind::Disconnected
        );
    })
    .await;
}

#[test]
fn drift_is_linear_plus_decaying_warm_up() {
    let cfg = SimWorldConfig {
        drift_um_per_min: 10.0,
        warmup_um: 50.0,
        warmup_tau_min: 10.0,
        drift_direction: [0.0, 2.0, 0.0],
        ..SimWorldConfig::default()
    };
    let w = cellcal::sim::World::new(
        tx60(),
        tx60(),
        &cfg,
        cellcal::sim::StageSource::Manual { position_mm: 0.0 },
    )
    .expect("world");
    let d0 = w.drift_mm_at(Duration::ZERO);
    assert!((d0 - Vector3::new(0.0, 0.05, 0.0)).norm() < 1e-12);
    let d = w.drift_mm_at(Duration::from_secs(600));
    let expected = 0.1 + 0.05 * (-1.0f64).exp();
    assert!((d - Vector3::new(0.0, expected, 0.0)).norm() < 1e-12);
}

#[test]
fn config_file_documents_the_defaults() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml");
    let text = std::fs::read_to_string(&path).expect("config/cell.sim.toml");
    // the strict parser of every path (`run`, `serve`, `sim`)
    let sim = cellcal::config::parse_sim_config(&text, &path).expect("valid [sim]");
    // every key shows its default, but for those set deliberately: the ball 60 mm above the
    // flange, slightly off the campaign's design tool (the setup step measures it); a tracker
    // frame that is not the robot's (the tracker 2.5 m away, turned); a stage slightly off its
    // nominal axis
    assert_eq!(sim.tool_mm, Some([0.4, -0.3, 60.0]));
    assert_eq!(
        sim.base_translation_mm,
        Some([2434.177, -693.336, -209.929])
    );
    assert_eq!(sim.base_rotation_vector_deg, Some([0.3, -0.2, 155.0]));
    assert_eq!(sim.stage_misalignment_mrad, [1.5, 0.0, -2.5]);
    assert_eq!(sim.tracker_position_mm, [0.0; 3]);
    // `robot_protocol` unset in the file: it follows `[robot_controller] protocol` (robotlink)
    assert_eq!(sim.robot_protocol, Some(RobotProtocol::Robotlink));
    assert_eq!(
        SimWorldConfig {
            robot_protocol: None,
            tool_mm: None,
            base_translation_mm: None,
            base_rotation_vector_deg: None,
            stage_misalignment_mrad: SimWorldConfig::default().stage_misalignment_mrad,
            tracker_position_mm: SimWorldConfig::default().tracker_position_mm,
            ..sim
        },
        SimWorldConfig::default()
    );
}

mod binary {
    use std::io::{BufRead, BufReader};
    use std::path::Path;
    use std::process::{Child, Command, Stdio};
    use std::sync::mpsc;
    use std::time::Duration;

    struct Killed(Child);

    impl Drop for Killed {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }

    fn write_config(dir: &Path, sim: &str) -> std::path::PathBuf {
        let robot = crate::cli::robot();
        let f = dir.join("cell.toml");
        let text = format!(
            "robot = {:?}\n\n[campaign]\nposes = 10\n\n[sim]\n{sim}\n",
            robot.to_string_lossy()
        );
        std::fs::write(&f, text).expect("write config");
        f
    }

    #[test]
    fn cellcal_sim_prints_one_line_per_device_and_serves_emscon() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = write_config(dir.path(), "seed = 7\ngauge = true\n");
        let child = Command::new(env!("CARGO_BIN_EXE_cellcal"))
            .args(["sim", "--config"])
            .arg(&cfg)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn cellcal sim");
        let mut child = Killed(child);
        let stdout = child.0.stdout.take().expect("stdout");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(l) = line else { break };
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        let mut lines = Vec::new();
        for _ in 0..4 {
            lines.push(
                rx.recv_timeout(Duration::from_secs(10))
                    .expect("a device line within 10 s"),
            );
        }
        assert!(lines[0].starts_with("tracker 127.0.0.1:"), "{lines:?}");
        assert!(lines[1].starts_with("robot 127.0.0.1:"), "{lines:?}");
        assert!(lines[2].starts_with("stage /dev/pts/"), "{lines:?}");
        assert!(lines[3].starts_with("gauge /dev/pts/"), "{lines:?}");
        let addr = lines[0]["tracker ".len()..].to_owned();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async {
            let c = emscon::Client::connect(addr.as_str(), emscon::ClientConfig::default())
                .await
                .expect("emscon client connects");
            let st = tokio::time::timeout(Duration::from_secs(5), c.system_status())
                .await
                .expect("in time")
                .expect("system status");
            assert_eq!(st.serial_number, 960_001);
        });
        assert!(
            child.0.try_wait().expect("status").is_none(),
            "still running"
        );
    }

    #[test]
    fn cellcal_sim_names_the_file_and_the_bad_key() {
        let dir = tempfile::tempdir().expect("tempdir");
        let cfg = write_config(dir.path(), "bogus_key = 1\n");
        let out = Command::new(env!("CARGO_BIN_EXE_cellcal"))
            .args(["sim", "--config"])
            .arg(&cfg)
            .stdin(Stdio::null())
            .output()
            .expect("run cellcal sim");
        assert_eq!(out.status.code(), Some(2));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("cell.toml") && err.contains("bogus_key"),
            "{err}"
        );
    }
}
