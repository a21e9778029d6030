//! Abort during a move (out-of-band STOP once authenticated; before that, by closing) and
//! cancel-safety of request futures. The latency bound (200 ms from sending STOP to a stopped arm) is the
//! acceptance criterion; the measured figures are printed (`--nocapture`).

use std::time::{Duration, Instant};

use robotlink::{RobotBackend, RobotClient, RobotError, SimpleBackend, SimpleConfig};

use std::future::Future;
use std::task::Poll;

use crate::common::{close, secret, Harness, Raw};

/// Poll `f` exactly once, then drop it; its output if it was ready.
async fn poll_once_then_drop<F: Future>(f: F) -> Option<F::Output> {
    let mut f = std::pin::pin!(f);
    std::future::poll_fn(|cx| {
        Poll::Ready(match f.as_mut().poll(cx) {
            Poll::Ready(v) => Some(v),
            Poll::Pending => None,
        })
    })
    .await
}

/// Acceptance bound: the arm has stopped within this time of sending STOP (or closing).
const STOP_BOUND: Duration = Duration::from_millis(200);
/// A 90° move at 20 °/s: 4.5 s.
const FAR: [f64; 6] = [90.0, 0.0, 0.0, 0.0, 0.0, 0.0];
const WHEN: Duration = Duration::from_millis(300);

async fn slow_arm() -> Harness {
    Harness::with_config(SimpleConfig {
        max_joint_speed_deg_s: 20.0,
        settle_time: Duration::from_millis(20),
        ..Default::default()
    })
    .await
}

