//! The public `ur_rtde` client (PyPI `ur-rtde`, tests/python/ur_rtde_smoke.py) against the
//! simulated controller on the standard ports of a 127.0.0.x address: DashboardClient powers
//! on, releases the brakes, reads the robot mode and safety status; RTDEReceiveInterface reads
//! getActualQ/getRobotMode/getSafetyMode while a movej sent by this crate's ScriptClient runs;
//! DashboardClient stops the program. When ur_rtde is missing the test says so loudly and
//! passes, unless CELLCAL_REQUIRE_UR_RTDE=1 (CI sets it).

use std::net::{IpAddr, Ipv4Addr};
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::process::Command;
use ur::{ServerConfig, SimController, TrapezoidMotion, UrServers};

use crate::common::{fast, max_abs_diff, script, HOME, TIMEOUT};

const REQUIRE: &str = "CELLCAL_REQUIRE_UR_RTDE";
/// The script's exit code when it cannot import ur_rtde.
const NOT_INSTALLED: i32 = 77;

/// Standard ports on the first free 127.0.0.x of a few (several controllers may run).
async fn serve_on_loopback(c: &SimController) -> (IpAddr, UrServers) {
    let base = 20 + (std::process::id() % 200) as u8;
    let mut last = None;
    for k in 0..30u8 {
        let host = IpAddr::V4(Ipv4Addr::new(127, 0, 0, base.wrapping_add(k).max(2)));
        match UrServers::start(c.clone(), &ServerConfig::standard(host)).await {
            Ok(s) => return (host, s),
            Err(e) => last = Some(e),
        }
    }
    panic!("no free 127.0.0.x for the standard UR ports: {last:?}");
}

fn skip_or_fail(stderr: &str) {
    assert!(
        std::env::var(REQUIRE).as_deref() != Ok("1"),
        "{REQUIRE}=1 but python3 cannot import ur_rtde (pip install ur-rtde): {stderr}"
    );
    eprintln!(
        "\n!!!!!!!! SKIPPED ur_rtde test: python3 cannot import ur_rtde \
         (pip install ur-rtde; set {REQUIRE}=1 to make this a failure) !!!!!!!!\n"
    );
}

fn json(line: &str) -> serde_json::Value {
    serde_json::from_str(line).unwrap_or_else(|e| panic!("not JSON ({e}): {line:?}"))
}

fn q_of(v: &serde_json::Value) -> [f64; 6] {
    let a = v.as_array().expect("joint list");
    assert_eq!(a.len(), 6, "{v}");
    std::array::from_fn(|i| a[i].as_f64().expect("number"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ur_rtde_reads_the_simulated_controller_while_a_movej_runs() {
    let c = SimController::new(fast(), Box::new(TrapezoidMotion::new(HOME)));
    let (host, servers) = serve_on_loopback(&c).await;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/ur_rtde_smoke.py");
    let mut child = Command::new("python3")
        .arg(path)
        .arg(host.to_string())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("python3 runs (install python3)");
    let mut stdin = child.stdin.take().unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut stderr = child.stderr.take().unwrap();
    let ready = tokio::time::timeout(Duration::from_secs(30), out.next_line())
        .await
        .expect("ur_rtde script ready within 30 s")
        .unwrap();
    let Some(ready) = ready else {
        let status = child.wait().await.unwrap();
        let mut err = String::new();
        stderr.read_to_string(&mut err).await.unwrap();
        if status.code() == Some(NOT_INSTALLED) {
            skip_or_fail(&err);
            return;
        }
        panic!("ur_rtde script ended early: {status}\nstderr: {err}");
    };
    let ready = json(&ready);
    eprintln!("ur_rtde ready: {ready}");
    assert_eq!(ready["remote"], true);
    assert_eq!(
        ready["modes"],
        serde_json::json!([
            "Robotmode: POWER_OFF",
            "Robotmode: IDLE",
            "Robotmode: RUNNING"
        ])
    );
    assert_eq!(ready["safetystatus"], "Safetystatus: NORMAL");
    assert_eq!(q_of(&ready["q"]), HOME);
    assert_eq!(ready["robot_mode"], 7);
    assert_eq!(ready["safety_mode"], 1);

    // a slow move ur_rtde watches, then stops through the Dashboard
    let target = [1.5, -1.0, 1.0, -1.0, -1.0, 1.5];
    script(&servers).movej(&target, 1.0, 0.5).await.unwrap();
    stdin.write_all(b"go\n").await.unwrap();
    let done = tokio::time::timeout(Duration::from_secs(30), out.next_line())
        .await
        .expect("ur_rtde script done within 30 s")
        .unwrap();
    let status = tokio::time::timeout(TIMEOUT, child.wait())
        .await
        .unwrap()
        .unwrap();
    let mut err = String::new();
    stderr.read_to_string(&mut err).await.unwrap();
    let done = json(&done.unwrap_or_else(|| panic!("no result; stderr: {err}")));
    assert!(status.success(), "{status}; stderr: {err}");
    let samples: Vec<[f64; 6]> = done["samples"]
        .as_array()
        .unwrap()
        .iter()
        .map(q_of)
        .collect();
    assert!(samples.len() >= 5, "{done}");
    // joint 1 runs from 0 toward 1.5 and never backwards while ur_rtde watches
    assert!(
        samples.windows(2).all(|w| w[1][0] >= w[0][0]),
        "{samples:?}"
    );
    let last = samples.last().unwrap();
    assert!(last[0] > 0.02 && last[0] < 1.5, "{last:?}");
    assert!(
        done["runtime_states"]
            .as_array()
            .unwrap()
            .contains(&2.into()),
        "never PLAYING: {done}"
    );
    // stopped by the Dashboard short of the target, at rest, program ended
    let after: Vec<[f64; 6]> = done["after_stop"]
        .as_array()
        .unwrap()
        .iter()
        .map(q_of)
        .collect();
    assert_eq!(after[0], after[1]);
    assert!(max_abs_diff(&after[1], &target) > 0.3, "{after:?}");
    assert_eq!(done["runtime_state_after"], 1);
    assert_eq!(done["robot_mode"], 7);
    assert_eq!(done["safety_mode"], 1);
    assert_eq!(done["robotmode"], "Robotmode: RUNNING");
    // (JSON text may round the last bit)
    assert!(max_abs_diff(&c.snapshot().joints.q, &after[1]) < 1e-12);
    drop(servers);
}
