//! Schema migrations, versioned by `PRAGMA user_version`.
//!
//! `MIGRATIONS[i]` takes the schema from version `i` to `i + 1`. Each one is applied inside its
//! own transaction together with the new `user_version`, so a crash mid-migration leaves the
//! previous version. Never edit a released migration: append a new one.
//!
//! Schema (version 1), every table `STRICT`:
//! - `campaigns(id, name, created_at_ms, state, model, seed, config_toml, robot_toml)`; the
//!   `u64` seed is stored as the `i64` with the same bits.
//! - `plan_poses(campaign_id, pose_index, set_name 'ident'|'verify', move_order, q_rad)`,
//!   primary key `(campaign_id, pose_index)`, `move_order` unique per campaign; `q_rad` is a
//!   JSON array of numbers (any number of joints).
//! - `measurements`: one row per raw tracker point, append-only (triggers refuse `UPDATE` and
//!   `DELETE`); `kind` in `p1, p2, drift, setup, discarded`; `pose_index` `NULL` for
//!   non-plan points, else a plan pose; statistics, weather and stage `NULL` when not recorded;
//!   `joints_rad` JSON array of the joints read after settling (or `NULL`).
//! - `pose_done(campaign_id, pose_index, p1_id, p2_id)`: primary key `(campaign_id,
//!   pose_index)`, so a pose is done at most once; names the measurement rows that are the
//!   pose's P1 and P2.
//! - `events(id, campaign_id, at_ms, kind, message)`.
//! - `results(id, campaign_id, created_at_ms, model, json)`; `created_at_ms` is stamped by
//!   SQLite (wall clock) on insert.
//!
//! Version 2 adds `setup_results(id, campaign_id, created_at_ms, json)`: the cell setup of a
//! campaign (tool frame, base registration) as JSON, append-only; the latest one is used.
//!
//! Version 3 adds `campaign_locks(campaign_id, pid, host, pid_start, acquired_at_ms)`: the
//! process that drives a campaign's robot (at most one row per campaign; deleted when the
//! process lets go, taken over when its pid is dead), and `frame_refs(campaign_id, segment,
//! measurement_id, poses_done)`: the drift-reference measurement that defines a campaign's
//! tracker frame (segment 0 at the first start; a re-registration appends the next segment),
//! append-only.
//!
//! Version 4 adds `frame_refs.to_first` (TEXT, JSON, `NULL` for segment 0): the rigid transform
//! from a re-registered segment's tracker frame into segment 0's, `{"rotation": 3×3 rows,
//! "translation_mm", "rms_mm", "max_mm", "points"}`, fitted on points re-measured at stored joints.
//!
//! Version 5 adds `campaign_kinds(campaign_id, kind, plan_json)`: the kind of a campaign that is
//! not a calibration (`iso9283`: an ISO 9283 pose accuracy/repeatability campaign) and its
//! kind's plan (JSON object), written with the campaign in one transaction, append-only. A
//! campaign without a row is a calibration campaign (every campaign of an older store).
//!
//! Version 6 adds `ident_checks(campaign_id, after_poses, json)`: the stop rule's check after
//! `after_poses` measured identification poses (`campaign.stop_when = "predicted"`: the
//! predicted verification error and, when it stopped the identification poses, why), one per
//! count, append-only. A campaign without a row has no check (every campaign of an older store).
//!
//! Version 7 adds `campaign_estimates(campaign_id, json)`: the planned duration of a campaign
//! (a JSON object, the planner's estimate by part), written with the campaign in one
//! transaction, append-only. A campaign without a row was created without one.

use rusqlite::{Connection, TransactionBehavior};

use super::error::{Ctx, StoreError};

