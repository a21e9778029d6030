//! Store tests that need the raw connection: STRICT tables, append-only triggers, and crash
//! safety (an uncommitted pose, a process killed in the middle of `commit_pose`).

use std::path::Path;
use std::process::Command;

use super::*;
use crate::dataset::PoseSet;

/// Env var naming the crash point the child process aborts at.
const CRASH_AT: &str = "CELLCAL_STORE_CRASH_AT";
/// Env var naming the database the child process writes.
const CRASH_DB: &str = "CELLCAL_STORE_CRASH_DB";

/// Fault injection inside `commit_pose`: abort the process (no destructors, no rollback)
/// when the environment asks for this point. Only the crash child sets the variable.
pub(crate) fn crash_point(name: &str) {
    if std::env::var(CRASH_AT).as_deref() == Ok(name) {
        std::process::abort();
    }
}

fn point(x: f64) -> PointRecord {
    PointRecord {
        x_mm: x,
        y_mm: 2.0,
        z_mm: 3.0,
        std_mm: [0.01, 0.02, 0.03],
        std_total_mm: 0.04,
        temperature_c: 20.5,
        pressure_mbar: 1013.0,
        humidity_pct: 40.0,
        stage_mm: 0.0,
        sent_at_ms: 1,
        received_at_ms: 2,
    }
}

/// A campaign of three ident poses (6 joints each); returns its id.
pub(crate) fn setup(store: &mut Store) -> i64 {
    let plan: Vec<PlannedPose> = (0..3)
        .map(|i| PlannedPose {
            index: i,
            set: PoseSet::Ident,
            order: i,
            q_rad: vec![0.1 * i as f64; 6],
        })
        .collect();
    let c = NewCampaign {
        name: "t".into(),
        created_at_ms: 0,
        model: "np".into(),
        seed: 1,
        config_toml: String::new(),
        robot_toml: String::new(),
    };
    store.create_campaign(&c, &plan).unwrap()
}

fn pose(index: usize) -> PoseMeasurement {
    PoseMeasurement {
        index,
        joints_rad: vec![0.1; 6],
        p1: point(1.0),
        p2: Some(point(101.0)),
    }
}

fn count(store: &mut Store, sql: &str) -> i64 {
    store.raw().query_row(sql, [], |r| r.get(0)).unwrap()
}

#[test]
fn strict_tables_refuse_wrong_types() {
    let mut s = Store::open_in_memory().unwrap();
    let id = setup(&mut s);
    let conn = s.raw();
    let bad = conn.execute(
        "INSERT INTO measurements (campaign_id, kind, x_mm, y_mm, z_mm, sent_at_ms, \
         received_at_ms) VALUES (?1, 'drift', 'abc', 0, 0, 0, 0)",
        [id],
    );
    assert!(bad.is_err(), "a string went into a REAL column");
    let bad = conn.execute(
        "INSERT INTO events (campaign_id, at_ms, kind, message) VALUES (?1, 'noon', 'k', 'm')",
        [id],
    );
    assert!(bad.is_err(), "a string went into an INTEGER column");
    let ok = conn.execute(
        "INSERT INTO measurements (campaign_id, kind, x_mm, y_mm, z_mm, sent_at_ms, \
         received_at_ms) VALUES (?1, 'drift', 1.5, 0, 0, 0, 0)",
        [id],
    );
    assert!(ok.is_ok(), "{ok:?}");
    let bad_kind = conn.execute(
        "INSERT INTO measurements (campaign_id, kind, x_mm, y_mm, z_mm, sent_at_ms, \
         received_at_ms) VALUES (?1, 'p3', 1.5, 0, 0, 0, 0)",
        [id],
    );
    assert!(bad_kind.is_err());
    let tables: i64 = conn
        .query_row(
            "SELECT count(*) FROM pragma_table_list WHERE schema = 'main' \
             AND name NOT LIKE 'sqlite_%' AND strict = 0",
            [],
            |r| r.get(0),
        )
        .unwrap();
    assert_eq!(tables, 0, "every table is STRICT");
}

