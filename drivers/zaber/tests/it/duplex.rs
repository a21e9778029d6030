//! In-memory tests (in addition to the pty tests): scripted device behaviour.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use zaber::ascii::{append_checksum, parse_command};
use zaber::sim::{serve_stage, StageSim, StageSimConfig};
use zaber::{GaugeClient, GaugeConfig, GaugeError, StageConfig, StageError, ZaberStage};

use crate::common::{sim, stage_cfg, STEPS_PER_MM};

#[tokio::test]
async fn stage_sim_over_duplex() {
    let (a, b) = tokio::io::duplex(1024);
    let s = sim(false);
    tokio::spawn(serve_stage(b, s.clone()));
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    st.home().await.unwrap();
    assert!((st.move_abs_mm(7.0).await.unwrap() - 7.0).abs() <= 0.5 / STEPS_PER_MM);
}

#[tokio::test]
async fn move_overhead_keeps_a_move_busy_and_zero_ends_it_at_once() {
    for (overhead, busy) in [(Duration::from_millis(200), true), (Duration::ZERO, false)] {
        let (a, b) = tokio::io::duplex(1024);
        let s = StageSim::new(StageSimConfig {
            homed: true,
            speed_steps_s: 1.0e12,
            move_overhead: overhead,
            ..StageSimConfig::default()
        });
        tokio::spawn(serve_stage(b, s.clone()));
        let mut st = ZaberStage::from_stream(a, stage_cfg());
        st.start_move_abs_mm(7.0).await.unwrap();
        assert_eq!(s.is_busy(), busy, "move overhead {overhead:?}");
        st.poll_until_idle(Duration::from_secs(1)).await.unwrap();
        assert!((st.position_mm().await.unwrap() - 7.0).abs() <= 0.5 / STEPS_PER_MM);
    }
}

/// Scripted device of a product not in the table: answers the identity queries, then skips
/// info/alert lines and a stale reply, answers with checksums.
#[tokio::test]
async fn client_skips_info_alert_and_stale_replies() {
    let (a, b) = tokio::io::duplex(1024);
    tokio::spawn(async move {
        let (rd, mut wr) = tokio::io::split(b);
        let mut rd = BufReader::new(rd);
        let mut line = String::new();
        let cmd = loop {
            line.clear();
            rd.read_line(&mut line).await.unwrap();
            let (cmd, had_cs) = parse_command(&line).unwrap();
            assert!(had_cs);
            if cmd.text == "get pos" {
                break cmd;
            }
            let reply = format!("@01 {} {} OK IDLE -- 7", cmd.axis, cmd.id.unwrap());
            wr.write_all(format!("{}\r\n", append_checksum(&reply)).as_bytes())
                .await
                .unwrap();
        };
        let id = cmd.id.unwrap();
        let stale = append_checksum(&format!("@01 1 {} OK IDLE -- 1", (id + 99) % 100));
        let info = "#01 1 some info text";
        let alert = "!01 1 IDLE --";
        let other_dev = "@02 1 0 OK IDLE -- 5";
        let good = append_checksum(&format!("@01 1 {id} OK IDLE -- -2500"));
        for l in [stale.as_str(), info, alert, other_dev, good.as_str()] {
            wr.write_all(format!("{l}\r\n").as_bytes()).await.unwrap();
        }
        let _ = rd.read_line(&mut line).await;
    });
    let cfg = StageConfig {
        microsteps_per_mm: Some(1000.0),
        ..stage_cfg()
    };
    let mut st = ZaberStage::from_stream(a, cfg);
    let p = st.position_mm().await.unwrap();
    assert!((p + 2.5).abs() < 1e-12);
    let id = st.identity().unwrap();
    assert_eq!((id.device_id, id.product), (7, None));
}

#[tokio::test]
async fn disconnected_after_eof() {
    let (a, b) = tokio::io::duplex(64);
    drop(b);
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    let e = st.position_mm().await.unwrap_err();
    assert!(
        matches!(e, StageError::Io(_) | StageError::Disconnected),
        "{e:?}"
    );
    assert!(matches!(
        st.position_mm().await,
        Err(StageError::Disconnected)
    ));
}

