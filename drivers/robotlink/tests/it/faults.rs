use std::sync::Arc;
use std::time::{Duration, Instant};

use robotlink::{ClientConfig, ErrorCode, EventName, RobotBackend, RobotClient, RobotError};

use crate::common::{close, eventually, Harness};

const T: [f64; 6] = [5.0, 5.0, 5.0, 5.0, 5.0, 5.0];

#[tokio::test]
async fn rejected_movej_codes() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    let cases = [
        ErrorCode::Unreachable,
        ErrorCode::Limit,
        ErrorCode::Power,
        ErrorCode::EStop,
    ];
    for code in cases {
        {
            let mut f = h.faults();
            f.reject_movej = 1;
            f.reject_code = code.clone();
        }
        let e = c.move_joints(T, None).await.unwrap_err();
        let ok = match (&code, &e) {
            (ErrorCode::Power, RobotError::PowerOff(_)) => true,
            (ErrorCode::EStop, RobotError::EStop(_)) => true,
            (c1, RobotError::Rejected { code: c2, .. }) => c1 == c2,
            _ => false,
        };
        assert!(ok, "{code:?} -> {e:?}");
        assert!(!h.backend.is_moving());
    }
    // One-shot: the next move is accepted.
    c.move_joints(T, None).await.unwrap();
    c.wait_settled(Duration::from_secs(1)).await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn injected_estop_during_move() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    let mut ev = c.subscribe();
    {
        let mut f = h.faults();
        f.estop_during_move = 1;
        f.estop_delay = Duration::from_millis(30);
    }
    c.speed(5.0).await.unwrap();
    c.move_joints([60.0, 0.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap();
    let e = c.wait_settled(Duration::from_secs(2)).await.unwrap_err();
    assert!(matches!(e, RobotError::EStop(_)), "{e:?}");
    let got = tokio::time::timeout(Duration::from_secs(1), ev.recv())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(got.name, EventName::EStop);
    assert!(!h.backend.is_moving());
    assert!(c.state().await.unwrap().estop);
    let e = c.move_joints(T, None).await.unwrap_err();
    assert!(matches!(e, RobotError::EStop(_)), "{e:?}");
    h.faults().estop_latched = false;
    c.move_joints(T, None).await.unwrap();
    c.wait_settled(Duration::from_secs(2)).await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn never_settles_and_slow_settle() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    h.faults().never_settle = 1;
    c.move_joints(T, None).await.unwrap();
    let t0 = Instant::now();
    let e = c
        .wait_settled(Duration::from_millis(150))
        .await
        .unwrap_err();
    assert!(matches!(e, RobotError::NotSettled(_)), "{e:?}");
    assert!(t0.elapsed() >= Duration::from_millis(150));
    assert!(!c.state().await.unwrap().settled);
    c.stop().await.unwrap();
    assert!(c.state().await.unwrap().settled);

    {
        let mut f = h.faults();
        f.slow_settle = 1;
        f.slow_settle_extra = Duration::from_millis(150);
    }
    c.move_joints([0.0; 6], None).await.unwrap();
    let t0 = Instant::now();
    let q = c.wait_settled(Duration::from_secs(2)).await.unwrap();
    assert!(t0.elapsed() >= Duration::from_millis(150));
    assert!(close(&q, &[0.0; 6], 1e-9));
    // Slow settle beyond the WAIT timeout is a NotSettled.
    {
        let mut f = h.faults();
        f.slow_settle = 1;
        f.slow_settle_extra = Duration::from_millis(500);
    }
    c.move_joints(T, None).await.unwrap();
    let e = c
        .wait_settled(Duration::from_millis(100))
        .await
        .unwrap_err();
    assert!(matches!(e, RobotError::NotSettled(_)), "{e:?}");
    h.stop().await;
}

#[tokio::test]
async fn client_timeout_on_delayed_reply() {
    // Reply later than the client allows: client times out, connection stays usable.
    let h = Harness::start().await;
    let c = RobotClient::connect(
        h.addr,
        ClientConfig {
            request_timeout: Duration::from_millis(100),
            wait_margin: Duration::from_millis(50),
            ..Harness::config()
        },
    )
    .await
    .unwrap();
    c.hello().await.unwrap();
    c.power(true).await.unwrap();
    {
        let mut f = h.faults();
        f.delay_reply = 1;
        f.reply_delay = Duration::from_millis(300);
    }
    let e = c.ping().await.unwrap_err();
    assert!(matches!(e, RobotError::Timeout("PING")), "{e:?}");
    // Late reply to the abandoned request (arrives at 300 ms) is dropped, the next one matches.
    tokio::time::sleep(Duration::from_millis(250)).await;
    c.ping().await.unwrap();
    c.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn read_back_offset_and_noise_hook() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    {
        let mut f = h.faults();
        f.joint_offset_deg = [0.01, 0.0, 0.0, 0.0, 0.0, -0.02];
        f.joint_hook = Some(Arc::new(|mut q: [f64; 6]| {
            q[2] += 0.001;
            q
        }));
    }
    c.move_joints(T, None).await.unwrap();
    let q = c.wait_settled(Duration::from_secs(1)).await.unwrap();
    let expect = [5.01, 5.0, 5.001, 5.0, 5.0, 4.98];
    assert!(close(&q, &expect, 1e-9), "{q:?}");
    assert!(close(&c.joints().await.unwrap(), &expect, 1e-9));
    assert!(close(&h.backend.joints_deg(), &T, 1e-9));
    h.stop().await;
}

#[tokio::test]
async fn delayed_and_split_replies_are_fine() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    {
        let mut f = h.faults();
        f.delay_reply = 1;
        f.reply_delay = Duration::from_millis(100);
    }
    let t0 = Instant::now();
    c.ping().await.unwrap();
    assert!(t0.elapsed() >= Duration::from_millis(100));
    h.faults().split_reply = 3;
    c.move_joints(T, None).await.unwrap();
    let q = c.wait_settled(Duration::from_secs(1)).await.unwrap();
    assert!(close(&q, &T, 1e-9));
    let st = c.state().await.unwrap();
    assert!(st.settled);
    h.stop().await;
}

