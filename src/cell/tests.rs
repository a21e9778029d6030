//! Unit tests of the device boundary: how each driver's errors are classified (the engine's
//! fault policy acts on the class: beam broken → re-lock, disconnected → reconnect, …), which
//! classes are transient, the technician's one-line context, and the manual stage with an
//! in-memory gauge.

use std::sync::{Arc, Mutex};

use emscon::EmsconError;
use robotlink::RobotError;
use zaber::{GaugeError, StageError};

use super::robot_link::classify_robotlink;
use super::stage_manual::classify_gauge;
use super::stage_zaber::classify_zaber;
use super::tracker_emscon::classify_emscon;
use super::{
    Answer, CellError, DeviceKind, FaultKind, GaugeReader, ManualStage, ManualStageConfig,
    PromptContext, ScriptedPrompter, Stage, StagePosition,
};

fn io() -> std::io::Error {
    std::io::Error::other("gone")
}

#[test]
fn emscon_errors_map_to_the_classes_the_engine_recovers_from() {
    use FaultKind::*;
    let table = [
        (EmsconError::BeamBroken, BeamBroken),
        (EmsconError::TargetNotFound, BeamBroken),
        (EmsconError::NotInitialized, NotReady),
        (EmsconError::NotWarmedUp, NotReady),
        (EmsconError::Busy, NotReady),
        (EmsconError::ConnectionRefused, Disconnected),
        (EmsconError::Disconnected, Disconnected),
        (EmsconError::Io(io()), Disconnected),
        (EmsconError::Protocol("x".into()), Protocol),
    ];
    for (e, kind) in table {
        assert_eq!(classify_emscon(&e), kind, "{e:?}");
    }
}

#[test]
fn robotlink_errors_map_to_the_classes_the_engine_recovers_from() {
    use FaultKind::*;
    let table = [
        (RobotError::EStop("x".into()), EmergencyStop),
        (RobotError::PowerOff("x".into()), EmergencyStop),
        (RobotError::NotSettled("x".into()), Timeout),
        (RobotError::Timeout("WAIT"), Timeout),
        (RobotError::Stopped("x".into()), Aborted),
        (RobotError::Protocol("x".into()), Protocol),
        (RobotError::Disconnected, Disconnected),
        (RobotError::Auth("x".into()), Rejected),
    ];
    for (e, kind) in table {
        assert_eq!(classify_robotlink(&e), kind, "{e:?}");
    }
}

#[test]
fn zaber_and_gauge_errors_map_to_the_classes_the_engine_recovers_from() {
    use FaultKind::*;
    let table = [
        (StageError::NotHomed, Rejected),
        (StageError::Rejected("BADDATA".into()), Rejected),
        (StageError::OutOfRange(60.0), Rejected),
        (StageError::Fault("FF".into()), Device),
        (StageError::Interrupted, Device),
        (StageError::UnexpectedLimit, Device),
        (StageError::Displaced, Device),
        (StageError::Timeout("move"), Timeout),
        (StageError::Checksum, Protocol),
        (StageError::Protocol("x".into()), Protocol),
        (StageError::Disconnected, Disconnected),
        (StageError::Io(io()), Disconnected),
    ];
    for (e, kind) in table {
        assert_eq!(classify_zaber(&e), kind, "{e:?}");
    }
    let gauge = [
        (GaugeError::Timeout, Timeout),
        (GaugeError::WrongUnit("in".into()), Device),
        (GaugeError::OutOfRange(99.0), Device),
        (GaugeError::DeviceStatus("E".into()), Device),
        (GaugeError::Protocol("x".into()), Protocol),
        (GaugeError::Disconnected, Disconnected),
        (GaugeError::Io(io()), Disconnected),
    ];
    for (e, kind) in gauge {
        assert_eq!(classify_gauge(&e), kind, "{e:?}");
    }
}

#[test]
fn only_faults_a_reconnect_or_relock_can_fix_are_transient() {
    use FaultKind::*;
    for (kind, transient) in [
        (BeamBroken, true),
        (Timeout, true),
        (Disconnected, true),
        (NotReady, true),
        (Protocol, true),
        (Rejected, false),
        (EmergencyStop, false),
        (Aborted, false),
        (Device, false),
    ] {
        let e = CellError::new(DeviceKind::Tracker, kind, "m");
        assert_eq!(e.is_transient(), transient, "{kind:?}");
    }
    let e = CellError::new(DeviceKind::Stage, FaultKind::Rejected, "BADDATA");
    assert_eq!(e.to_string(), "stage Rejected: BADDATA");
}

