//! The typed journal: every event kind goes into the store typed and comes out typed, as the
//! same JSON text as before the journal was typed (literal strings below); an old or unknown row
//! never makes a journal unreadable; only `store/` owns a lock over a `Store`.

use std::path::{Path, PathBuf};

use crate::common::rust_files;

use cellcal::calibrate::{IdentCheck, StopReason};
use cellcal::campaign::engine::{BaseResult, SetupResult, ToolFrameResult};
use cellcal::campaign::events::UnknownEvent;
use cellcal::campaign::{CampaignEvent, CampaignState};
use cellcal::cell::{DeviceKind, FaultKind, PromptContext, StagePosition};
use cellcal::dataset::PoseSet;
use cellcal::store::{JournalEvent, NewCampaign, PlannedPose, Store, StoredState};

fn campaign(s: &mut Store) -> i64 {
    let new = NewCampaign {
        name: "journal".into(),
        created_at_ms: 1,
        model: "np".into(),
        seed: 1,
        config_toml: String::new(),
        robot_toml: String::new(),
    };
    let plan = [PlannedPose {
        index: 0,
        set: PoseSet::Ident,
        order: 0,
        q_rad: vec![0.0; 6],
    }];
    s.create_campaign(&new, &plan).expect("campaign")
}

/// Every variant, with the JSON text today's journal holds for it (field order of the
/// declaration; a setup result's and an identification result's keys sorted, since both were
/// written through a JSON value).
fn every_variant() -> Vec<(CampaignEvent, &'static str)> {
    vec![
        (
            CampaignEvent::State {
                state: CampaignState::Running,
            },
            r#"{"event":"state","state":{"state":"running"}}"#,
        ),
        (
            CampaignEvent::State {
                state: CampaignState::Paused {
                    reason: "tracker: beam".into(),
                },
            },
            r#"{"event":"state","state":{"state":"paused","reason":"tracker: beam"}}"#,
        ),
        (
            CampaignEvent::State {
                state: CampaignState::Failed { reason: "x".into() },
            },
            r#"{"event":"state","state":{"state":"failed","reason":"x"}}"#,
        ),
        (
            CampaignEvent::Measured {
                pose: 4,
                done: 2,
                total: 20,
                p1_mm: [0.1 + 0.2, -1_234.567_890_123_456_7, 1e-300],
                deviation_mm: Some(0.123_456_789_012_345_68),
                deviation_xyz_mm: None,
            },
            r#"{"event":"measured","pose":4,"done":2,"total":20,"p1_mm":[0.30000000000000004,-1234.5678901234567,1e-300],"deviation_mm":0.12345678901234568,"deviation_xyz_mm":null}"#,
        ),
        (
            CampaignEvent::fault(
                DeviceKind::Tracker,
                FaultKind::BeamBroken,
                "beam broken",
                "relock",
            ),
            r#"{"event":"fault","device":"tracker","kind":"BeamBroken","message":"beam broken","action":"relock"}"#,
        ),
        (
            CampaignEvent::fault(
                DeviceKind::Operator,
                FaultKind::EmergencyStop,
                "e-stop",
                "pause",
            ),
            r#"{"event":"fault","device":"operator","kind":"EmergencyStop","message":"e-stop","action":"pause"}"#,
        ),
        (
            CampaignEvent::Drift {
                drift_mm: 0.012,
                max_mm: 0.05,
            },
            r#"{"event":"drift","drift_mm":0.012,"max_mm":0.05}"#,
        ),
        (
            CampaignEvent::Setup {
                result: Box::new(SetupResult {
                    tool_frame: Some(ToolFrameResult {
                        tool_mm: [1.0, 2.0, 150.25],
                        stage_axis: [0.0, 0.0, 1.0],
                        flange_origin_tracker_mm: [1000.5, -2.0, 3.0],
                        flange_axes_tracker: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                        sphere_radius_mm: 150.26,
                        sphere_rms_mm: 0.004,
                        jog_axes_angle_deg: 90.01,
                        stage_travel_measured_mm: 25.002,
                        targets: 12,
                    }),
                    base: Some(BaseResult {
                        translation_mm: [2000.0, 0.5, -10.0],
                        rotation_vector_rad: [0.0, 0.0, 0.1],
                        rms_mm: 0.3,
                        max_mm: 0.6,
                        tracker_in_base_mm: [-2000.0, 1.0, 10.0],
                        poses: 6,
                    }),
                }),
            },
            r#"{"event":"setup","result":{"base":{"max_mm":0.6,"poses":6,"rms_mm":0.3,"rotation_vector_rad":[0.0,0.0,0.1],"tracker_in_base_mm":[-2000.0,1.0,10.0],"translation_mm":[2000.0,0.5,-10.0]},"tool_frame":{"flange_axes_tracker":[[1.0,0.0,0.0],[0.0,1.0,0.0],[0.0,0.0,1.0]],"flange_origin_tracker_mm":[1000.5,-2.0,3.0],"jog_axes_angle_deg":90.01,"sphere_radius_mm":150.26,"sphere_rms_mm":0.004,"stage_axis":[0.0,0.0,1.0],"stage_travel_measured_mm":25.002,"targets":12,"tool_mm":[1.0,2.0,150.25]}}}"#,
        ),
        (
            CampaignEvent::Setup {
                result: Box::default(),
            },
            r#"{"event":"setup","result":{"base":null,"tool_frame":null}}"#,
        ),
        (
            CampaignEvent::Prompt {
                seq: 3,
                id: "stage_move".into(),
                text: "Move the stage to 25 mm".into(),
                expected_mm: Some(25.0),
                context: PromptContext {
                    step: Some("pose".into()),
                    pose: Some(2),
                    poses_total: Some(20),
                    position: Some(StagePosition::P2),
                    robot_stopped: true,
                    retry_reason: None,
                },
            },
            r#"{"event":"prompt","seq":3,"id":"stage_move","text":"Move the stage to 25 mm","expected_mm":25.0,"step":"pose","pose":2,"poses_total":20,"position":"P2","robot_stopped":true,"retry_reason":null}"#,
        ),
        (
            CampaignEvent::Devices {
                tracker: Some("AT960 #1".into()),
                robot: None,
                stage: Some("X-LSM".into()),
            },
            r#"{"event":"devices","tracker":"AT960 #1","robot":null,"stage":"X-LSM"}"#,
        ),
        (
            CampaignEvent::Stopped {
                reason: "abort".into(),
                robot: "stopped".into(),
                stage: "manual".into(),
            },
            r#"{"event":"stopped","reason":"abort","robot":"stopped","stage":"manual"}"#,
        ),
        (
            CampaignEvent::IdentStopped {
                after_poses: 30,
                skipped: 70,
                reason: StopReason::MinGain,
                predicted_mm: 0.03,
                history: vec![IdentCheck {
                    after_poses: 30,
                    predicted_mm: 0.03,
                    noise_floor_mm: 0.025,
                    gain: Some(0.01),
                    stopped: Some(StopReason::MinGain),
                    predicted_all_mm: None,
                    remaining_gain: None,
                    held_back: Vec::new(),
                }],
            },
            r#"{"event":"ident_stopped","after_poses":30,"skipped":70,"reason":"min_gain","predicted_mm":0.03,"history":[{"after_poses":30,"predicted_mm":0.03,"noise_floor_mm":0.025,"gain":0.01,"stopped":"min_gain"}]}"#,
        ),
        (
            CampaignEvent::Note {
                text: "took over \"the\" cell".into(),
            },
            r#"{"event":"note","text":"took over \"the\" cell"}"#,
        ),
        (
            CampaignEvent::Result {
                json: serde_json::json!({"quality": "ok", "metrics": {"rms": 0.25}}),
            },
            r#"{"event":"result","json":{"metrics":{"rms":0.25},"quality":"ok"}}"#,
        ),
    ]
}

