//! A campaign that stops when it has enough (`campaign.stop_when = "predicted"`), on the
//! simulated cell over the real protocols: it stops measuring identification poses, measures
//! every verification pose, says why in the journal and the stored result, keeps its decision
//! across a kill -9 and a resume; bad stop keys are refused naming file and key.

use std::collections::BTreeSet;
use std::time::Duration;

use cellcal::calibrate::{CalibrationResult, IdentCheck, StopReason};
use cellcal::campaign::CampaignEvent;
use cellcal::dataset::PoseSet;
use cellcal::store::Store;

use crate::campaign::{config_text, run_in_process, write_config};

/// The ident and verify poses a stored campaign planned and measured:
/// `((ident planned, ident done), (verify planned, verify done))`, and the done ident poses.
fn counts(store: &Store, id: i64) -> ((usize, usize), (usize, usize), BTreeSet<usize>) {
    let plan = store.plan(id).expect("plan");
    let done: BTreeSet<usize> = store.done_poses(id).expect("done").into_iter().collect();
    let of = |set: PoseSet| {
        let planned: Vec<usize> = plan
            .iter()
            .filter(|p| p.set == set)
            .map(|p| p.index)
            .collect();
        let done = planned.iter().filter(|i| done.contains(i)).count();
        (planned.len(), done)
    };
    let ident_done = plan
        .iter()
        .filter(|p| p.set == PoseSet::Ident && done.contains(&p.index))
        .map(|p| p.index)
        .collect();
    (of(PoseSet::Ident), of(PoseSet::Verify), ident_done)
}

/// The `ident_stopped` events of a stored campaign's journal.
fn stop_events(store: &Store, id: i64) -> Vec<CampaignEvent> {
    store
        .events::<CampaignEvent>(id)
        .expect("events")
        .into_iter()
        .filter(|e| e.event.kind() == "ident_stopped")
        .map(|e| e.event)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_predicted_stop_measures_fewer_ident_poses_all_verify_poses_and_says_why() {
    let full = run_in_process(&config_text("", "", "")).await;
    let early = run_in_process(&config_text("", "stop_when = \"predicted\"", "")).await;
    let s = Store::open(&early.store).expect("store");
    let ((ident_planned, ident_done), (verify_planned, verify_done), _) = counts(&s, early.id);
    let stop = early
        .report
        .ident_stop
        .clone()
        .expect("ident_stop in the result");
    let (before, after) = (full.report_after_mm, early.report_after_mm);
    eprintln!(
        "stop rule: {ident_done} of {ident_planned} ident poses, verification {after:.5} mm vs \
         {before:.5} mm with all ({:+.1} %); history {:?}",
        100.0 * (after / before - 1.0),
        stop.history
            .iter()
            .map(|c| (c.after_poses, c.predicted_mm, c.gain))
            .collect::<Vec<_>>()
    );
    assert!(
        full.report.ident_stop.is_none(),
        "a planned campaign has none"
    );
    // it stopped early, for the gain, and measured the whole verification set
    assert_eq!(stop.reason, StopReason::MinGain);
    assert!(
        ident_done < ident_planned,
        "{ident_done} of {ident_planned}"
    );
    assert_eq!(
        (stop.ident_measured, stop.ident_planned),
        (ident_done, ident_planned)
    );
    assert_eq!(
        verify_done, verify_planned,
        "every verification pose measured"
    );
    let last = stop.history.last().expect("history");
    assert_eq!(last.after_poses, ident_done);
    assert_eq!(last.stopped, Some(StopReason::MinGain));
    assert!(last.gain.expect("gain") < 0.02);
    assert!(stop.history[..stop.history.len() - 1]
        .iter()
        .all(|c| c.stopped.is_none() && c.gain.is_none_or(|g| g >= 0.02)));
    // the identification used the measured ident poses only
    assert_eq!(early.report.metrics.ident.after.poses, ident_done);
    // the journal says so, and the stored result keeps it
    let events = stop_events(&s, early.id);
    let [CampaignEvent::IdentStopped {
        after_poses,
        skipped,
        reason,
        history,
        ..
    }] = events.as_slice()
    else {
        panic!("one ident_stopped event: {events:?}");
    };
    assert_eq!(
        (*after_poses, *skipped, *reason),
        (ident_done, ident_planned - ident_done, StopReason::MinGain)
    );
    assert_eq!(history, &stop.history);
    let stored = CalibrationResult::from_stored_json(
        &s.latest_result(early.id).expect("read").expect("result"),
    )
    .expect("stored result");
    assert_eq!(stored.report.ident_stop.as_ref(), Some(&stop));
    // and the verification error is within a few % of the full campaign's
    assert!(
        after <= 1.05 * before,
        "verification {after:.5} mm with {ident_done} ident poses vs {before:.5} mm with all"
    );
}

#[test]
fn bad_stop_keys_exit_2_naming_file_and_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (text, want) in [
        ("[campaign]\nstop_when = \"sometimes\"\n", "stop_when"),
        (
            "[campaign]\nstop_min_gain = -0.1\n",
            "campaign.stop_min_gain",
        ),
        (
            "[campaign]\nstop_min_gain = 1.5\n",
            "campaign.stop_min_gain",
        ),
        (
            "[campaign]\nstop_min_gain = nan\n",
            "campaign.stop_min_gain",
        ),
        (
            "[campaign]\ntarget_verify_mm = 0.0\n",
            "campaign.target_verify_mm",
        ),
        (
            "[campaign]\ntarget_verify_mm = -0.03\n",
            "campaign.target_verify_mm",
        ),
        (
            "[campaign]\ntarget_verify_mm = inf\n",
            "campaign.target_verify_mm",
        ),
        ("[campaign]\nstop_block = 0\n", "campaign.stop_block"),
        ("[campaign]\nstop_block = 101\n", "campaign.stop_block"),
        ("[campaign]\nstop_block = -5\n", "stop_block"),
        (
            "[campaign]\nstop_when = \"predicted\"\n[iso9283]\ncompensated_model = \"id.toml\"\n",
            "campaign.stop_when",
        ),
    ] {
        let p = dir.path().join("bad.toml");
        std::fs::write(&p, text).expect("write");
        let out = std::process::Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
            .args(["run", "--config"])
            .arg(&p)
            .output()
            .expect("runs");
        assert_eq!(out.status.code(), Some(2), "{text}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("bad.toml") && err.contains(want),
            "{text}: {err}"
        );
    }
}
