//! The campaign store through its public API (crash and STRICT tests live in
//! `src/store/tests.rs`, which needs the raw connection).

use cellcal::campaign::CampaignEvent;
use cellcal::dataset::{parse_csv, write_csv, Observation, PoseSet, Required};
use cellcal::store::identification_rows;
use cellcal::store::{
    schema_version, NewCampaign, PlannedPose, PointKind, PointRecord, PoseMeasurement, Store,
    StoreError, StoredState, IMPORTED_STATE, INITIAL_STATE,
};
use nalgebra::Vector3;

fn new_campaign(name: &str) -> NewCampaign {
    NewCampaign {
        name: name.into(),
        created_at_ms: 1_700_000_000_000,
        model: "np".into(),
        seed: u64::MAX - 7, // above i64::MAX: must survive the i64 column
        config_toml: "[stage]\ntravel_mm = 10.0\n".into(),
        robot_toml: "name = \"tx60\"\n".into(),
    }
}

/// Awkward but finite values, so a lossy encoding would show.
fn q(i: usize) -> Vec<f64> {
    (0..6)
        .map(|j| (i * 6 + j) as f64 * 0.123_456_789_012_345_67 - 1.0 / 3.0)
        .collect()
}

/// Five poses, moved in the order 4, 3, 2, 1, 0; poses 3 and 4 verify.
fn plan() -> Vec<PlannedPose> {
    (0..5)
        .map(|i| PlannedPose {
            index: i,
            set: if i >= 3 {
                PoseSet::Verify
            } else {
                PoseSet::Ident
            },
            order: 4 - i,
            q_rad: q(i),
        })
        .collect()
}

fn point(x: f64, t: i64) -> PointRecord {
    PointRecord {
        x_mm: x,
        y_mm: -x / 7.0,
        z_mm: 1e-9 + x.sqrt(),
        std_mm: [0.011, 0.012, 0.013],
        std_total_mm: 0.021,
        temperature_c: 20.3,
        pressure_mbar: 1012.7,
        humidity_pct: 41.5,
        stage_mm: 0.1 + 0.2,
        sent_at_ms: t,
        received_at_ms: t + 35,
    }
}

fn measurement(i: usize) -> PoseMeasurement {
    let x = 1000.0 / 3.0 + i as f64;
    PoseMeasurement {
        index: i,
        joints_rad: q(i).iter().map(|v| v + 1e-5 / 3.0).collect(),
        p1: point(x, 10 * i as i64),
        p2: Some(PointRecord {
            stage_mm: 10.0,
            ..point(x + 10.0 / 3.0, 10 * i as i64 + 5)
        }),
    }
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn count_measurements(path: &std::path::Path) -> i64 {
    let conn = rusqlite::Connection::open(path).unwrap();
    conn.query_row("SELECT count(*) FROM measurements", [], |r| r.get(0))
        .unwrap()
}

#[test]
fn create_and_read_back_campaign_and_plan() {
    let mut s = Store::open_in_memory().unwrap();
    assert_eq!(s.latest_campaign().unwrap(), None);
    let id = s.create_campaign(&new_campaign("a"), &plan()).unwrap();
    let row = s.campaign(id).unwrap();
    assert_eq!(row.name, "a");
    assert_eq!(row.seed, u64::MAX - 7);
    assert_eq!(row.state, INITIAL_STATE);
    assert_eq!(row.config_toml, new_campaign("a").config_toml);
    let mut expected = plan();
    expected.sort_by_key(|p| p.order);
    let got = s.plan(id).unwrap();
    assert_eq!(got, expected);
    for (g, e) in got.iter().zip(&expected) {
        assert_eq!(bits(&g.q_rad), bits(&e.q_rad));
    }
    let id2 = s.create_campaign(&new_campaign("b"), &plan()).unwrap();
    assert_eq!(s.latest_campaign().unwrap(), Some(id2));
    let names: Vec<String> = s
        .list_campaigns()
        .unwrap()
        .into_iter()
        .map(|c| c.name)
        .collect();
    assert_eq!(names, ["a", "b"]);
    assert!(matches!(s.campaign(999), Err(StoreError::NoCampaign(999))));
    assert!(matches!(s.plan(999), Err(StoreError::NoCampaign(999))));
}

#[test]
fn bad_plans_are_refused_whole() {
    let mut s = Store::open_in_memory().unwrap();
    let mut dup = plan();
    dup[1].index = 0;
    assert!(matches!(
        s.create_campaign(&new_campaign("x"), &dup),
        Err(StoreError::Invalid(_))
    ));
    assert!(matches!(
        s.create_campaign(&new_campaign("x"), &[]),
        Err(StoreError::Invalid(_))
    ));
    let mut nan = plan();
    nan[2].q_rad[3] = f64::NAN;
    assert!(s.create_campaign(&new_campaign("x"), &nan).is_err());
    assert_eq!(s.latest_campaign().unwrap(), None);
}

#[test]
fn commit_marks_done_and_duplicate_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.sqlite");
    let mut s = Store::open(&path).unwrap();
    let id = s.create_campaign(&new_campaign("a"), &plan()).unwrap();
    assert!(s.done_poses(id).unwrap().is_empty());
    s.commit_pose(id, &measurement(3)).unwrap();
    s.commit_pose(id, &measurement(1)).unwrap();
    assert_eq!(s.done_poses(id).unwrap(), vec![1, 3]);
    assert_eq!(count_measurements(&path), 4);

    let err = s.commit_pose(id, &measurement(3)).unwrap_err();
    assert!(matches!(
        err,
        StoreError::AlreadyMeasured {
            campaign,
            pose: 3
        } if campaign == id
    ));
    assert_eq!(count_measurements(&path), 4, "a rejected commit wrote rows");
    assert!(matches!(
        s.commit_pose(id, &measurement(7)),
        Err(StoreError::NotInPlan { pose: 7, .. })
    ));
    let mut short = measurement(2);
    short.joints_rad.pop();
    assert!(matches!(
        s.commit_pose(id, &short),
        Err(StoreError::Invalid(_))
    ));
    assert!(matches!(
        s.commit_pose(id + 1, &measurement(0)),
        Err(StoreError::NoCampaign(_))
    ));
    assert_eq!(count_measurements(&path), 4);
    assert_eq!(s.done_poses(id).unwrap(), vec![1, 3]);
}