/// The `(kind, message)` columns of the campaign's journal rows.
fn stored_rows(path: &Path, id: i64) -> Vec<(String, String)> {
    let conn = rusqlite::Connection::open(path).expect("open");
    let mut st = conn
        .prepare("SELECT kind, message FROM events WHERE campaign_id = ?1 ORDER BY id")
        .expect("query");
    st.query_map([id], |r| Ok((r.get(0)?, r.get(1)?)))
        .expect("rows")
        .collect::<Result<_, _>>()
        .expect("rows")
}

fn temp_store() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("journal.sqlite");
    (dir, path)
}

#[test]
fn every_event_kind_round_trips_through_the_store_as_todays_json() {
    let (_dir, path) = temp_store();
    let mut s = Store::open(&path).expect("store");
    let id = campaign(&mut s);
    let cases = every_variant();
    for (i, (event, _)) in cases.iter().enumerate() {
        s.add_event(id, 1000 + i as i64, event).expect("journal");
    }
    // on disk: the kind column and today's text
    let rows = stored_rows(&path, id);
    assert_eq!(rows.len(), cases.len());
    for ((event, json), (kind, text)) in cases.iter().zip(&rows) {
        assert_eq!(kind, event.kind());
        assert_eq!(text, json, "{kind}");
    }
    // read back typed, by the writer and by a reader; written again, the same text
    let reader = Store::open_reader(&path).expect("reader");
    for back in [s.events::<CampaignEvent>(id), reader.events(id)] {
        let back = back.expect("events");
        for (i, ((event, json), e)) in cases.iter().zip(&back).enumerate() {
            assert_eq!(&e.event, event);
            assert_eq!(e.at_ms, 1000 + i as i64);
            assert_eq!(serde_json::to_string(&e.event).expect("json"), *json);
        }
    }
    // the state's stored names are its serde names
    for st in StoredState::ALL {
        assert_eq!(
            serde_json::to_string(&st).expect("json"),
            format!("\"{}\"", st.name())
        );
        assert_eq!(StoredState::from_name(st.name()), Some(st));
    }
}