#[tokio::test]
async fn gauge_configurable_request_and_mitutoyo_format() {
    let (a, b) = tokio::io::duplex(256);
    tokio::spawn(async move {
        let (rd, mut wr) = tokio::io::split(b);
        let mut rd = BufReader::new(rd);
        let mut buf = Vec::new();
        rd.read_until(b'\r', &mut buf).await.unwrap();
        assert_eq!(buf, b"1\r");
        wr.write_all(b"01A+00012.345\r").await.unwrap();
        let _ = rd.read_until(b'\r', &mut buf).await;
        // Stay connected but silent.
        tokio::time::sleep(Duration::from_secs(2)).await;
        drop(wr);
    });
    let mut g = GaugeClient::from_stream(
        a,
        GaugeConfig {
            request: "1\r".into(),
            reply_timeout: Duration::from_millis(200),
            ..Default::default()
        },
    );
    assert_eq!(g.read_mm().await.unwrap(), 12.345);
    // Second request gets no answer.
    assert!(matches!(g.read_mm().await, Err(GaugeError::Timeout)));
}

#[tokio::test]
async fn a_command_dropped_mid_write_is_discarded_not_joined_to_the_next() {
    // An 8-byte pipe nobody reads yet: the move line is cut after 8 bytes when its future is
    // dropped (an abort). The device must discard that partial line, not run it glued to the
    // next command (or reject the next one).
    let (a, b) = tokio::io::duplex(8);
    let s = sim(true);
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    {
        let cut = std::pin::pin!(st.command("move abs 1000"));
        let polled = futures_poll_once(cut).await;
        assert!(polled.is_none(), "the whole line fitted the pipe");
    }
    tokio::spawn(serve_stage(b, s.clone()));
    let p = st.position_mm().await.unwrap();
    assert!(p.abs() < 1e-9, "the cut move ran: {p}");
    assert!((st.move_abs_mm(7.0).await.unwrap() - 7.0).abs() <= 0.5 / STEPS_PER_MM);
}

/// Poll `f` once; its output if it was ready (the caller drops it).
async fn futures_poll_once<F: std::future::Future + Unpin>(mut f: F) -> Option<F::Output> {
    std::future::poll_fn(|cx| {
        std::task::Poll::Ready(match std::pin::Pin::new(&mut f).poll(cx) {
            std::task::Poll::Ready(v) => Some(v),
            std::task::Poll::Pending => None,
        })
    })
    .await
}

#[tokio::test]
async fn a_dropped_gauge_reading_is_not_taken_for_the_next_one() {
    use std::sync::atomic::{AtomicU64, Ordering};
    let value = std::sync::Arc::new(AtomicU64::new(1.0f64.to_bits()));
    let source = value.clone();
    let gauge = zaber::sim::GaugeSim::new(std::sync::Arc::new(move || {
        f64::from_bits(source.load(Ordering::SeqCst))
    }));
    let (a, b) = tokio::io::duplex(256);
    tokio::spawn(zaber::sim::serve_gauge(b, gauge));
    let mut g = GaugeClient::from_stream(
        a,
        GaugeConfig {
            reply_timeout: Duration::from_millis(200),
            ..Default::default()
        },
    );
    assert_eq!(g.read_mm().await.unwrap(), 1.0);
    {
        // the request goes out, then the caller gives up before the reading (an abort)
        let dropped = std::pin::pin!(g.read_mm());
        assert!(futures_poll_once(dropped).await.is_none());
    }
    tokio::time::sleep(Duration::from_millis(50)).await; // the late reading (1.0) arrives
    value.store(2.0f64.to_bits(), Ordering::SeqCst);
    assert_eq!(
        g.read_mm().await.unwrap(),
        2.0,
        "the dropped request's reading was taken for the next one"
    );
}