#[test]
fn observations_are_bit_identical_in_plan_order() {
    let mut s = Store::open_in_memory().unwrap();
    let id = s.create_campaign(&new_campaign("a"), &plan()).unwrap();
    let mut no_p2 = measurement(0);
    no_p2.p2 = None;
    for m in [measurement(2), no_p2.clone(), measurement(4)] {
        s.commit_pose(id, &m).unwrap();
    }
    let obs = s.measured(id).map(identification_rows).unwrap();
    // Plan order is 4, 3, 2, 1, 0; measured: 4, 2, 0.
    let ids: Vec<&str> = obs.iter().map(|o| o.id.as_str()).collect();
    assert_eq!(ids, ["4", "2", "0"]);
    for o in &obs {
        let i: usize = o.id.parse().unwrap();
        let m = if i == 0 {
            no_p2.clone()
        } else {
            measurement(i)
        };
        assert_eq!(
            o.set,
            if i >= 3 {
                PoseSet::Verify
            } else {
                PoseSet::Ident
            }
        );
        assert_eq!(bits(&o.q), bits(&m.joints_rad), "q read after settling");
        assert_eq!(
            bits(o.p1.as_slice()),
            bits(&[m.p1.x_mm, m.p1.y_mm, m.p1.z_mm])
        );
        assert_eq!(
            o.p2.map(|p| bits(p.as_slice())),
            m.p2.map(|p| bits(&[p.x_mm, p.y_mm, p.z_mm]))
        );
        assert!(o.rotation.is_none());
    }
    // Full records too.
    let full = s.measured_poses(id).unwrap();
    assert_eq!(full[0].1, measurement(4));
    assert_eq!(full[2].1, no_p2);
}