#[test]
fn measurements_are_append_only() {
    let mut s = Store::open_in_memory().unwrap();
    let id = setup(&mut s);
    s.commit_pose(id, &pose(0)).unwrap();
    let conn = s.raw();
    assert!(conn
        .execute("UPDATE measurements SET x_mm = 0", [])
        .is_err());
    assert!(conn.execute("DELETE FROM measurements", []).is_err());
    assert_eq!(count(&mut s, "SELECT count(*) FROM measurements"), 2);
}

#[test]
fn dropped_transaction_leaves_no_half_pose() {
    let mut s = Store::open_in_memory().unwrap();
    let id = setup(&mut s);
    {
        let tx = s.raw().transaction().unwrap();
        tx.execute(
            "INSERT INTO measurements (campaign_id, pose_index, kind, x_mm, y_mm, z_mm, \
             sent_at_ms, received_at_ms, joints_rad) VALUES (?1, 0, 'p1', 1, 2, 3, 0, 0, '[0]')",
            [id],
        )
        .unwrap();
        // Dropped without commit: rolled back.
    }
    assert_eq!(s.done_poses(id).unwrap(), Vec::<usize>::new());
    assert_eq!(count(&mut s, "SELECT count(*) FROM measurements"), 0);
    s.commit_pose(id, &pose(0)).unwrap();
    assert_eq!(s.done_poses(id).unwrap(), vec![0]);
}

/// Child half of [`killed_mid_commit_leaves_no_half_pose`]: does nothing unless the parent
/// set the environment.
#[test]
fn crash_child() {
    let Ok(db) = std::env::var(CRASH_DB) else {
        return;
    };
    let mut s = Store::open(Path::new(&db)).unwrap();
    let id = s.latest_campaign().unwrap().unwrap();
    // Aborts the process after the P1 insert, inside the transaction.
    let _ = s.commit_pose(id, &pose(1));
    unreachable!("the crash point did not fire");
}

#[test]
fn killed_mid_commit_leaves_no_half_pose() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("campaign.sqlite");
    let id = {
        let mut s = Store::open(&db).unwrap();
        let id = setup(&mut s);
        s.commit_pose(id, &pose(0)).unwrap();
        id
    };
    let status = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "store::tests::crash_child", "--test-threads=1"])
        .env(CRASH_DB, &db)
        .env(CRASH_AT, "after_p1")
        .output()
        .unwrap();
    let aborted = {
        #[cfg(unix)]
        {
            use std::os::unix::process::ExitStatusExt;
            status.status.signal() == Some(6) // SIGABRT from the crash point
        }
        #[cfg(not(unix))]
        {
            !status.status.success()
        }
    };
    assert!(
        aborted,
        "the child should have aborted at the crash point ({}): {}",
        status.status,
        String::from_utf8_lossy(&status.stdout)
    );
    let mut s = Store::open(&db).unwrap();
    assert_eq!(s.done_poses(id).unwrap(), vec![0]);
    assert_eq!(
        count(
            &mut s,
            "SELECT count(*) FROM measurements WHERE pose_index = 1"
        ),
        0
    );
    assert_eq!(count(&mut s, "SELECT count(*) FROM measurements"), 2);
    s.commit_pose(id, &pose(1)).unwrap();
    assert_eq!(s.done_poses(id).unwrap(), vec![0, 1]);
}

#[test]
fn frame_references_number_segments_and_refuse_non_drift_points() {
    let mut s = Store::open_in_memory().unwrap();
    let id = setup(&mut s);
    assert!(s.frame_refs(id).unwrap().is_empty());
    let q = [0.1; 6];
    let d0 = s
        .add_point(
            id,
            PointKind::Drift,
            None,
            Some(&q),
            &point(1.0),
            "drift reference",
        )
        .unwrap();
    let no_joints = s
        .add_point(id, PointKind::Drift, None, None, &point(1.5), "drift")
        .unwrap();
    let setup_pt = s
        .add_point(id, PointKind::Setup, None, Some(&q), &point(2.0), "setup")
        .unwrap();
    let t = shift(5.0);
    assert!(matches!(
        s.add_frame_ref(id, d0, 0, Some(&t)),
        Err(StoreError::Invalid(_))
    ));
    assert_eq!(s.add_frame_ref(id, d0, 0, None).unwrap(), 0);
    for bad in [no_joints, setup_pt, 9999] {
        assert!(matches!(
            s.add_frame_ref(id, bad, 0, Some(&t)),
            Err(StoreError::Invalid(_))
        ));
    }
    let d1 = s
        .add_point(
            id,
            PointKind::Drift,
            None,
            Some(&q),
            &point(3.0),
            "re-registered",
        )
        .unwrap();
    assert!(matches!(
        s.add_frame_ref(id, d1, 2, None),
        Err(StoreError::Invalid(_))
    ));
    assert_eq!(s.add_frame_ref(id, d1, 2, Some(&t)).unwrap(), 1);
    let refs = s.frame_refs(id).unwrap();
    assert!(refs[0].to_first.is_none());
    assert_eq!(refs[1].to_first.as_ref().unwrap().points, 6);
    assert_eq!(refs.len(), 2);
    assert_eq!((refs[0].point.x_mm, refs[0].poses_done), (1.0, 0));
    assert_eq!(
        (refs[1].segment, refs[1].point.x_mm, refs[1].poses_done),
        (1, 3.0, 2)
    );
    assert_eq!(refs[1].joints_rad, q.to_vec());
    // append-only
    assert!(s.raw().execute("DELETE FROM frame_refs", []).is_err());
}

