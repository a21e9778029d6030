//! The crate's clients against its simulated controller over loopback TCP.

use std::time::Duration;

use ur::client::{DashboardClient, RtdeClient, STATE_RECIPE};
use ur::dashboard;
use ur::{RobotMode, RuntimeState, SafetyMode, UrError};

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboard_powers_on_releases_brakes_and_reports_modes() {
    let (_c, s) = start(fast()).await;
    let mut d = DashboardClient::connect(s.dashboard, TIMEOUT)
        .await
        .unwrap();
    assert_eq!(d.banner(), dashboard::BANNER);
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOff);
    assert!(d.is_in_remote_control().await.unwrap());
    d.power_on().await.unwrap();
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOn);
    wait_mode(&mut d, RobotMode::Idle).await;
    d.brake_release().await.unwrap();
    wait_mode(&mut d, RobotMode::Running).await;
    assert_eq!(d.safety_status().await.unwrap(), SafetyMode::Normal);
    assert_eq!(d.safety_mode().await.unwrap(), SafetyMode::Normal);
    assert_eq!(
        d.raw("hello there").await.unwrap(),
        "could not understand: 'hello there'"
    );
    assert!(d
        .raw("PolyscopeVersion")
        .await
        .unwrap()
        .starts_with("URSoftware 5."));
    d.close_popup().await.unwrap();
    d.close_safety_popup().await.unwrap();
    d.stop().await.unwrap();
    d.power_off().await.unwrap();
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOff);
    // brake release while powered off powers on on the fly, then releases
    d.brake_release().await.unwrap();
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOn);
    wait_mode(&mut d, RobotMode::Running).await;
    d.quit().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn local_control_refuses_remote_commands_and_scripts() {
    let (c, s) = start(fast()).await;
    let mut d = make_running(&s).await;
    c.set_remote_control(false);
    assert!(!d.is_in_remote_control().await.unwrap());
    match d.power_off().await {
        Err(UrError::Refused { reply, .. }) => assert_eq!(reply, dashboard::LOCAL_CONTROL),
        other => panic!("{other:?}"),
    }
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::Running);
    script(&s).movej(&[0.2; 6], 1.0, 1.0).await.unwrap();
    let mut r = rtde(&s).await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    let st = r.latest_state().await.unwrap();
    assert_eq!(st.actual_q, HOME, "a script ran in local control");
    let (run, refused, why) = c.script_counts();
    assert_eq!((run, refused), (0, 1));
    assert!(why.unwrap().contains("local control"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_streams_the_state_while_a_movej_runs_to_its_target() {
    let (_c, s) = start(fast()).await;
    let _d = make_running(&s).await;
    let mut r = RtdeClient::connect(s.rtde, TIMEOUT).await.unwrap();
    let v = r.controller_version().await.unwrap();
    assert_eq!((v.major, v.minor), (5, 11));
    let recipe = r.setup_outputs(&STATE_RECIPE, 125.0).await.unwrap();
    assert_eq!(recipe.id, 1);
    r.start().await.unwrap();
    let st = r.latest_state().await.unwrap();
    assert_eq!(st.actual_q, HOME);
    assert_eq!(st.robot_mode, RobotMode::Running);
    assert_eq!(st.safety_mode, SafetyMode::Normal);
    assert_eq!(st.runtime_state, RuntimeState::Stopped);
    let target = [0.3, -1.2, 1.2, -1.3, -1.6, 0.4];
    script(&s).movej(&target, 3.0, 2.0).await.unwrap();
    let seen = follow(&mut r, |st| {
        !st.program_running() && max_abs_diff(&st.actual_q, &target) < 1e-12
    })
    .await
    .unwrap();
    assert!(
        seen.iter().any(|st| st.program_running()
            && st.runtime_state == RuntimeState::Playing
            && st.actual_qd.iter().any(|v| v.abs() > 0.0)),
        "never saw the program run with the joints moving"
    );
    let last = seen.last().unwrap();
    assert_eq!(last.actual_qd, [0.0; 6]);
    // the controller timestamps increase
    assert!(seen.windows(2).all(|w| w[1].timestamp > w[0].timestamp));
    // the leading joint never exceeds v = 2 rad/s
    let vmax = seen
        .iter()
        .flat_map(|st| st.actual_qd)
        .fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(vmax <= 2.0 + 1e-9 && vmax > 0.5, "peak speed {vmax}");
    r.pause().await.unwrap();
    r.start().await.unwrap();
    assert_eq!(r.latest_state().await.unwrap().actual_q, target);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_refuses_unknown_variables_bad_rates_and_other_versions() {
    let (_c, s) = start(fast()).await;
    let mut r = RtdeClient::connect(s.rtde, TIMEOUT).await.unwrap();
    match r
        .setup_outputs(&["actual_q", "no_such_variable"], 125.0)
        .await
    {
        Err(UrError::Refused { reply, .. }) => {
            assert_eq!(reply, "no_such_variable: NOT_FOUND")
        }
        other => panic!("{other:?}"),
    }
    assert!(r.setup_outputs(&["actual_q"], 0.0).await.is_err());
    assert!(r.setup_outputs(&["actual_q"], f64::NAN).await.is_err());
    // above the controller's 500 Hz: recipe set up, start refused, an error message sent
    r.setup_outputs(&["actual_q"], 1000.0).await.unwrap();
    assert!(matches!(r.start().await, Err(UrError::Refused { .. })));
    let msgs = r.take_messages();
    assert!(msgs.iter().any(|m| m.message.contains("1000")), "{msgs:?}");
    // protocol version 1 is not spoken by the simulator (the driver asks for 2)
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut raw = tokio::net::TcpStream::connect(s.rtde).await.unwrap();
    raw.write_all(&[0, 5, b'V', 0, 1]).await.unwrap();
    let mut reply = [0u8; 4];
    raw.read_exact(&mut reply).await.unwrap();
    assert_eq!(reply, [0, 4, b'V', 0]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stopj_and_dashboard_stop_end_a_move_short_of_its_target() {
    let (_c, s) = start(fast()).await;
    let mut d = make_running(&s).await;
    let mut r = rtde(&s).await;
    let far = [2.5, -1.5, 1.5, -1.5, -1.5, 0.0];
    let back = [-2.5, -1.5, 1.5, -1.5, -1.5, 0.0];
    for stop_with_dashboard in [false, true] {
        let from = r.latest_state().await.unwrap().actual_q;
        let target = if stop_with_dashboard { back } else { far };
        script(&s).movej(&target, 2.0, 0.5).await.unwrap();
        follow(&mut r, |st| st.actual_qd[0].abs() > 0.3)
            .await
            .unwrap();
        if stop_with_dashboard {
            d.stop().await.unwrap();
        } else {
            script(&s).stopj(4.0).await.unwrap();
        }
        let seen = follow(&mut r, |st| {
            !st.program_running() && st.actual_qd == [0.0; 6]
        })
        .await
        .unwrap();
        let stopped = seen.last().unwrap().actual_q;
        assert!(max_abs_diff(&stopped, &target) > 0.5, "reached {stopped:?}");
        assert!(max_abs_diff(&stopped, &from) > 0.02, "did not move");
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert_eq!(r.latest_state().await.unwrap().actual_q, stopped);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protective_stop_halts_and_is_released_only_after_the_delay() {
    let (c, s) = start(fast()).await;
    let mut d = make_running(&s).await;
    let mut r = rtde(&s).await;
    script(&s).movej(&[1.0; 6], 2.0, 0.5).await.unwrap();
    follow(&mut r, |st| st.actual_qd[1].abs() > 0.3)
        .await
        .unwrap();
    c.protective_stop();
    let st = follow(&mut r, |st| st.safety_mode == SafetyMode::ProtectiveStop)
        .await
        .unwrap()
        .pop()
        .unwrap();
    assert!(!st.program_running());
    assert_eq!(st.actual_qd, [0.0; 6]);
    assert_eq!(d.safety_status().await.unwrap(), SafetyMode::ProtectiveStop);
    // a program sent now does not run
    script(&s).movej(&HOME, 1.0, 1.0).await.unwrap();
    match d.unlock_protective_stop().await {
        Err(UrError::Refused { reply, .. }) => assert_eq!(reply, dashboard::CANNOT_UNLOCK_YET),
        other => panic!("{other:?}"),
    }
    tokio::time::sleep(Duration::from_millis(350)).await;
    assert_eq!(r.latest_state().await.unwrap().actual_q, st.actual_q);
    d.unlock_protective_stop().await.unwrap();
    assert_eq!(d.safety_status().await.unwrap(), SafetyMode::Normal);
    let (run, refused, _) = c.script_counts();
    assert_eq!((run, refused), (1, 1));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn emergency_stop_powers_off_until_power_on_and_brake_release() {
    let (c, s) = start(fast()).await;
    let mut d = make_running(&s).await;
    let mut r = rtde(&s).await;
    c.emergency_stop(true);
    let st = follow(&mut r, |st| {
        st.safety_mode == SafetyMode::RobotEmergencyStop
    })
    .await
    .unwrap()
    .pop()
    .unwrap();
    assert_eq!(st.robot_mode, RobotMode::PowerOff);
    // power on and brake release do nothing while the button is pressed
    d.power_on().await.unwrap();
    d.brake_release().await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOff);
    c.emergency_stop(false);
    assert_eq!(d.safety_status().await.unwrap(), SafetyMode::Normal);
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOff);
    d.power_on().await.unwrap();
    wait_mode(&mut d, RobotMode::Idle).await;
    d.brake_release().await.unwrap();
    wait_mode(&mut d, RobotMode::Running).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_network_drop_closes_every_client_connection() {
    let (c, s) = start(fast()).await;
    let mut d = DashboardClient::connect(s.dashboard, TIMEOUT)
        .await
        .unwrap();
    let mut r = rtde(&s).await;
    r.next_data().await.unwrap();
    c.disconnect_clients();
    let rt = async {
        loop {
            if let Err(e) = r.next_data().await {
                return e;
            }
        }
    };
    let e = tokio::time::timeout(Duration::from_secs(2), rt)
        .await
        .unwrap();
    assert!(
        matches!(e, UrError::Closed(_) | UrError::Io { .. }),
        "{e:?}"
    );
    assert!(d.robot_mode().await.is_err());
    // new connections are served again
    let mut d = DashboardClient::connect(s.dashboard, TIMEOUT)
        .await
        .unwrap();
    assert_eq!(d.robot_mode().await.unwrap(), RobotMode::PowerOff);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn programs_that_do_not_compile_or_find_the_arm_not_running_do_not_run() {
    let (c, s) = start(fast()).await;
    // powered off
    script(&s).movej(&[0.5; 6], 1.0, 1.0).await.unwrap();
    let _d = make_running(&s).await;
    // one unknown statement: nothing runs
    script(&s)
        .send("def p():\n  movej([0.5,0.5,0.5,0.5,0.5,0.5])\n  set_digital_out(0, True)\nend\n")
        .await
        .unwrap();
    // a block cut by the end of the connection
    script(&s)
        .send("def p():\n  movej([0.5,0.5,0.5,0.5,0.5,0.5])")
        .await
        .unwrap();
    let mut r = rtde(&s).await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(r.latest_state().await.unwrap().actual_q, HOME);
    let (run, refused, why) = c.script_counts();
    assert_eq!((run, refused), (0, 2), "{why:?}");
    assert!(why.unwrap().contains("set_digital_out"));
}

/// A [`TrapezoidMotion`] whose fault model raises `fault` 0.15 s into the first move.
struct Collides {
    inner: ur::TrapezoidMotion,
    fault: ur::MotionFault,
    at: Option<f64>,
}

impl ur::Motion for Collides {
    fn sample(&mut self, t: f64) -> ur::sim::JointSample {
        self.inner.sample(t)
    }
    fn movej(&mut self, t: f64, q: [f64; 6], a: f64, v: f64, min: f64) {
        self.at.get_or_insert(t + 0.15);
        self.inner.movej(t, q, a, v, min)
    }
    fn stopj(&mut self, t: f64, a: f64) {
        self.inner.stopj(t, a)
    }
    fn halt(&mut self, t: f64) {
        self.inner.halt(t)
    }
    fn is_moving(&mut self, t: f64) -> bool {
        self.inner.is_moving(t)
    }
    fn fault(&mut self, t: f64) -> Option<ur::MotionFault> {
        match self.at {
            Some(at) if t >= at => {
                self.at = Some(f64::INFINITY);
                Some(self.fault)
            }
            _ => None,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn faults_of_the_embedding_motion_become_the_controllers_safety_modes() {
    for (fault, mode) in [
        (ur::MotionFault::ProtectiveStop, SafetyMode::ProtectiveStop),
        (
            ur::MotionFault::EmergencyStop,
            SafetyMode::RobotEmergencyStop,
        ),
    ] {
        let motion = Collides {
            inner: ur::TrapezoidMotion::new(HOME),
            fault,
            at: None,
        };
        let c = ur::SimController::new(fast(), Box::new(motion));
        let s = ur::UrServers::start(
            c.clone(),
            &ur::ServerConfig::ephemeral(std::net::Ipv4Addr::LOCALHOST.into()),
        )
        .await
        .unwrap();
        let _d = make_running(&s).await;
        let mut r = rtde(&s).await;
        script(&s).movej(&[2.0; 6], 2.0, 1.0).await.unwrap();
        let seen = follow(&mut r, |st| st.safety_mode == mode).await.unwrap();
        let st = seen.last().unwrap();
        assert!(seen.iter().any(|st| st.program_running()));
        assert!(!st.program_running());
        assert_eq!(st.actual_qd, [0.0; 6]);
        assert!(max_abs_diff(&st.actual_q, &HOME) > 0.01, "never moved");
        if fault == ur::MotionFault::EmergencyStop {
            assert_eq!(st.robot_mode, RobotMode::PowerOff);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert_eq!(r.latest_state().await.unwrap().actual_q, st.actual_q);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dropped_next_data_futures_lose_or_split_no_package() {
    let (_c, s) = start(fast()).await;
    let mut r = RtdeClient::connect(s.rtde, TIMEOUT).await.unwrap();
    r.setup_outputs(&STATE_RECIPE, 500.0).await.unwrap();
    r.start().await.unwrap();
    let mut last = 0.0;
    let (mut got, mut dropped) = (0, 0);
    while got < 200 {
        // a deadline shorter than the 2 ms period drops many reads part way
        match tokio::time::timeout(Duration::from_micros(700), r.next_data()).await {
            Ok(p) => {
                let st = ur::RobotState::from_package(&p.unwrap()).unwrap();
                assert!(st.timestamp > last, "{} after {last}", st.timestamp);
                last = st.timestamp;
                got += 1;
            }
            Err(_) => dropped += 1,
        }
    }
    assert!(dropped > 0, "no read was dropped");
}