#[tokio::test]
async fn unsolicited_event_line_is_delivered() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    let mut ev = c.subscribe();
    h.faults().extra_line = 1;
    c.ping().await.unwrap();
    let got = tokio::time::timeout(Duration::from_secs(1), ev.recv())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(got.name, EventName::Other("NOTE".into()));
    assert_eq!(got.data, "unsolicited");
    c.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn unsolicited_reply_line_is_protocol_error() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    {
        let mut f = h.faults();
        f.extra_line = 1;
        f.extra_line_text = "4242 OK".into();
    }
    let e = c.ping().await.unwrap_err();
    assert!(matches!(e, RobotError::Protocol(_)), "{e:?}");
    assert!(matches!(c.ping().await, Err(RobotError::Disconnected)));
    h.stop().await;
}

#[tokio::test]
async fn wrong_sequence_number_is_protocol_error_then_reconnect() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    h.faults().wrong_seq = 1;
    let e = c.joints().await.unwrap_err();
    assert!(matches!(e, RobotError::Protocol(_)), "{e:?}");
    assert!(matches!(c.state().await, Err(RobotError::Disconnected)));
    drop(c);
    let mut c2 = None;
    for _ in 0..50 {
        let c = h.client().await;
        if c.hello().await.is_ok() {
            c2 = Some(c);
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let c2 = c2.expect("reconnect");
    c2.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn non_numeric_field_is_protocol_error_connection_kept() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    h.faults().non_numeric = 1;
    let e = c.joints().await.unwrap_err();
    assert!(
        matches!(e, RobotError::Protocol(ref m) if m.contains("abc")),
        "{e:?}"
    );
    h.faults().non_numeric = 1;
    let e = c.pose().await.unwrap_err();
    assert!(matches!(e, RobotError::Protocol(_)), "{e:?}");
    c.joints().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn server_drops_during_move_stops_motion() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    c.speed(5.0).await.unwrap();
    h.faults().disconnect_during_move = 1;
    c.move_joints([90.0, 0.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap();
    let e = c.wait_settled(Duration::from_secs(1)).await.unwrap_err();
    assert!(matches!(e, RobotError::Disconnected), "{e:?}");
    assert!(eventually(Duration::from_secs(1), || !h.backend.is_moving()).await);
    assert!(h.backend.joints_deg()[0] < 90.0);
    // Reconnect recovers.
    let c = h.ready_client().await;
    c.move_joints(T, Some(100.0)).await.unwrap();
    c.speed(100.0).await.unwrap();
    c.wait_settled(Duration::from_secs(3)).await.unwrap();
    h.stop().await;
}