/// Poll the backend every millisecond until it has stopped; time since `sent`.
async fn stopped_after(b: &SimpleBackend, sent: Instant) -> Duration {
    while b.is_moving() && sent.elapsed() < Duration::from_secs(6) {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    assert!(!b.is_moving(), "the arm never stopped");
    sent.elapsed()
}

/// The arm stands still short of FAR (at roughly 0.3 s × 20 °/s = 6°).
async fn assert_frozen_short(b: &SimpleBackend) {
    let q1 = b.joints_deg();
    tokio::time::sleep(Duration::from_millis(50)).await;
    let q2 = b.joints_deg();
    assert_eq!(q1, q2, "joints still changing after the stop");
    assert!(q1[0] > 1.0 && q1[0] < 30.0, "stopped at {q1:?}");
}

#[tokio::test]
async fn stop_overtakes_an_outstanding_wait() {
    let h = slow_arm().await;
    let c = h.ready_client().await;
    assert_eq!(c.protocol_version(), Some(3));
    c.move_joints(FAR, None).await.unwrap();
    let stopper = async {
        tokio::time::sleep(WHEN).await;
        let sent = Instant::now();
        c.stop().await.unwrap();
        (sent, stopped_after(&h.backend, sent).await)
    };
    let (wait, (sent, latency)) = tokio::join!(c.wait_settled(Duration::from_secs(10)), stopper);
    eprintln!("STOP latency, v2, WAIT outstanding: {latency:?}");
    assert!(latency < STOP_BOUND, "{latency:?}");
    assert!(matches!(wait, Err(RobotError::Stopped(_))), "{wait:?}");
    assert!(sent.elapsed() < Duration::from_secs(1));
    assert_frozen_short(&h.backend).await;
    c.ping().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn dropped_wait_then_stop_reaches_the_arm() {
    // The campaign engine's abort path: the move/WAIT future is dropped, then stop().
    let h = slow_arm().await;
    let c = h.ready_client().await;
    c.move_joints(FAR, None).await.unwrap();
    let r = tokio::time::timeout(WHEN, c.wait_settled(Duration::from_secs(10))).await;
    assert!(r.is_err(), "WAIT ended early: {r:?}");
    let sent = Instant::now();
    c.stop().await.unwrap();
    let latency = stopped_after(&h.backend, sent).await;
    eprintln!("STOP latency, v2, dropped WAIT then stop(): {latency:?}");
    assert!(latency < STOP_BOUND, "{latency:?}");
    assert_frozen_short(&h.backend).await;
    // The abandoned WAIT's late E_STOPPED reply was dropped; the stream is in step.
    let q = c.joints().await.unwrap();
    assert!(close(&q, &h.backend.joints_deg(), 1e-5), "{q:?}");
    c.move_joints([0.0; 6], None).await.unwrap();
    c.stop().await.unwrap();
    h.stop().await;
}

#[tokio::test]
async fn stop_handle_stops_from_another_task() {
    let h = slow_arm().await;
    let c = h.ready_client().await;
    let stop = c.stop_handle();
    c.move_joints(FAR, None).await.unwrap();
    let t = tokio::spawn(async move {
        tokio::time::sleep(WHEN).await;
        let sent = Instant::now();
        stop.stop().await.unwrap();
        sent
    });
    let wait = c.wait_settled(Duration::from_secs(10)).await;
    let sent = t.await.unwrap();
    let latency = stopped_after(&h.backend, sent).await;
    eprintln!("STOP latency, v2, StopHandle from another task: {latency:?}");
    assert!(latency < STOP_BOUND, "{latency:?}");
    assert!(matches!(wait, Err(RobotError::Stopped(_))), "{wait:?}");
    h.stop().await;
}

#[tokio::test]
async fn stop_is_accepted_before_the_handshake() {
    // STOP is the one request a client that has not authenticated may send: it can only stop.
    let h = slow_arm().await;
    h.backend.set_power(true).unwrap();
    h.backend.start_move(FAR, 100.0).unwrap();
    let c = h.client().await;
    let sent = Instant::now();
    c.stop().await.unwrap();
    let latency = stopped_after(&h.backend, sent).await;
    assert!(latency < STOP_BOUND, "{latency:?}");
    assert!(!c.is_closed());
    // The handshake still works on the same connection.
    c.hello().await.unwrap();
    c.ping().await.unwrap();
    h.stop().await;
}

/// A raw session after the handshake and `POWER ON`, the 4.5 s move accepted as seq 4.
async fn raw_moving(h: &Harness) -> Raw {
    let mut s = Raw::connect(h).await;
    let auth = s.authenticate(&secret()).await;
    assert!(auth.starts_with("2 OK"), "{auth}");
    assert_eq!(s.exchange("3 POWER ON").await, "3 OK");
    assert_eq!(s.exchange("4 MOVEJ 90 0 0 0 0 0").await, "4 OK");
    s
}

#[tokio::test]
async fn authenticated_server_answers_stop_at_once_and_busy_for_other_requests() {
    let h = slow_arm().await;
    let mut s = raw_moving(&h).await;
    s.send("5 WAIT 10000").await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    // Another request while WAIT executes: E_BUSY at once, the WAIT goes on.
    let busy = s.exchange("6 JOINTS").await;
    assert!(busy.starts_with("6 ERR E_BUSY"), "{busy}");
    assert!(h.backend.is_moving());
    // A malformed argument is still E_ARGS, the WAIT goes on.
    assert!(s.exchange("7 WAIT x").await.starts_with("7 ERR E_ARGS"));
    s.send("8 STOP").await;
    // The interrupted WAIT answers first, then the STOP.
    s.expect("5 ERR E_STOPPED").await;
    s.expect("8 OK").await;
    assert!(!h.backend.is_moving());
    s.send("9 JOINTS").await;
    s.expect("9 OK ").await;
    h.stop().await;
}

#[tokio::test]
async fn before_authentication_requests_are_handled_in_order() {
    // Before the handshake a STOP sent behind another request waits for it (v1 rules).
    let h = slow_arm().await;
    h.faults().delay_reply = 1;
    let mut s = Raw::connect(&h).await;
    s.send("1 HELLO 3").await;
    s.send("2 STOP").await;
    s.expect("1 OK ").await;
    s.expect("2 OK").await;
    h.stop().await;
}

#[tokio::test]
async fn dropped_request_futures_never_desynchronise() {
    let h = Harness::start().await;
    let c = h.ready_client().await;
    // Polled once (the line is queued for the wire), then dropped.
    let t = [20.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert!(poll_once_then_drop(c.move_joints(t, None)).await.is_none());
    assert!(poll_once_then_drop(c.joints()).await.is_none());
    let q = c.wait_settled(Duration::from_secs(2)).await.unwrap();
    assert_eq!(
        q, t,
        "the dropped MOVEJ was executed, WAIT matched its own reply"
    );
    c.move_joints([0.0; 6], None).await.unwrap();
    let r = tokio::time::timeout(
        Duration::from_millis(5),
        c.wait_settled(Duration::from_secs(2)),
    );
    assert!(r.await.is_err());
    // JOINTS waits for the abandoned WAIT's reply, then goes out and matches.
    assert!(c.joints().await.is_ok());
    c.ping().await.unwrap();
    // A dropped out-of-band STOP followed at once by another STOP.
    assert!(poll_once_then_drop(c.stop()).await.is_none());
    c.stop().await.unwrap();
    c.ping().await.unwrap();
    // Many drops at every point of a request's life.
    for i in 0..60u64 {
        let d = Duration::from_micros(i * 37 % 400);
        let _ = tokio::time::timeout(d, c.state()).await;
        let _ = tokio::time::timeout(d, c.joints()).await;
        let _ = tokio::time::timeout(d, c.ping()).await;
    }
    c.ping().await.unwrap();
    assert!(c.state().await.unwrap().settled);
    assert!(!c.is_closed());
    h.stop().await;
}

#[tokio::test]
async fn a_dropped_server_session_stops_the_arm_and_closes_the_connection() {
    // Dropping `serve_connection` (e.g. its task aborted at shutdown) must end the session as
    // returning does: the arm stopped and the peer told by EOF, not left waiting.
    let backend = std::sync::Arc::new(SimpleBackend::new(SimpleConfig {
        max_joint_speed_deg_s: 20.0,
        ..Default::default()
    }));
    let (a, b) = tokio::io::duplex(1024);
    let (_keep, stop_rx) = tokio::sync::watch::channel(false);
    let dynb: std::sync::Arc<dyn RobotBackend> = backend.clone();
    let session = tokio::spawn(robotlink::serve_connection(
        b,
        dynb,
        robotlink::FaultConfig::handle(),
        std::sync::Arc::new(robotlink::ServerAccess::loopback(secret())),
        stop_rx,
    ));
    let c = RobotClient::from_stream(a, Harness::config());
    c.hello().await.unwrap();
    c.power(true).await.unwrap();
    c.move_joints(FAR, None).await.unwrap();
    assert!(backend.is_moving());
    session.abort();
    let _ = session.await;
    assert!(
        !backend.is_moving(),
        "the dropped session left the arm moving"
    );
    let ping = tokio::time::timeout(Duration::from_millis(500), c.ping()).await;
    assert!(
        matches!(ping, Ok(Err(RobotError::Disconnected))),
        "the dropped session left the connection open: {ping:?}"
    );
}