#[test]
fn reopen_finds_everything() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.sqlite");
    let (id, obs) = {
        let mut s = Store::open(&path).unwrap();
        let id = s.create_campaign(&new_campaign("a"), &plan()).unwrap();
        s.commit_pose(id, &measurement(0)).unwrap();
        s.commit_pose(id, &measurement(4)).unwrap();
        s.add_point(
            id,
            PointKind::Drift,
            None,
            None,
            &point(5.0, 99),
            "drift check",
        )
        .unwrap();
        s.add_point(
            id,
            PointKind::Discarded,
            Some(2),
            Some(&q(2)),
            &point(6.0, 98),
            "beam",
        )
        .unwrap();
        assert!(matches!(
            s.add_point(id, PointKind::Setup, Some(9), None, &point(1.0, 0), ""),
            Err(StoreError::NotInPlan { pose: 9, .. })
        ));
        s.add_event(
            id,
            42,
            &CampaignEvent::Note {
                text: "pose 0".into(),
            },
        )
        .unwrap();
        s.set_state(id, StoredState::Running).unwrap();
        assert!(s.latest_result(id).unwrap().is_none());
        s.save_result(id, "np", "{\"rms\": 1}").unwrap();
        s.save_result(id, "np", "{\"rms\": 0.5}").unwrap();
        assert!(matches!(
            s.save_result(id, "np", "{oops"),
            Err(StoreError::Invalid(_))
        ));
        (id, s.measured(id).map(identification_rows).unwrap())
    };
    let s = Store::open(&path).unwrap();
    assert_eq!(s.user_version().unwrap(), schema_version());
    assert_eq!(s.latest_campaign().unwrap(), Some(id));
    assert_eq!(s.campaign(id).unwrap().state, StoredState::Running);
    assert_eq!(s.done_poses(id).unwrap(), vec![0, 4]);
    assert_eq!(s.measured(id).map(identification_rows).unwrap(), obs);
    assert_eq!(
        s.events::<CampaignEvent>(id).unwrap()[0].event,
        CampaignEvent::Note {
            text: "pose 0".into()
        }
    );
    assert_eq!(
        s.latest_result(id).unwrap().as_deref(),
        Some("{\"rms\": 0.5}")
    );
    assert_eq!(count_measurements(&path), 6);
    let mut plan_sorted = plan();
    plan_sorted.sort_by_key(|p| p.order);
    assert_eq!(s.plan(id).unwrap(), plan_sorted);
    let mode: String = rusqlite::Connection::open(&path)
        .unwrap()
        .query_row("PRAGMA journal_mode", [], |r| r.get(0))
        .unwrap();
    assert_eq!(mode, "wal");
}

#[test]
fn newer_schema_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.sqlite");
    {
        let s = Store::open(&path).unwrap();
        assert_eq!(s.user_version().unwrap(), schema_version());
        assert!(schema_version() >= 1);
    }
    // Reopening an up-to-date file changes nothing.
    drop(Store::open(&path).unwrap());
    {
        let conn = rusqlite::Connection::open(&path).unwrap();
        conn.pragma_update(None, "user_version", schema_version() + 1)
            .unwrap();
    }
    match Store::open(&path) {
        Err(StoreError::SchemaTooNew { found, known }) => {
            assert_eq!((found, known), (schema_version() + 1, schema_version()));
        }
        other => panic!("expected SchemaTooNew, got {other:?}"),
    }
}

fn rows() -> Vec<Observation> {
    (0..4)
        .map(|i| Observation {
            line: 0,
            id: format!("{}", 10 + i),
            set: if i == 3 {
                PoseSet::Verify
            } else {
                PoseSet::Ident
            },
            q: q(i),
            p1: Vector3::new(0.1 * i as f64, 1.0 / 3.0, -2.0 / 7.0),
            p2: Some(Vector3::new(10.1, 1.0 / 3.0, -2.0 / 7.0)),
            rotation: None,
        })
        .collect()
}

#[test]
fn import_then_observations_round_trip() {
    let mut s = Store::open_in_memory().unwrap();
    let id = s
        .import_observations(&new_campaign("imp"), &rows())
        .unwrap();
    assert_eq!(s.campaign(id).unwrap().state, IMPORTED_STATE);
    assert_eq!(s.done_poses(id).unwrap(), vec![10, 11, 12, 13]);
    assert_eq!(s.measured(id).map(identification_rows).unwrap(), rows());

    // Export as CSV, parse, import again: the same observations (ids kept).
    let csv = write_csv(
        &s.measured(id).map(identification_rows).unwrap(),
        6,
        "export",
    );
    let parsed = parse_csv(&csv, 6, Required::default()).unwrap();
    let id2 = s
        .import_observations(&new_campaign("again"), &parsed)
        .unwrap();
    let back: Vec<Observation> = s.measured(id2).map(identification_rows).unwrap();
    assert_eq!(back, rows());

    // Non-numeric ids: row numbers.
    let mut named = rows();
    for (i, r) in named.iter_mut().enumerate() {
        r.id = format!("p{i}");
    }
    let id3 = s
        .import_observations(&new_campaign("named"), &named)
        .unwrap();
    assert_eq!(s.done_poses(id3).unwrap(), vec![0, 1, 2, 3]);

    // Rotations cannot be kept: refused, nothing written.
    let mut rot = rows();
    rot[0].rotation = Some(Box::new(nalgebra::Matrix3::identity()));
    assert!(matches!(
        s.import_observations(&new_campaign("rot"), &rot),
        Err(StoreError::Invalid(_))
    ));
    assert_eq!(s.latest_campaign().unwrap(), Some(id3));
}
