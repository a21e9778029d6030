use super::*;
use crate::calibrate::SetupResult;
use crate::cell::{DeviceKind, FaultKind};
use crate::plan::PlanEntry;

/// A plan of `ident` identification poses then verification poses, `total` in all.
fn plan(total: usize, ident: usize) -> Plan {
    Plan {
        poses: (0..total)
            .map(|index| PlanEntry {
                index,
                set: if index < ident {
                    PoseSet::Ident
                } else {
                    PoseSet::Verify
                },
                q_rad: vec![0.0; 6],
            })
            .collect(),
        drift_reference: vec![0.0; 6],
        via_points: 0,
        approach: Default::default(),
        sampling_order_s: 0.0,
        planned_order_s: 0.0,
    }
}

/// Feeds events at journal times (s) and keeps the lines.
struct Feed {
    p: Progress,
    seq: i64,
}

impl Feed {
    fn new(total: usize, ident: usize) -> Feed {
        Feed {
            p: Progress::new(&plan(total, ident)),
            seq: 0,
        }
    }

    fn at(&mut self, t_s: f64, event: CampaignEvent) -> Option<String> {
        self.seq += 1;
        self.p.line(&Journalled {
            seq: self.seq,
            at_ms: 1_795_000_000_000 + (t_s * 1000.0) as i64,
            event,
        })
    }

    fn state(&mut self, t_s: f64, state: CampaignState) -> String {
        self.at(t_s, CampaignEvent::State { state }).expect("line")
    }

    fn pose(&mut self, t_s: f64, pose: usize, done: usize, total: usize) -> String {
        let e = CampaignEvent::Measured {
            pose,
            done,
            total,
            p1_mm: [0.0; 3],
            deviation_mm: Some(0.0214),
            deviation_xyz_mm: None,
        };
        self.at(t_s, e).expect("line")
    }

    fn fault(&mut self, t_s: f64) -> String {
        let e = CampaignEvent::fault(
            DeviceKind::Tracker,
            FaultKind::BeamBroken,
            "beam broken",
            "relock",
        );
        self.at(t_s, e).expect("line")
    }
}

#[test]
fn the_pose_line_has_the_contract_s_shape() {
    let mut f = Feed::new(300, 100);
    assert_eq!(f.state(0.0, CampaignState::Armed), "state armed");
    assert_eq!(
        f.state(2.0, CampaignState::Running),
        "state running · elapsed 0.0 s · faults 0"
    );
    // pose index 7 is an identification pose, index 250 a verification pose
    assert_eq!(
        f.pose(12.0, 7, 1, 300),
        "pose 1/300 ident · elapsed 10.0 s · left ~49 min 50 s · last 0.021 mm · faults 0"
    );
    assert!(f
        .pose(14.0, 250, 2, 300)
        .starts_with("pose 2/300 verify · "));
}

#[test]
fn time_left_is_the_pace_of_the_poses_measured_so_far_without_setup_and_pauses() {
    let mut f = Feed::new(10, 5);
    f.state(0.0, CampaignState::Armed);
    f.state(1.0, CampaignState::Running);
    // 30 s of setup: measured once, not part of the pace
    let setup = CampaignEvent::Setup {
        result: Box::new(SetupResult::default()),
    };
    assert_eq!(
        f.at(31.0, setup).as_deref(),
        Some("setup measured: nothing to measure · elapsed 30.0 s · faults 0")
    );
    // the first pose 4 s after the setup: 9 poses left at 4 s
    assert!(f.pose(35.0, 0, 1, 10).contains("left ~36.0 s"));
    // then 2 s a pose: 8 poses left at 2 s (the first pose's setup share is gone)
    assert!(f.pose(37.0, 1, 2, 10).contains("left ~16.0 s"));
    // a pause of 100 s counts in elapsed, not in the pace
    let paused = CampaignState::Paused {
        reason: "paused by the operator".into(),
    };
    assert_eq!(
        f.state(38.0, paused),
        "state paused: paused by the operator · elapsed 37.0 s · faults 0"
    );
    assert_eq!(
        f.state(138.0, CampaignState::Running),
        "state resumed · elapsed 2 min 17 s · faults 0"
    );
    let line = f.pose(141.0, 2, 3, 10);
    // poses 2 and 3 in 2 + 1 + 3 s of measuring since pose 1: 3 s a pose, 7 left
    assert!(line.contains("elapsed 2 min 20 s · left ~21.0 s"), "{line}");
    let last = f.pose(143.0, 3, 10, 10);
    assert!(last.contains(" · left 0 s · "), "{last}");
}