/// The migrations, in order. `MIGRATIONS.len()` is the schema version this code writes.
pub(crate) const MIGRATIONS: &[&str] = &[
    // 0 -> 1: initial schema.
    r#"
CREATE TABLE campaigns (
    id            INTEGER PRIMARY KEY,
    name          TEXT    NOT NULL,
    created_at_ms INTEGER NOT NULL,
    state         TEXT    NOT NULL,
    model         TEXT    NOT NULL,
    seed          INTEGER NOT NULL,
    config_toml   TEXT    NOT NULL,
    robot_toml    TEXT    NOT NULL
) STRICT;

CREATE TABLE plan_poses (
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    pose_index  INTEGER NOT NULL CHECK (pose_index >= 0),
    set_name    TEXT    NOT NULL CHECK (set_name IN ('ident', 'verify')),
    move_order  INTEGER NOT NULL CHECK (move_order >= 0),
    q_rad       TEXT    NOT NULL CHECK (json_valid(q_rad) AND json_type(q_rad) = 'array'),
    PRIMARY KEY (campaign_id, pose_index),
    UNIQUE (campaign_id, move_order)
) STRICT;

CREATE TABLE measurements (
    id             INTEGER PRIMARY KEY,
    campaign_id    INTEGER NOT NULL REFERENCES campaigns(id),
    pose_index     INTEGER,
    kind           TEXT    NOT NULL CHECK (kind IN ('p1', 'p2', 'drift', 'setup', 'discarded')),
    x_mm           REAL    NOT NULL,
    y_mm           REAL    NOT NULL,
    z_mm           REAL    NOT NULL,
    std_x_mm       REAL,
    std_y_mm       REAL,
    std_z_mm       REAL,
    std_total_mm   REAL,
    temperature_c  REAL,
    pressure_mbar  REAL,
    humidity_pct   REAL,
    stage_mm       REAL,
    sent_at_ms     INTEGER NOT NULL,
    received_at_ms INTEGER NOT NULL,
    joints_rad     TEXT CHECK (joints_rad IS NULL
                               OR (json_valid(joints_rad) AND json_type(joints_rad) = 'array')),
    note           TEXT    NOT NULL DEFAULT '',
    CHECK (kind NOT IN ('p1', 'p2') OR (pose_index IS NOT NULL AND joints_rad IS NOT NULL)),
    FOREIGN KEY (campaign_id, pose_index) REFERENCES plan_poses(campaign_id, pose_index)
) STRICT;
CREATE INDEX measurements_by_campaign ON measurements(campaign_id, pose_index);

CREATE TRIGGER measurements_no_update BEFORE UPDATE ON measurements
BEGIN SELECT RAISE(ABORT, 'measurements are append-only'); END;
CREATE TRIGGER measurements_no_delete BEFORE DELETE ON measurements
BEGIN SELECT RAISE(ABORT, 'measurements are append-only'); END;

CREATE TABLE pose_done (
    campaign_id INTEGER NOT NULL,
    pose_index  INTEGER NOT NULL,
    p1_id       INTEGER NOT NULL REFERENCES measurements(id),
    p2_id       INTEGER REFERENCES measurements(id),
    PRIMARY KEY (campaign_id, pose_index),
    FOREIGN KEY (campaign_id, pose_index) REFERENCES plan_poses(campaign_id, pose_index)
) STRICT;

CREATE TABLE events (
    id          INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    at_ms       INTEGER NOT NULL,
    kind        TEXT    NOT NULL,
    message     TEXT    NOT NULL
) STRICT;
CREATE INDEX events_by_campaign ON events(campaign_id, id);

CREATE TABLE results (
    id            INTEGER PRIMARY KEY,
    campaign_id   INTEGER NOT NULL REFERENCES campaigns(id),
    created_at_ms INTEGER NOT NULL DEFAULT (CAST(unixepoch('subsec') * 1000 AS INTEGER)),
    model         TEXT    NOT NULL,
    json          TEXT    NOT NULL CHECK (json_valid(json))
) STRICT;
CREATE INDEX results_by_campaign ON results(campaign_id, id);
"#,
    // 1 -> 2: cell setup results (tool frame, base registration), append-only.
    r#"
CREATE TABLE setup_results (
    id            INTEGER PRIMARY KEY,
    campaign_id   INTEGER NOT NULL REFERENCES campaigns(id),
    created_at_ms INTEGER NOT NULL DEFAULT (CAST(unixepoch('subsec') * 1000 AS INTEGER)),
    json          TEXT    NOT NULL CHECK (json_valid(json))
) STRICT;
CREATE INDEX setup_results_by_campaign ON setup_results(campaign_id, id);
CREATE TRIGGER setup_results_no_update BEFORE UPDATE ON setup_results
BEGIN SELECT RAISE(ABORT, 'setup results are append-only'); END;
CREATE TRIGGER setup_results_no_delete BEFORE DELETE ON setup_results
BEGIN SELECT RAISE(ABORT, 'setup results are append-only'); END;
"#,
    // 2 -> 3: one runner per campaign (lock rows), and the frame references of campaigns.
    r#"
CREATE TABLE campaign_locks (
    campaign_id    INTEGER PRIMARY KEY REFERENCES campaigns(id),
    pid            INTEGER NOT NULL,
    host           TEXT    NOT NULL,
    pid_start      INTEGER NOT NULL,
    acquired_at_ms INTEGER NOT NULL
) STRICT;

CREATE TABLE frame_refs (
    id             INTEGER PRIMARY KEY,
    campaign_id    INTEGER NOT NULL REFERENCES campaigns(id),
    segment        INTEGER NOT NULL CHECK (segment >= 0),
    measurement_id INTEGER NOT NULL REFERENCES measurements(id),
    poses_done     INTEGER NOT NULL CHECK (poses_done >= 0),
    UNIQUE (campaign_id, segment)
) STRICT;
CREATE TRIGGER frame_refs_no_update BEFORE UPDATE ON frame_refs
BEGIN SELECT RAISE(ABORT, 'frame references are append-only'); END;
CREATE TRIGGER frame_refs_no_delete BEFORE DELETE ON frame_refs
BEGIN SELECT RAISE(ABORT, 'frame references are append-only'); END;
"#,
    // 3 -> 4: the transform of a re-registered frame segment into segment 0's frame.
    r#"
ALTER TABLE frame_refs ADD COLUMN to_first TEXT
    CHECK (to_first IS NULL OR (json_valid(to_first) AND json_type(to_first) = 'object'));
"#,
    // 4 -> 5: campaign kinds other than calibration (ISO 9283) and their plans.
    r#"
CREATE TABLE campaign_kinds (
    campaign_id INTEGER PRIMARY KEY REFERENCES campaigns(id),
    kind        TEXT    NOT NULL CHECK (kind IN ('iso9283')),
    plan_json   TEXT    NOT NULL CHECK (json_valid(plan_json) AND json_type(plan_json) = 'object')
) STRICT;
CREATE TRIGGER campaign_kinds_no_update BEFORE UPDATE ON campaign_kinds
BEGIN SELECT RAISE(ABORT, 'campaign kinds are append-only'); END;
CREATE TRIGGER campaign_kinds_no_delete BEFORE DELETE ON campaign_kinds
BEGIN SELECT RAISE(ABORT, 'campaign kinds are append-only'); END;
"#,
    // 5 -> 6: the stop rule's checks of a campaign (`stop_when = "predicted"`).
    r#"
CREATE TABLE ident_checks (
    id          INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    after_poses INTEGER NOT NULL CHECK (after_poses >= 0),
    json        TEXT    NOT NULL CHECK (json_valid(json) AND json_type(json) = 'object'),
    UNIQUE (campaign_id, after_poses)
) STRICT;
CREATE TRIGGER ident_checks_no_update BEFORE UPDATE ON ident_checks
BEGIN SELECT RAISE(ABORT, 'identification checks are append-only'); END;
CREATE TRIGGER ident_checks_no_delete BEFORE DELETE ON ident_checks
BEGIN SELECT RAISE(ABORT, 'identification checks are append-only'); END;
"#,
    // 6 -> 7: the planned duration of a campaign, stored with it.
    r#"
CREATE TABLE campaign_estimates (
    campaign_id INTEGER PRIMARY KEY REFERENCES campaigns(id),
    json        TEXT    NOT NULL CHECK (json_valid(json) AND json_type(json) = 'object')
) STRICT;
CREATE TRIGGER campaign_estimates_no_update BEFORE UPDATE ON campaign_estimates
BEGIN SELECT RAISE(ABORT, 'campaign estimates are append-only'); END;
CREATE TRIGGER campaign_estimates_no_delete BEFORE DELETE ON campaign_estimates
BEGIN SELECT RAISE(ABORT, 'campaign estimates are append-only'); END;
"#,
];

/// The schema version this code writes.
pub(crate) fn known_version() -> i64 {
    MIGRATIONS.len() as i64
}

/// Read `PRAGMA user_version`.
pub(crate) fn user_version(conn: &Connection) -> Result<i64, StoreError> {
    conn.pragma_query_value(None, "user_version", |r| r.get(0))
        .ctx("read the schema version")
}

/// Bring the schema up to [`known_version`]; refuse a newer file.
pub(crate) fn migrate(conn: &mut Connection) -> Result<(), StoreError> {
    let known = known_version();
    loop {
        // Immediate: a concurrent opener waits (busy timeout) instead of migrating twice.
        let tx = conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin migration")?;
        let found = user_version(&tx)?;
        if found > known {
            return Err(StoreError::SchemaTooNew { found, known });
        }
        if found == known {
            return Ok(());
        }
        let sql = usize::try_from(found)
            .ok()
            .and_then(|i| MIGRATIONS.get(i))
            .ok_or_else(|| StoreError::Corrupt(format!("schema version {found}")))?;
        tx.execute_batch(sql).ctx("apply a schema migration")?;
        tx.pragma_update(None, "user_version", found + 1)
            .ctx("set the schema version")?;
        tx.commit().ctx("commit a schema migration")?;
    }
}
