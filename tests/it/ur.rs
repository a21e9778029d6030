//! Universal Robots over its own interfaces (issue 22): the UR adapter against the simulated UR
//! controller of the cell (Dashboard, RTDE, URScript over loopback TCP), and a full campaign on
//! the simulated UR5 (`config/cell.sim-ur5.toml`).

use std::path::Path;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Duration;

use cellcal::cell::{FaultKind, Robot, UrRobot, UrRobotConfig};
use cellcal::config::{parse_cell_config, RobotProtocol};
use cellcal::model::load_robot;
use cellcal::plan::MotionLimits;
use cellcal::sim::start_cell;

/// A loopback address of its own per test (the simulated controller takes the standard ports).
fn loopback() -> String {
    static N: AtomicU8 = AtomicU8::new(1);
    let pid = std::process::id();
    format!(
        "127.{}.{}.{}",
        (pid >> 8) % 250 + 1,
        pid % 250 + 1,
        N.fetch_add(1, Ordering::Relaxed)
    )
}

fn ur5_text(host: &str) -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::read_to_string(root.join("config/cell.sim-ur5.toml"))
        .expect("cell.sim-ur5.toml")
        .replace("ur_host = \"127.0.0.1\"", &format!("ur_host = \"{host}\""))
}

fn write_ur5(dir: &Path, host: &str) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::create_dir_all(dir.join("robots")).expect("mkdir");
    std::fs::copy(
        root.join("config/robots/ur5.toml"),
        dir.join("robots/ur5.toml"),
    )
    .expect("copy robot");
    let p = dir.join("cell.toml");
    std::fs::write(&p, ur5_text(host)).expect("write");
    p
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ur_adapter_checks_without_script_powers_on_after_prepare_moves_stops_and_maps_a_protective_stop(
) {
    let dir = tempfile::tempdir().expect("tempdir");
    let host = loopback();
    let path = write_ur5(dir.path(), &host);
    let cfg = parse_cell_config(&ur5_text(&host), &path).expect("config");
    assert_eq!(cfg.robot_controller.protocol, RobotProtocol::Ur);
    let nominal = load_robot(&dir.path().join("robots/ur5.toml")).expect("robot");
    let sim_cfg = cfg.sim.clone().expect("[sim]");
    assert_eq!(sim_cfg.robot_protocol, Some(RobotProtocol::Ur));
    let cell = start_cell(nominal.clone(), sim_cfg, std::future::pending())
        .await
        .expect("sim cell");
    let ur_sim = cell.ur.as_ref().expect("a simulated UR controller");
    let mut ur =
        UrRobotConfig::from_section(&cfg.robot_controller, MotionLimits::of(&nominal, 100.0));
    cell.ur_robot_config(&cfg.robot_controller, &mut ur)
        .expect("UR config");
    assert_eq!(ur.dashboard_port, 29999);
    assert_eq!(ur.rtde_port, 30004);
    assert_eq!(ur.script_port, 30002);
    let mut robot = UrRobot::new(ur);

    // without arming: a check reads modes and joints, sends no script, powers nothing
    let line = robot.check().await.expect("check");
    assert!(line.contains("robot mode POWER_OFF"), "{line}");
    assert!(line.contains("safety mode NORMAL"), "{line}");
    assert_eq!(ur_sim.controller.script_counts().0, 0, "no program ran");
    assert_eq!(ur_sim.controller.script_counts().1, 0, "no program sent");
    assert_eq!(
        ur_sim.controller.snapshot().robot_mode,
        ur::RobotMode::PowerOff
    );

    // a move before prepare is refused without sending anything
    let q0 = robot.joints().await.expect("joints");
    let err = robot.move_joints(&q0).await.expect_err("not prepared");
    assert_eq!(err.kind, FaultKind::NotReady);
    assert_eq!(ur_sim.controller.script_counts(), (0, 0, None));

    // prepare: power on + brake release through the Dashboard, RUNNING on RTDE
    robot.prepare(50.0).await.expect("prepare");
    assert_eq!(
        ur_sim.controller.snapshot().robot_mode,
        ur::RobotMode::Running
    );

    let mut target = q0.clone();
    target[0] += 0.2;
    target[5] -= 0.3;
    robot.move_joints(&target).await.expect("movej");
    let settled = robot
        .wait_settled(Duration::from_secs(10))
        .await
        .expect("settled");
    for (a, b) in settled.iter().zip(&target) {
        assert!((a - b).abs() < 1e-6, "{settled:?} vs {target:?}");
    }
    assert_eq!(
        ur_sim.controller.script_counts().0,
        1,
        "one movej program ran"
    );
    robot.stop().await.expect("stop");

    // a protective stop during a move ends the wait as an operator fault; never released
    target[0] -= 0.4;
    robot.move_joints(&target).await.expect("movej");
    ur_sim.controller.protective_stop();
    let err = robot
        .wait_settled(Duration::from_secs(10))
        .await
        .expect_err("protective stop");
    assert_eq!(err.kind, FaultKind::EmergencyStop, "{err}");
    assert!(err.message.contains("protective stop"), "{err}");
    let err = robot.move_joints(&target).await.expect_err("still stopped");
    assert_eq!(err.kind, FaultKind::EmergencyStop);
    assert_eq!(
        ur_sim.controller.snapshot().safety_mode,
        ur::SafetyMode::ProtectiveStop,
        "cellcal never unlocks a protective stop"
    );
    cell.stop().await;
}

/// README command 1 with `config/cell.sim-ur5.toml`: a full campaign over Dashboard, RTDE and
/// URScript identifies the simulated UR5 (verification error down at least 10×).
#[test]
fn ur5_campaign_on_the_simulated_ur_controller_identifies_the_arm() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = write_ur5(dir.path(), &loopback());
    let json = dir.path().join("result.json");
    let out = assert_cmd::Command::cargo_bin("cellcal")
        .expect("binary")
        .args(["run", "--config"])
        .arg(&cfg)
        .args(["--arm", "--store"])
        .arg(dir.path().join("campaign.db"))
        .arg("--json")
        .arg(&json)
        .timeout(Duration::from_secs(600))
        .output()
        .expect("run");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("robot Universal Robots controller"),
        "the campaign drove the UR controller: {stderr}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("parse");
    let before = v["metrics"]["verify"]["before"]["position_mean_mm"]
        .as_f64()
        .unwrap_or_else(|| panic!("verify before in {}", v["metrics"]));
    let after = v["metrics"]["verify"]["after"]["position_mean_mm"]
        .as_f64()
        .expect("verify after");
    assert!(after * 10.0 <= before, "verify mean {before} -> {after} mm");
}