#[test]
fn a_prompt_context_says_only_what_is_known() {
    let full = PromptContext {
        step: Some("pose".into()),
        pose: Some(3),
        poses_total: Some(20),
        position: Some(StagePosition::P2),
        robot_stopped: true,
        retry_reason: None,
    };
    assert_eq!(
        full.describe(),
        "pose 3 of 20 · P2 · robot stopped — safe to approach"
    );
    let drift = PromptContext {
        step: Some("drift".into()),
        position: Some(StagePosition::P1),
        ..PromptContext::default()
    };
    assert_eq!(
        drift.describe(),
        "drift check at the reference pose · P1 · robot state not known — check that it \
         stands still before approaching"
    );
    let unnumbered = PromptContext {
        pose: Some(4),
        robot_stopped: true,
        ..PromptContext::default()
    };
    assert_eq!(
        unnumbered.describe(),
        "pose 4 · robot stopped — safe to approach"
    );
    for (step, said) in [
        ("setup", "setup"),
        ("reregister", "re-registering the tracker frame"),
    ] {
        let c = PromptContext {
            step: Some(step.into()),
            ..PromptContext::default()
        };
        assert!(c.describe().starts_with(said), "{}", c.describe());
    }
}

/// A gauge answering from a list (then `Disconnected`), counting its readings.
struct ListGauge(Arc<Mutex<Vec<Result<f64, GaugeError>>>>);

#[async_trait::async_trait]
impl GaugeReader for ListGauge {
    /// Cancel-safe: no await.
    async fn read_mm(&mut self) -> Result<f64, GaugeError> {
        let mut q = self.0.lock().expect("gauge");
        if q.is_empty() {
            return Err(GaugeError::Disconnected);
        }
        q.remove(0)
    }
}

#[tokio::test]
async fn a_gauge_read_stage_takes_the_gauge_not_the_technician_and_classifies_its_faults() {
    let readings = Arc::new(Mutex::new(vec![
        Ok(5.0),   // prepare
        Ok(10.3),  // out of tolerance: asked again
        Ok(10.01), // accepted
        Err(GaugeError::Timeout),
    ]));
    let p = Arc::new(ScriptedPrompter::exact());
    let mut s = ManualStage::with_gauge(
        p.clone(),
        Box::new(ListGauge(Arc::clone(&readings))),
        ManualStageConfig::default(),
    );
    s.prepare().await.expect("the gauge answers");
    assert_eq!(s.move_to(10.0).await.expect("second reading"), 10.01);
    let asked = p.asked();
    assert_eq!(asked.len(), 2);
    assert_eq!(
        asked[0].text,
        "Move the micrometer to 10.000 mm and confirm"
    );
    assert!(
        asked[1]
            .context
            .retry_reason
            .as_deref()
            .is_some_and(|r| r.starts_with("The gauge reads 10.300 mm")),
        "{:?}",
        asked[1].context
    );
    let e = s.move_to(0.0).await.expect_err("gauge timeout");
    assert_eq!((e.device, e.kind), (DeviceKind::Stage, FaultKind::Timeout));
    let e = s.prepare().await.expect_err("gauge gone");
    assert_eq!(e.kind, FaultKind::Disconnected);
    let e = s.move_to(f64::NAN).await.expect_err("not a number");
    assert_eq!(e.kind, FaultKind::Rejected);
}

#[tokio::test]
async fn the_cell_is_confirmed_clear_only_by_the_clear_answer() {
    let p = Arc::new(ScriptedPrompter::from_answers([
        Answer::Confirmed,
        Answer::Number(0.0),
        Answer::Clear,
    ]));
    let mut s = ManualStage::new(p.clone(), ManualStageConfig::default());
    assert!(s.needs_clear());
    s.confirm_clear(PromptContext::default())
        .await
        .expect("the third answer");
    let asked = p.asked();
    assert_eq!(asked.len(), 3);
    assert!(asked.iter().all(|q| q.id == super::CONFIRM_CLEAR));
    assert!(asked[1].context.retry_reason.is_some());

    let p = Arc::new(ScriptedPrompter::from_answers(vec![Answer::Confirmed; 3]));
    let mut s = ManualStage::new(p, ManualStageConfig::default());
    let e = s
        .confirm_clear(PromptContext::default())
        .await
        .expect_err("never clear");
    assert_eq!(e.kind, FaultKind::Rejected);

    let p = Arc::new(ScriptedPrompter::from_answers([Answer::Abort]));
    let mut s = ManualStage::new(p, ManualStageConfig::default());
    let e = s
        .confirm_clear(PromptContext::default())
        .await
        .expect_err("aborted");
    assert_eq!(e.kind, FaultKind::Aborted);

    // switched off: nothing is asked
    let p = Arc::new(ScriptedPrompter::from_answers([]));
    let cfg = ManualStageConfig {
        confirm_clear: false,
        ..ManualStageConfig::default()
    };
    let mut s = ManualStage::new(p.clone(), cfg);
    assert!(!s.needs_clear());
    s.confirm_clear(PromptContext::default())
        .await
        .expect("nothing to confirm");
    assert!(p.asked().is_empty());
}