/// A frame transform: a quarter turn about z, then `dx` along x.
fn shift(dx: f64) -> FrameTransform {
    FrameTransform {
        to_first: crate::model::Pose::from_rotation_vector(
            &nalgebra::Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            nalgebra::Vector3::new(dx, 0.0, 0.0),
        ),
        rms_mm: 0.01,
        max_mm: 0.02,
        points: 6,
    }
}

#[test]
fn observations_of_a_re_registered_segment_are_mapped_into_the_first_frame() {
    let mut s = Store::open_in_memory().unwrap();
    let id = setup(&mut s);
    let q = [0.1; 6];
    let d0 = s
        .add_point(id, PointKind::Drift, None, Some(&q), &point(1.0), "ref")
        .unwrap();
    s.add_frame_ref(id, d0, 0, None).unwrap();
    s.commit_pose(id, &pose(0)).unwrap();
    let d1 = s
        .add_point(id, PointKind::Drift, None, Some(&q), &point(1.0), "ref 1")
        .unwrap();
    s.add_frame_ref(id, d1, 1, Some(&shift(5.0))).unwrap();
    s.commit_pose(id, &pose(1)).unwrap();
    let raw = s.measured_poses(id).unwrap();
    let obs = s.measured(id).map(identification_rows).unwrap();
    // segment 0 unchanged
    let p0 = &raw[0].1.p1;
    assert_eq!(obs[0].p1, nalgebra::Vector3::new(p0.x_mm, p0.y_mm, p0.z_mm));
    // segment 1: (x, y, z) -> (-y + 5, x, z), P2 too
    for (got, rec) in [
        (obs[1].p1, raw[1].1.p1),
        (obs[1].p2.unwrap(), raw[1].1.p2.unwrap()),
    ] {
        let want = nalgebra::Vector3::new(5.0 - rec.y_mm, rec.x_mm, rec.z_mm);
        assert!((got - want).norm() < 1e-12, "{got} vs {want}");
    }
    // the stored rows stay raw
    assert_eq!(raw[1].1.p1.x_mm, pose(1).p1.x_mm);
    // candidates of a re-registration: rows with joints at the stage position
    let pts = s.joint_points(id, 0..d1, 0.0).unwrap();
    assert!(pts.iter().any(|p| p.row == d0));
    assert!(pts.iter().all(|p| p.row < d1 && p.kind != "p2"));
}

/// Two commanders started together open one new store at the same instant: both get it open
/// (one is then refused by the cell lock, naming the other), neither fails on the journal-mode
/// switch, for which SQLite returns BUSY at once instead of calling the busy handler.
#[test]
fn processes_opening_one_new_store_at_once_all_open_it() {
    for round in 0..20 {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("c.db");
        let start = std::sync::Arc::new(std::sync::Barrier::new(6));
        let opened: Vec<Result<(), String>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..6)
                .map(|_| {
                    let (path, start) = (path.clone(), start.clone());
                    s.spawn(move || {
                        start.wait();
                        Store::open(&path).map(|_| ()).map_err(|e| e.to_string())
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("thread"))
                .collect()
        });
        for r in opened {
            assert!(r.is_ok(), "round {round}: {r:?}");
        }
    }
}