#[test]
fn an_event_read_back_is_the_same_text_to_the_last_digit() {
    // shortest round-trip floats of every magnitude, parsed back exactly (serde_json's default
    // float parser may be one ulp off; the journal's is not)
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for _ in 0..20_000 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let v = f64::from_bits(x);
        if !v.is_finite() {
            continue;
        }
        let e = CampaignEvent::Drift {
            drift_mm: v,
            max_mm: v / 3.0,
        };
        let text = e.to_text().expect("text");
        let back = CampaignEvent::from_stored("drift".into(), text.clone());
        assert_eq!(back, e, "{text}");
        assert_eq!(back.to_text().expect("text"), text);
    }
}

#[test]
fn an_old_or_unknown_journal_row_still_loads_and_is_served_as_stored() {
    let (_dir, path) = temp_store();
    let mut s = Store::open(&path).expect("store");
    let id = campaign(&mut s);
    drop(s);
    let old = [
        // an early journal: a kind of its own and plain text
        ("pose_done", "pose 0"),
        // a `measured` event from before the deviation fields: read typed, fields null
        (
            "measured",
            r#"{"event":"measured","pose":1,"done":1,"total":9,"p1_mm":[1.0,2.0,3.0]}"#,
        ),
        // a kind this cellcal does not know
        (
            "calibrated_gauge",
            r#"{"event":"calibrated_gauge","offset_mm":0.5}"#,
        ),
        // a known kind with a value it cannot read (a device it does not know)
        (
            "fault",
            r#"{"action":"pause","device":"gauge","event":"fault","kind":"Timeout","message":"m"}"#,
        ),
        // a text that names another kind than its row
        ("note", r#"{"event":"drift","drift_mm":0.1,"max_mm":0.2}"#),
        // today's note
        ("note", r#"{"event":"note","text":"hello"}"#),
    ];
    {
        let conn = rusqlite::Connection::open(&path).expect("open");
        for (kind, text) in old {
            conn.execute(
                "INSERT INTO events (campaign_id, at_ms, kind, message) VALUES (?1, 5, ?2, ?3)",
                rusqlite::params![id, kind, text],
            )
            .expect("insert");
        }
    }
    let s = Store::open(&path).expect("store opens");
    let back = s.events::<CampaignEvent>(id).expect("the journal reads");
    assert_eq!(back.len(), old.len());
    let other = |kind: &str, body: serde_json::Value| {
        CampaignEvent::Other(UnknownEvent {
            kind: kind.into(),
            body,
        })
    };
    assert_eq!(back[0].event, other("pose_done", "pose 0".into()));
    assert_eq!(
        back[1].event,
        CampaignEvent::Measured {
            pose: 1,
            done: 1,
            total: 9,
            p1_mm: [1.0, 2.0, 3.0],
            deviation_mm: None,
            deviation_xyz_mm: None,
        }
    );
    assert_eq!(
        back[2].event,
        other(
            "calibrated_gauge",
            serde_json::from_str(old[2].1).expect("json")
        )
    );
    assert_eq!(
        back[3].event,
        other("fault", serde_json::from_str(old[3].1).expect("json"))
    );
    assert_eq!(
        back[4].event,
        other("note", serde_json::from_str(old[4].1).expect("json"))
    );
    assert_eq!(
        back[5].event,
        CampaignEvent::Note {
            text: "hello".into()
        }
    );
    // an unknown row keeps its kind and is written as it was stored (JSON, or the text as a
    // JSON string, as `GET …/events` has always served a text that is not JSON)
    for (i, e) in back.iter().enumerate().filter(|(i, _)| *i != 1) {
        assert_eq!(e.event.kind(), old[i].0);
        let want = match serde_json::from_str::<serde_json::Value>(old[i].1) {
            Ok(v) => v,
            Err(_) => serde_json::Value::String(old[i].1.into()),
        };
        assert_eq!(serde_json::to_value(&e.event).expect("json"), want);
    }
    assert_eq!(
        serde_json::to_string(&back[2].event).expect("json"),
        old[2].1
    );
    assert!(!back.iter().any(|e| e.event.ends_run()));
}

#[test]
fn no_module_outside_the_store_holds_a_lock_over_a_store() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    let store_dir = root.join("src/store");
    let mut found = Vec::new();
    for f in files.iter().filter(|f| !f.starts_with(&store_dir)) {
        let text = std::fs::read_to_string(f).expect("read");
        let flat: String = text.split_whitespace().collect();
        for pattern in [
            "Mutex<Store",
            "Mutex<crate::store::Store",
            "Mutex<cellcal::store::Store",
            "Mutex<Vec<StoreReader",
            "Mutex<StoreReader",
        ] {
            if flat.contains(pattern) {
                found.push(format!("{}: {pattern}", f.display()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "a Store is locked outside src/store/ (use store::StoreHandle / ReaderPool): {found:#?}"
    );
    assert!(files.len() > 50, "scanned {} files", files.len());
}
