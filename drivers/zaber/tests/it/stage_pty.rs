use std::time::Duration;

use zaber::{StageError, ZaberStage};

use crate::common::{stage_cfg, stage_on_pty, STEPS_PER_MM};

#[tokio::test]
async fn normal_session_over_real_pty() {
    let (sim, dev, mut st) = stage_on_pty(false);
    st.home().await.unwrap();
    assert!(sim.is_homed());
    let rb = st.move_abs_mm(12.345).await.unwrap();
    let half_step_mm = 0.5 / STEPS_PER_MM;
    assert!((rb - 12.345).abs() <= half_step_mm, "{rb}");
    assert_eq!(sim.position_steps(), (12.345 * STEPS_PER_MM).round() as i64);
    assert!((st.position_mm().await.unwrap() - 12.345).abs() <= half_step_mm);
    st.start_move_abs_mm(100.0).await.unwrap();
    st.poll_until_idle(Duration::from_secs(1)).await.unwrap();
    assert_eq!(sim.position_steps(), (100.0 * STEPS_PER_MM).round() as i64);
    st.stop().await.unwrap();
    // Close and reopen the same slave path (like re-opening a USB port).
    drop(st);
    let mut st = ZaberStage::open(&dev.path(), stage_cfg()).unwrap();
    assert!((st.position_mm().await.unwrap() - 100.0).abs() <= 0.5 / STEPS_PER_MM);
}

#[tokio::test]
async fn not_homed_and_lost_home() {
    let (sim, _dev, mut st) = stage_on_pty(false);
    let e = st.move_abs_mm(1.0).await.unwrap_err();
    assert!(matches!(e, StageError::NotHomed), "{e:?}");
    st.home().await.unwrap();
    st.move_abs_mm(1.0).await.unwrap();
    sim.faults().lose_home = 1;
    let e = st.move_abs_mm(2.0).await.unwrap_err();
    assert!(matches!(e, StageError::NotHomed), "{e:?}");
}

#[tokio::test]
async fn rejections_and_range() {
    let (sim, _dev, mut st) = stage_on_pty(true);
    for reason in ["BADCOMMAND", "BADDATA"] {
        {
            let mut f = sim.faults();
            f.reject = 1;
            f.reject_reason = reason.into();
        }
        let e = st.move_abs_mm(3.0).await.unwrap_err();
        assert!(
            matches!(e, StageError::Rejected(ref r) if r == reason),
            "{e:?}"
        );
    }
    let e = st.move_abs_mm(-1.0).await.unwrap_err();
    assert!(matches!(e, StageError::OutOfRange(v) if v == -1.0), "{e:?}");
    let e = st.move_abs_mm(f64::NAN).await.unwrap_err();
    assert!(matches!(e, StageError::OutOfRange(_)), "{e:?}");
    // Device-side limit (travel shorter than configured range).
    let e = st.move_abs_mm(2500.0).await.unwrap_err();
    assert!(
        matches!(e, StageError::Rejected(ref r) if r == "BADDATA"),
        "{e:?}"
    );
    st.move_abs_mm(3.0).await.unwrap();
}

#[tokio::test]
async fn stall_times_out_then_stop_recovers() {
    let (sim, _dev, mut st) = stage_on_pty(true);
    sim.faults().stall = 1;
    let e = st.move_abs_mm(50.0).await.unwrap_err();
    assert!(matches!(e, StageError::Timeout(_)), "{e:?}");
    assert!(sim.is_busy());
    st.stop().await.unwrap();
    assert!(!sim.is_busy());
    st.move_abs_mm(5.0).await.unwrap();
}

#[tokio::test]
async fn fault_interrupt_overshoot() {
    let (sim, _dev, mut st) = stage_on_pty(true);
    sim.faults().fault = 1;
    let e = st.move_abs_mm(30.0).await.unwrap_err();
    assert!(matches!(e, StageError::Fault(ref f) if f == "FF"), "{e:?}");
    // The latched fault is reported once more by `warnings clear`, then cleared.
    let e = st.move_abs_mm(30.0).await.unwrap_err();
    assert!(matches!(e, StageError::Fault(_)), "{e:?}");
    st.move_abs_mm(30.0).await.unwrap();

    sim.faults().interrupt = 1;
    let e = st.move_abs_mm(10.0).await.unwrap_err();
    assert!(matches!(e, StageError::Interrupted), "{e:?}");
    st.move_abs_mm(10.0).await.unwrap();

    {
        let mut f = sim.faults();
        f.overshoot = 1;
        f.overshoot_steps = 100;
    }
    let e = st.move_abs_mm(20.0).await.unwrap_err();
    match e {
        StageError::Mismatch {
            target_mm,
            readback_mm,
        } => {
            assert_eq!(target_mm, 20.0);
            let expected = 20.0 + 100.0 / STEPS_PER_MM;
            assert!(
                (readback_mm - expected).abs() <= 1.0 / STEPS_PER_MM,
                "{readback_mm}"
            );
        }
        e => panic!("{e:?}"),
    }
}

#[tokio::test]
async fn wire_faults_checksum_garbage_partial_silence() {
    let (sim, _dev, mut st) = stage_on_pty(true);
    sim.faults().bad_checksum = 1;
    assert!(matches!(st.position_mm().await, Err(StageError::Checksum)));
    st.position_mm().await.unwrap();

    sim.faults().garbage = 1;
    let e = st.position_mm().await.unwrap_err();
    assert!(matches!(e, StageError::Protocol(_)), "{e:?}");
    st.position_mm().await.unwrap();

    sim.faults().partial = 1;
    let e = st.position_mm().await.unwrap_err();
    assert!(matches!(e, StageError::Timeout(_)), "{e:?}");
    st.position_mm().await.unwrap();

    sim.faults().silence = 1;
    let e = st.position_mm().await.unwrap_err();
    assert!(matches!(e, StageError::Timeout(_)), "{e:?}");
    st.position_mm().await.unwrap();
}