#[test]
fn faults_are_counted_in_every_later_line() {
    let mut f = Feed::new(4, 2);
    f.state(0.0, CampaignState::Running);
    assert_eq!(
        f.fault(1.0),
        "fault tracker BeamBroken (relock): beam broken · elapsed 1.0 s · faults 1"
    );
    f.fault(1.5);
    assert!(f.pose(2.0, 0, 1, 4).ends_with("last 0.021 mm · faults 2"));
    assert_eq!(f.p.faults(), 2);
    assert_eq!(
        f.state(3.0, CampaignState::Aborted),
        "state aborted · elapsed 3.0 s · faults 2"
    );
}

#[test]
fn a_pose_without_a_deviation_or_set_and_a_result_without_a_line() {
    let mut f = Feed::new(2, 1);
    f.state(0.0, CampaignState::Running);
    let e = CampaignEvent::Measured {
        pose: 99,
        done: 1,
        total: 2,
        p1_mm: [0.0; 3],
        deviation_mm: None,
        deviation_xyz_mm: None,
    };
    assert_eq!(
        f.at(1.0, e).as_deref(),
        Some("pose 1/2 · elapsed 1.0 s · left ~1.0 s · last n/a · faults 0")
    );
    let result = CampaignEvent::Result {
        json: serde_json::Value::Null,
    };
    assert_eq!(f.at(2.0, result), None);
    let drift = CampaignEvent::Drift {
        drift_mm: 0.0041,
        max_mm: 0.1,
    };
    assert_eq!(
        f.at(3.0, drift).as_deref(),
        Some("drift 0.004 mm (max 0.100 mm) · elapsed 3.0 s · faults 0")
    );
}

#[test]
fn numbers_for_people() {
    assert_eq!(fmt_mm(0.0214), "0.021");
    assert_eq!(fmt_mm(-122.2478), "-122.248");
    assert_eq!(fmt_mm(-0.0001), "0.000");
    assert_eq!(fmt_duration(Duration::from_millis(21_840)), "21.8 s");
    assert_eq!(fmt_duration(Duration::from_millis(59_960)), "1 min 00 s");
    assert_eq!(fmt_duration(Duration::from_secs(250)), "4 min 10 s");
    assert_eq!(fmt_duration(Duration::from_secs(3_900)), "1 h 05 min");
    assert_eq!(fmt_duration(Duration::from_secs(3_599)), "59 min 59 s");
}

#[test]
fn an_ident_stop_says_which_gain_stopped_it() {
    use crate::calibrate::{IdentCheck, StopReason};
    let check = |reason| IdentCheck {
        after_poses: 64,
        predicted_mm: 0.0246,
        noise_floor_mm: 0.022,
        gain: Some(0.008),
        stopped: Some(reason),
        predicted_all_mm: Some(0.0241),
        remaining_gain: Some(0.019),
        held_back: Vec::new(),
    };
    let mut f = Feed::new(100, 60);
    let mut line = |reason| {
        f.at(
            1.0,
            CampaignEvent::IdentStopped {
                after_poses: 64,
                skipped: 36,
                reason,
                predicted_mm: 0.0246,
                history: vec![check(reason)],
            },
        )
        .expect("a line")
    };
    let min = line(StopReason::MinGain);
    assert!(min.contains("the last block gained 0.8 %"), "{min}");
    let rest = line(StopReason::RemainingGain);
    assert!(
        rest.contains("the poses still planned would gain 1.9 %"),
        "{rest}"
    );
}
