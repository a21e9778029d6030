//! The simulated stage answers like an X-series device, and the driver takes its scale and its
//! safety faults from what the device says.

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader, DuplexStream};
use zaber::ascii::{parse_message, Message, Reply, ReplyFlag, Warning};
use zaber::product::SIM_PRODUCT;
use zaber::sim::{serve_stage, StageSim, StageSimConfig};
use zaber::{StageConfig, StageError, ZaberStage};

use crate::common::{sim, stage_cfg, STEPS_PER_MM};

/// A raw line client on a simulated stage (no driver in between).
struct Raw {
    io: BufReader<DuplexStream>,
}

impl Raw {
    fn new(s: StageSim) -> Raw {
        let (a, b) = tokio::io::duplex(4096);
        tokio::spawn(serve_stage(b, s));
        Raw {
            io: BufReader::new(a),
        }
    }

    async fn ask(&mut self, line: &str) -> Reply {
        self.io
            .get_mut()
            .write_all(format!("{line}\n").as_bytes())
            .await
            .unwrap();
        let mut buf = String::new();
        self.io.read_line(&mut buf).await.unwrap();
        match parse_message(&buf).unwrap() {
            Message::Reply(r) => r,
            m => panic!("not a reply: {m:?}"),
        }
    }
}

#[tokio::test]
async fn device_scope_replies_on_axis_0_and_axis_scope_on_the_axis() {
    let mut raw = Raw::new(sim(false));
    // zaber-motion's first words on a port: an empty command to every device.
    let r = raw.ask("/0 0 00").await;
    assert_eq!(
        (r.device, r.axis, r.id, r.flag),
        (1, 0, Some(0), ReplyFlag::Ok)
    );
    let r = raw.ask("/1 0 01 get device.id").await;
    assert_eq!((r.axis, r.id), (0, Some(1)));
    assert_eq!(r.data, SIM_PRODUCT.device_id.to_string());
    let r = raw.ask("/1 1 get pos").await;
    assert_eq!((r.axis, r.data.as_str()), (1, "0"));
    // An axis setting read at device scope answers for the (one) axis, on axis 0.
    let r = raw.ask("/1 0 get resolution").await;
    assert_eq!((r.axis, r.data.as_str()), (0, "64"));
    // A device setting read on an axis is refused.
    let r = raw.ask("/1 1 get device.id").await;
    assert_eq!(
        (r.axis, r.flag, r.data.as_str()),
        (1, ReplyFlag::Rejected, "BADAXIS")
    );
    let r = raw.ask("/1 home").await;
    assert_eq!((r.axis, r.flag), (0, ReplyFlag::Ok));
}

#[tokio::test]
async fn the_gets_a_client_sends_on_detect_and_identify_are_answered() {
    let mut raw = Raw::new(StageSim::new(StageSimConfig {
        serial: 4242,
        ..StageSimConfig::default()
    }));
    let want = [
        ("/1 0 get device.id", SIM_PRODUCT.device_id.to_string()),
        ("/1 0 get deviceid", SIM_PRODUCT.device_id.to_string()),
        ("/1 0 get system.serial", "4242".into()),
        ("/1 0 get version", "7.38".into()),
        ("/1 0 get version.build", "18000".into()),
        ("/1 0 get comm.packet.size.max", "80".into()),
        ("/1 0 get system.axiscount", "1".into()),
        ("/1 1 get resolution", "64".into()),
        (
            "/1 1 get peripheral.id",
            SIM_PRODUCT.peripheral_id.to_string(),
        ),
        (
            "/1 1 get peripheralid",
            SIM_PRODUCT.peripheral_id.to_string(),
        ),
        ("/1 1 get limit.min", "0".into()),
        ("/1 1 get limit.max", "2100000".into()),
        ("/1 1 get maxspeed", "32768000".into()),
    ];
    for (cmd, data) in want {
        let r = raw.ask(cmd).await;
        assert_eq!(
            (r.flag, r.data.as_str()),
            (ReplyFlag::Ok, data.as_str()),
            "{cmd}"
        );
    }
    let r = raw.ask("/1 1 get no.such.setting").await;
    assert_eq!(
        (r.flag, r.data.as_str()),
        (ReplyFlag::Rejected, "BADCOMMAND")
    );
}

#[tokio::test]
async fn microsteps_per_mm_come_from_the_device() {
    let (a, b) = tokio::io::duplex(4096);
    let s = StageSim::new(StageSimConfig {
        resolution: 128,
        homed: true,
        ..StageSimConfig::default()
    });
    tokio::spawn(serve_stage(b, s.clone()));
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    assert_eq!(st.microsteps_per_mm(), None);
    let id = st.identify().await.unwrap();
    assert_eq!(id.device_id, SIM_PRODUCT.device_id);
    assert_eq!(id.peripheral_id, SIM_PRODUCT.peripheral_id);
    assert_eq!(
        (id.serial, id.firmware.as_str(), id.resolution),
        (123_456, "7.38", 128)
    );
    assert_eq!(id.product, Some(SIM_PRODUCT.name));
    let k = 128.0 / SIM_PRODUCT.full_step_mm;
    assert!((id.microsteps_per_mm - k).abs() < 1e-9);
    st.move_abs_mm(10.0).await.unwrap();
    assert_eq!(s.position_steps(), (10.0 * k).round() as i64);
}

