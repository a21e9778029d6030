//! Every device setting of the cell configuration reaches its driver: parsed once from the TOML
//! text, handed to the adapters by the one mapping (`with_section`) the session uses, and seen
//! on the wire by the real simulated devices (emScon server, robotlink peer, Zaber pty).

use std::future::Future;
use std::path::Path;
use std::time::{Duration, Instant};

use cellcal::cell::{
    EmsconTracker, FaultKind, LinkRobot, LinkRobotConfig, Robot, Stage, Tracker, ZaberStageAdapter,
    ZaberStageAdapterConfig,
};
use cellcal::config::{parse_cell_config, CellConfig};
use cellcal::sim::{start_cell, SimWorldConfig};
use zaber::pty::spawn_stage_pty;
use zaber::sim::{StageSim, StageSimConfig};

use crate::common::tx60;

/// Every test body runs under this bound.
async fn bounded<T>(f: impl Future<Output = T>) -> T {
    tokio::time::timeout(Duration::from_secs(20), f)
        .await
        .expect("test finished within 20 s")
}

fn cell_config(text: &str) -> CellConfig {
    parse_cell_config(text, Path::new("cell.toml")).expect("valid configuration")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_configured_emscon_command_timeout_makes_a_silent_tracker_fail_in_that_time() {
    bounded(async {
        let cell = start_cell(tx60(), SimWorldConfig::default(), std::future::pending())
            .await
            .expect("simulated cell");
        // the simulated cell's own default is 2000 ms
        let cfg = cell_config("[tracker]\ncommand_timeout_ms = 300\n");
        let mut t = EmsconTracker::new(cell.tracker_config().with_section(&cfg.tracker));
        assert_eq!(t.config().command_timeout_ms, 300);
        cell.tracker_faults
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .no_reply = 1;
        let start = Instant::now();
        let e = t.prepare().await.expect_err("a silent tracker");
        let took = start.elapsed();
        assert_eq!(e.kind, FaultKind::Timeout, "{e}");
        assert!(
            took >= Duration::from_millis(300) && took < Duration::from_millis(1500),
            "failed after {took:?}, not after the configured 300 ms"
        );
    })
    .await;
}

/// `[sim] measure_ms` is the measuring time of a simulated tracker whose `[tracker]` leaves
/// `measure_ms` unset (it reached no campaign before: `[tracker]`'s default of 1000 ms always
/// won); a given `[tracker] measure_ms` wins; the estimate reads the same time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sim_measure_ms_reaches_a_simulated_tracker_unless_the_tracker_section_sets_one() {
    bounded(async {
        let cfg = cell_config("[sim]\nmeasure_ms = 40\n");
        assert_eq!(cfg.tracker.measure_ms, None);
        assert_eq!(cfg.tracker_measure_ms(), 40);
        let sim = cfg.sim.clone().expect("[sim]");
        let cell = start_cell(tx60(), sim, std::future::pending())
            .await
            .expect("simulated cell");
        let t = EmsconTracker::new(cell.tracker_config().with_section(&cfg.tracker));
        assert_eq!(t.config().meas_time_ms, 40);
        let times = cellcal::campaign::estimate::cell_times(&cfg, &tx60());
        assert!(
            (times.reading_s - 0.040).abs() < 0.01,
            "{}",
            times.reading_s
        );
        let given = cell_config("[tracker]\nmeasure_ms = 7\n[sim]\nmeasure_ms = 40\n");
        assert_eq!(given.tracker_measure_ms(), 7);
        let t = EmsconTracker::new(cell.tracker_config().with_section(&given.tracker));
        assert_eq!(t.config().meas_time_ms, 7);
        // a real tracker without the key: the AT960's 1000 ms
        let real = cell_config("[tracker]\nmode = \"real\"\n");
        assert_eq!(real.tracker_measure_ms(), cellcal::config::REAL_MEASURE_MS);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_configured_beam_break_code_makes_that_status_a_beam_break() {
    bounded(async {
        let sim: SimWorldConfig = SimWorldConfig {
            faults: cellcal::sim::SimFaults {
                tracker: cellcal::sim::config::TrackerFaults {
                    beam_break_status: 10050,
                    ..Default::default()
                },
                ..Default::default()
            },
            ..SimWorldConfig::default()
        };
        let cell = start_cell(tx60(), sim, std::future::pending())
            .await
            .expect("simulated cell");
        let mut kinds = Vec::new();
        for text in ["", "[tracker]\nbeam_break_code = 10050\n"] {
            let cfg = cell_config(text);
            let mut t = EmsconTracker::new(cell.tracker_config().with_section(&cfg.tracker));
            t.prepare().await.expect("tracker prepares");
            cell.tracker_faults
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .beam_break_before_measure = 1;
            kinds.push(t.measure().await.expect_err("the beam breaks").kind);
            t.relock(None).await.expect("relocks");
        }
        // unknown to the driver: a device fault (the campaign pauses); configured: a beam
        // break (the campaign re-locks and measures again)
        assert_eq!(kinds, [FaultKind::Device, FaultKind::BeamBroken]);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_configured_robot_request_timeout_reaches_the_robotlink_client() {
    bounded(async {
        // a controller that accepts the connection and never answers
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind");
        let addr = listener.local_addr().expect("addr");
        let silent = tokio::spawn(async move {
            let mut held = Vec::new();
            while let Ok((s, _)) = listener.accept().await {
                held.push(s);
            }
        });
        // the real controller's default is 5000 ms
        let cfg = cell_config("[robot_controller]\nmode = \"real\"\nrequest_timeout_ms = 300\n");
        let device = LinkRobotConfig {
            address: addr.to_string(),
            secret: Some(robotlink::SharedSecret::generate().expect("secret")),
            ..LinkRobotConfig::default()
        };
        let mut r = LinkRobot::new(device.with_section(&cfg.robot_controller));
        let start = Instant::now();
        let e = r.prepare(10.0).await.expect_err("a silent controller");
        let took = start.elapsed();
        assert_eq!(e.kind, FaultKind::Timeout, "{e}");
        assert!(
            took >= Duration::from_millis(300) && took < Duration::from_millis(2500),
            "failed after {took:?}, not after the configured 300 ms"
        );
        silent.abort();
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_configured_zaber_device_and_axis_go_on_the_wire() {
    bounded(async {
        // a stage at device 2, axis 2 of its chain
        let sim = StageSim::new(StageSimConfig {
            device: 2,
            axis: 2,
            ..StageSimConfig::default()
        });
        let pty = spawn_stage_pty(sim.clone()).expect("stage pty");
        let adapter = |text: &str| {
            let cfg = cell_config(&format!(
                "[stage]\nmode = \"real\"\nreply_timeout_ms = 200\npoll_interval_ms = 1\n{text}"
            ));
            let port = ZaberStageAdapterConfig {
                port: pty.path(),
                ..ZaberStageAdapterConfig::default()
            };
            ZaberStageAdapter::new(port.with_section(&cfg.stage))
        };
        // the default address (1, 1): nobody answers within the configured reply timeout
        let start = Instant::now();
        let e = adapter("").prepare().await.expect_err("no device 1");
        assert_eq!(e.kind, FaultKind::Timeout, "{e}");
        assert!(start.elapsed() < Duration::from_millis(1500), "{e}");
        // device 2, axis 1: the device answers, the axis does not exist
        let e = adapter("device_address = 2\n")
            .prepare()
            .await
            .expect_err("no axis 1");
        assert_eq!(e.kind, FaultKind::Rejected, "{e}");
        // device 2, axis 2: prepared, homed and moved
        let mut s = adapter("device_address = 2\naxis_number = 2\n");
        s.prepare().await.expect("the stage at device 2, axis 2");
        let at = s.move_to(5.0).await.expect("moves");
        assert!((at - 5.0).abs() < 0.02, "{at}");
        assert!(sim.position_steps() > 0);
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_session_builds_its_devices_from_the_configured_settings() {
    bounded(async {
        let dir = tempfile::tempdir().expect("tempdir");
        let text = crate::campaign::config_text("", "", "")
            .replace("poses = 300", "poses = 40")
            .replace("ident = 100", "ident = 20")
            .replace(
                "[tracker]\n",
                "[tracker]\ncommand_timeout_ms = 300\nbeam_break_code = 10050\n",
            )
            .replace(
                "[stage]\n",
                "[stage]\ndevice_address = 3\naxis_number = 1\n",
            );
        let mut session = crate::campaign::sim_session(dir.path(), &text).await;
        let sim = session.sim.as_ref().expect("simulated cell");
        // one stage: the simulated Zaber device sits at the configured address, and the
        // session's adapter talks to it there
        assert_eq!(sim.stage_sim.as_ref().expect("zaber").config().device, 3);
        session
            .devices
            .stage
            .prepare()
            .await
            .expect("the stage at device 3");
        // the configured emScon timeout, not the simulated cell's 2000 ms
        sim.tracker_faults
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .no_reply = 1;
        let start = Instant::now();
        let e = session
            .devices
            .tracker
            .prepare()
            .await
            .expect_err("a silent tracker");
        assert_eq!(e.kind, FaultKind::Timeout, "{e}");
        assert!(start.elapsed() < Duration::from_millis(1500), "{e}");
        session.sim.take().expect("sim").stop().await;
    })
    .await;
}

#[test]
fn every_device_key_reaches_the_driver_configuration() {
    let cfg = cell_config(
        "[tracker]\nmode = \"real\"\naddress = \"10.0.0.7:700\"\nmeasure_ms = 700\nreflector_id = 4\n\
         use_adm = false\nbeam_break_codes = [1, 2]\nbeam_break_code = 3\n\
         search_distance_mm = 4100.0\nconnect_timeout_ms = 11\ncommand_timeout_ms = 12\n\
         initialize_timeout_ms = 13\nsearch_timeout_ms = 14\nmeasure_margin_ms = 15\n\
         [robot_controller]\nmode = \"real\"\nconnect_timeout_ms = 21\nrequest_timeout_ms = 22\n\
         wait_margin_ms = 23\n\
         [stage]\nmode = \"real\"\nserial_path = \"/dev/ttyS9\"\nmicrosteps_per_mm = 1000.0\n\
         range_mm = [1.0, 30.0]\ntolerance_mm = 0.03\ndevice_address = 5\naxis_number = 2\n\
         baud = 9600\nhome_on_prepare = false\nreply_timeout_ms = 31\npoll_interval_ms = 32\n\
         move_timeout_ms = 33\nhome_timeout_ms = 34\n",
    );
    let ms = Duration::from_millis;
    let t = cellcal::cell::EmsconTrackerConfig {
        address: cfg.tracker.address.clone(),
        ..Default::default()
    }
    .with_section(&cfg.tracker);
    let c = t.client_config();
    assert_eq!(
        (
            t.address.as_str(),
            t.meas_time_ms,
            t.reflector_id,
            t.use_adm
        ),
        ("10.0.0.7:700", 700, Some(4), false)
    );
    assert_eq!(t.search_distance_mm, 4100.0);
    assert_eq!(
        (c.beam_break_codes.as_slice(), c.beam_break_code),
        (&[1, 2][..], Some(3))
    );
    assert_eq!(
        [
            c.connect_timeout,
            c.command_timeout,
            c.initialize_timeout,
            c.search_timeout,
            c.measure_margin
        ],
        [ms(11), ms(12), ms(13), ms(14), ms(15)]
    );
    let r = LinkRobotConfig::default()
        .with_section(&cfg.robot_controller)
        .client_config();
    assert_eq!(
        [r.connect_timeout, r.request_timeout, r.wait_margin],
        [ms(21), ms(22), ms(23)]
    );
    let s = ZaberStageAdapterConfig {
        port: cfg.stage.serial_path.clone(),
        ..ZaberStageAdapterConfig::default()
    }
    .with_section(&cfg.stage);
    assert_eq!((s.port.as_str(), s.home_on_prepare), ("/dev/ttyS9", false));
    let d = s.stage_config();
    assert_eq!(
        (d.device, d.axis, d.baud, d.microsteps_per_mm),
        (5, 2, 9600, Some(1000.0))
    );
    assert_eq!((d.min_mm, d.max_mm, d.tolerance_mm), (1.0, 30.0, 0.03));
    assert_eq!(
        [
            d.reply_timeout,
            d.poll_interval,
            d.move_timeout,
            d.home_timeout
        ],
        [ms(31), ms(32), ms(33), ms(34)]
    );
    // unset keys keep the device's defaults (the real ones here)
    let t = cellcal::cell::EmsconTrackerConfig::default()
        .with_section(&cell_config("[tracker]\nmode = \"real\"\n").tracker);
    assert_eq!(
        (
            t.command_timeout_ms,
            t.initialize_timeout_ms,
            t.beam_break_codes
        ),
        (30_000, 90_000, None)
    );
}
