use std::time::{Duration, Instant};

use robotlink::{ClientConfig, ErrorCode, EventName, RobotBackend, RobotClient, RobotError};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

use crate::common::{close, eventually, secret, Harness, Raw};

#[tokio::test]
async fn normal_session() {
    let h = Harness::start().await;
    let c = h.client().await;
    let id = c.hello().await.unwrap();
    assert_eq!(id.ctrl, "SIM");
    c.ping().await.unwrap();
    let st = c.state().await.unwrap();
    assert!(!st.power && !st.estop && !st.moving && st.settled);
    assert_eq!(st.mode, "remote");
    c.power(true).await.unwrap();
    c.speed(50.0).await.unwrap();
    let target = [10.0, -20.0, 30.0, 0.0, 45.0, -5.5];
    c.move_joints(target, Some(100.0)).await.unwrap();
    let st = c.state().await.unwrap();
    assert!(st.power && st.moving && !st.settled);
    let q = c.wait_settled(Duration::from_secs(2)).await.unwrap();
    assert!(close(&q, &target, 1e-6), "{q:?}");
    assert!(close(&c.joints().await.unwrap(), &target, 1e-6));
    let p = c.pose().await.unwrap();
    assert_eq!(p.xyz_mm, [10.0, -20.0, 30.0]);
    assert_eq!(p.rxyz_deg, [0.0, 45.0, -5.5]);
    c.stop().await.unwrap();
    let st = c.state().await.unwrap();
    assert!(!st.moving && st.settled);
    c.power(false).await.unwrap();
    assert!(!h.backend.power());
    h.stop().await;
}

#[tokio::test]
async fn motion_needs_power_and_limits() {
    let h = Harness::start().await;
    let c = h.client().await;
    c.hello().await.unwrap();
    let e = c.move_joints([1.0; 6], None).await.unwrap_err();
    assert!(matches!(e, RobotError::PowerOff(_)), "{e:?}");
    c.power(true).await.unwrap();
    let e = c
        .move_joints([0.0, 200.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            RobotError::Rejected {
                code: ErrorCode::Limit,
                ..
            }
        ),
        "{e:?}"
    );
    let e = c.speed(0.0).await.unwrap_err();
    assert!(matches!(
        e,
        RobotError::Rejected {
            code: ErrorCode::Args,
            ..
        }
    ));
    // Busy while moving.
    c.speed(1.0).await.unwrap();
    c.move_joints([50.0, 0.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap();
    let e = c.move_joints([0.0; 6], None).await.unwrap_err();
    assert!(matches!(
        e,
        RobotError::Rejected {
            code: ErrorCode::Busy,
            ..
        }
    ));
    c.stop().await.unwrap();
    assert!(!h.backend.is_moving());
    h.stop().await;
}

#[tokio::test]
async fn second_client_refused() {
    let h = Harness::start().await;
    let c1 = h.ready_client().await;
    let c2 = h.client().await;
    let e = c2.ping().await.unwrap_err();
    assert!(
        matches!(
            e,
            RobotError::Rejected {
                code: ErrorCode::Busy,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(matches!(c2.ping().await, Err(RobotError::Disconnected)));
    c1.ping().await.unwrap();
    drop(c1);
    // Once the first client is gone a new one is accepted.
    let mut ok = false;
    for _ in 0..50 {
        let c3 = h.client().await;
        if c3.hello().await.is_ok() {
            ok = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(ok);
    h.stop().await;
}

#[tokio::test]
async fn client_disconnect_stops_motion_and_reconnect_works() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    c.speed(5.0).await.unwrap();
    c.move_joints([90.0, 0.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap();
    assert!(h.backend.is_moving());
    c.close().await;
    assert!(matches!(c.ping().await, Err(RobotError::Disconnected)));
    drop(c);
    assert!(eventually(Duration::from_secs(1), || !h.backend.is_moving()).await);
    assert!(h.backend.joints_deg()[0] < 90.0);
    let c = h.client().await;
    c.hello().await.unwrap();
    c.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn hardware_estop_and_power_loss_during_wait() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    let mut ev = c.subscribe();
    c.speed(5.0).await.unwrap();
    c.move_joints([90.0, 0.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap();
    let b = h.backend.clone();
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(50)).await;
        b.set_estop(true);
    });
    let e = c.wait_settled(Duration::from_secs(2)).await.unwrap_err();
    assert!(matches!(e, RobotError::EStop(_)), "{e:?}");
    let got = tokio::time::timeout(Duration::from_secs(1), ev.recv())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(got.name, EventName::EStop);
    assert!(!h.backend.is_moving());
    let e = c.power(true).await.unwrap_err();
    assert!(matches!(e, RobotError::EStop(_)), "{e:?}");
    h.backend.set_estop(false);
    c.power(true).await.unwrap();
    assert!(c.state().await.unwrap().power);

    c.move_joints([-90.0, 0.0, 0.0, 0.0, 0.0, 0.0], None)
        .await
        .unwrap();
    let b = h.backend.clone();
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(50)).await;
        b.drop_power();
    });
    let e = c.wait_settled(Duration::from_secs(2)).await.unwrap_err();
    assert!(matches!(e, RobotError::PowerOff(_)), "{e:?}");
    // Connection survives both.
    c.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn malformed_line_closes_and_args_error_does_not() {
    let h = Harness::start().await;
    let mut s = Raw::connect(&h).await;
    assert!(s.authenticate(&secret()).await.starts_with("2 OK "));
    let l = s.exchange("7 MOVEJ 1 2\r").await;
    assert!(l.starts_with("7 ERR E_ARGS"), "{l}");
    assert_eq!(s.exchange("8 PING").await, "8 OK");
    let l = s.exchange("9 LAUNCH").await;
    assert!(l.starts_with("9 ERR E_SYNTAX"), "{l}");
    assert!(s.closed().await, "server must close after a malformed line");
    h.stop().await;
}

#[tokio::test]
async fn client_over_duplex_rejects_garbage() {
    let (a, b) = tokio::io::duplex(256);
    let c = RobotClient::from_stream(a, ClientConfig::default());
    let (rd, mut wr) = tokio::io::split(b);
    tokio::spawn(async move {
        let mut rd = BufReader::new(rd);
        let mut l = String::new();
        rd.read_line(&mut l).await.unwrap();
        assert_eq!(l, "1 PING\n");
        wr.write_all(b"1 MAYBE\n").await.unwrap();
        let _ = rd.read_line(&mut l).await;
    });
    let e = c.ping().await.unwrap_err();
    assert!(matches!(e, RobotError::Protocol(_)), "{e:?}");
    assert!(matches!(c.ping().await, Err(RobotError::Disconnected)));
}

#[tokio::test]
async fn server_gone_gives_disconnected() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    h.stop().await;
    let t0 = Instant::now();
    let e = c.ping().await.unwrap_err();
    assert!(matches!(e, RobotError::Disconnected), "{e:?}");
    assert!(t0.elapsed() < Duration::from_secs(1));
    assert!(c.is_closed());
}