#[tokio::test]
async fn a_configured_scale_that_disagrees_with_the_device_is_refused() {
    for (configured, ok) in [
        (STEPS_PER_MM, true),
        (20_997.0, true), // the old config default: 1.8e-5 off
        (1000.0, false),
        (STEPS_PER_MM * 1.001, false),
    ] {
        let (a, b) = tokio::io::duplex(4096);
        tokio::spawn(serve_stage(b, sim(true)));
        let cfg = StageConfig {
            microsteps_per_mm: Some(configured),
            ..stage_cfg()
        };
        let mut st = ZaberStage::from_stream(a, cfg);
        let r = st.move_abs_mm(1.0).await;
        if ok {
            r.unwrap();
        } else {
            let e = r.unwrap_err();
            match &e {
                StageError::ScaleMismatch {
                    configured: c,
                    device,
                    resolution,
                    ..
                } => {
                    assert_eq!((*c, *resolution), (configured, 64));
                    assert!((device - STEPS_PER_MM).abs() < 1e-9);
                }
                e => panic!("{configured}: {e:?}"),
            }
            assert!(e.to_string().contains("disagrees"), "{e}");
        }
    }
    for bad in [f64::NAN, 0.0, -5.0, f64::INFINITY] {
        let (a, b) = tokio::io::duplex(4096);
        tokio::spawn(serve_stage(b, sim(true)));
        let cfg = StageConfig {
            microsteps_per_mm: Some(bad),
            ..stage_cfg()
        };
        let e = ZaberStage::from_stream(a, cfg)
            .identify()
            .await
            .unwrap_err();
        assert!(matches!(e, StageError::InvalidConfig(_)), "{bad}: {e:?}");
    }
}

#[tokio::test]
async fn an_unknown_product_without_a_configured_scale_is_refused() {
    let (a, b) = tokio::io::duplex(4096);
    tokio::spawn(serve_stage(
        b,
        StageSim::new(StageSimConfig {
            device_id: 1234,
            homed: true,
            ..StageSimConfig::default()
        }),
    ));
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    let e = st.move_abs_mm(1.0).await.unwrap_err();
    assert!(
        matches!(
            e,
            StageError::UnknownProduct {
                device_id: 1234,
                ..
            }
        ),
        "{e:?}"
    );
}

#[tokio::test]
async fn unexpected_limit_is_a_fault_then_cleared() {
    let (a, b) = tokio::io::duplex(4096);
    let s = sim(true);
    tokio::spawn(serve_stage(b, s.clone()));
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    s.faults().limit_hit = 1;
    let e = st.move_abs_mm(30.0).await.unwrap_err();
    assert!(matches!(e, StageError::UnexpectedLimit), "{e:?}");
    assert_eq!(s.warning_flags(), vec![Warning::WL]);
    // Still latched: the next move reports it (once) and clears it instead of moving.
    let e = st.move_abs_mm(30.0).await.unwrap_err();
    assert!(matches!(e, StageError::UnexpectedLimit), "{e:?}");
    assert!(s.warning_flags().is_empty());
    st.move_abs_mm(30.0).await.unwrap();
}

#[tokio::test]
async fn displaced_while_stationary_is_a_fault_then_cleared() {
    let (a, b) = tokio::io::duplex(4096);
    let s = sim(true);
    tokio::spawn(serve_stage(b, s.clone()));
    let mut st = ZaberStage::from_stream(a, stage_cfg());
    st.move_abs_mm(5.0).await.unwrap();
    let before = s.position_steps();
    {
        let mut f = s.faults();
        f.displace = 1;
        f.displace_steps = 300;
    }
    let e = st.position_mm().await.unwrap_err();
    assert!(matches!(e, StageError::Displaced), "{e:?}");
    assert_eq!(s.position_steps(), before + 300);
    let e = st.move_abs_mm(6.0).await.unwrap_err();
    assert!(matches!(e, StageError::Displaced), "{e:?}");
    assert!(s.warning_flags().is_empty());
    st.move_abs_mm(6.0).await.unwrap();
}

#[tokio::test]
async fn warnings_lists_and_clear_keeps_wr_until_homed() {
    let s = sim(false);
    let mut raw = Raw::new(s.clone());
    let r = raw.ask("/1 1 warnings").await;
    assert_eq!((r.warning, r.data.as_str()), (Warning::WR, "01 WR"));
    s.faults().displace = 1;
    let r = raw.ask("/1 1 warnings clear").await;
    assert_eq!(r.data, "02 WR WM");
    assert_eq!(s.warning_flags(), vec![Warning::WR]);
    raw.ask("/1 1 home").await;
    let r = raw.ask("/1 1 warnings").await;
    assert_eq!((r.warning, r.data.as_str()), (Warning::NONE, "00"));
    // Faults outrank warnings in the reply's flag field.
    {
        let mut f = s.faults();
        f.limit_hit = 1;
    }
    raw.ask("/1 1 move abs 3000").await;
    while s.is_busy() {
        tokio::time::sleep(std::time::Duration::from_millis(2)).await;
    }
    s.faults().fault = 1;
    raw.ask("/1 1 move abs 9000").await;
    while s.is_busy() {
        tokio::time::sleep(std::time::Duration::from_millis(2)).await;
    }
    let r = raw.ask("/1 1").await;
    assert_eq!(r.warning, Warning::FF);
    let r = raw.ask("/1 1 warnings clear").await;
    assert_eq!(r.data, "02 WL FF");
    let r = raw.ask("/1 1 warnings").await;
    assert_eq!(r.data, "00");
}
