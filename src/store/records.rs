//! Row types of the campaign store, and the text encodings of the values SQLite has no type
//! for (joint vectors, the pose set).

use super::error::StoreError;
use crate::dataset::PoseSet;

/// One raw tracker point as stored (one `measurements` row without its campaign, pose and
/// kind).
///
/// `x_mm`, `y_mm`, `z_mm` must be finite. The other measured values may be NaN, meaning "not
/// recorded" (e.g. an imported data set has no tracker statistics); NaN is stored as SQL
/// `NULL` and read back as NaN. Infinite values are refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointRecord {
    /// Position x (mm, tracker frame).
    pub x_mm: f64,
    /// Position y (mm).
    pub y_mm: f64,
    /// Position z (mm).
    pub z_mm: f64,
    /// Per-axis standard deviation (mm).
    pub std_mm: [f64; 3],
    /// Total standard deviation (mm).
    pub std_total_mm: f64,
    /// Air temperature (°C).
    pub temperature_c: f64,
    /// Air pressure (mbar).
    pub pressure_mbar: f64,
    /// Relative humidity (%).
    pub humidity_pct: f64,
    /// Stage position when measured (mm).
    pub stage_mm: f64,
    /// When the measurement was requested (ms since the Unix epoch).
    pub sent_at_ms: i64,
    /// When the result arrived (ms since the Unix epoch).
    pub received_at_ms: i64,
}

impl PointRecord {
    /// A point with only a position known: statistics, weather and stage are NaN ("not
    /// recorded"), both times are `at_ms`.
    pub fn position_only(x_mm: f64, y_mm: f64, z_mm: f64, at_ms: i64) -> PointRecord {
        PointRecord {
            x_mm,
            y_mm,
            z_mm,
            std_mm: [f64::NAN; 3],
            std_total_mm: f64::NAN,
            temperature_c: f64::NAN,
            pressure_mbar: f64::NAN,
            humidity_pct: f64::NAN,
            stage_mm: f64::NAN,
            sent_at_ms: at_ms,
            received_at_ms: at_ms,
        }
    }

    /// Refuse non-finite positions and infinite optional values.
    pub(crate) fn check(&self, what: &str) -> Result<(), StoreError> {
        for (name, v) in [
            ("x_mm", self.x_mm),
            ("y_mm", self.y_mm),
            ("z_mm", self.z_mm),
        ] {
            if !v.is_finite() {
                return Err(StoreError::Invalid(format!(
                    "{what}: {name} = {v} is not finite"
                )));
            }
        }
        let optional = [
            ("std_x_mm", self.std_mm[0]),
            ("std_y_mm", self.std_mm[1]),
            ("std_z_mm", self.std_mm[2]),
            ("std_total_mm", self.std_total_mm),
            ("temperature_c", self.temperature_c),
            ("pressure_mbar", self.pressure_mbar),
            ("humidity_pct", self.humidity_pct),
            ("stage_mm", self.stage_mm),
        ];
        for (name, v) in optional {
            if v.is_infinite() {
                return Err(StoreError::Invalid(format!("{what}: {name} is infinite")));
            }
        }
        Ok(())
    }
}

/// One pose of a campaign's plan, fixed when the campaign is created.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPose {
    /// Pose index, unique within the campaign (the pose id in exports).
    pub index: usize,
    /// Identification or verification set.
    pub set: PoseSet,
    /// Position in the order of moves (unique within the campaign).
    pub order: usize,
    /// Commanded joint values (rad).
    pub q_rad: Vec<f64>,
}

/// A completely measured plan pose, committed atomically by
/// [`Store::commit_pose`](super::Store::commit_pose).
#[derive(Debug, Clone, PartialEq)]
pub struct PoseMeasurement {
    /// Plan pose index.
    pub index: usize,
    /// Joint values read from the controller after settling (rad).
    pub joints_rad: Vec<f64>,
    /// Ball at stage position P1.
    pub p1: PointRecord,
    /// Ball at stage position P2, when the stage direction is measured.
    pub p2: Option<PointRecord>,
}

/// What a new campaign is, before it has an id.
#[derive(Debug, Clone, PartialEq)]
pub struct NewCampaign {
    /// Human name.
    pub name: String,
    /// Creation time (ms since the Unix epoch).
    pub created_at_ms: i64,
    /// Observation model name (e.g. `position`, `np`).
    pub model: String,
    /// Seed of the plan (and of the simulator, if simulated).
    pub seed: u64,
    /// The cell configuration used, verbatim TOML.
    pub config_toml: String,
    /// The nominal robot model used, verbatim TOML.
    pub robot_toml: String,
}

/// A stored campaign.
#[derive(Debug, Clone, PartialEq)]
pub struct CampaignRow {
    /// Campaign id (SQLite rowid, increasing).
    pub id: i64,
    /// Human name.
    pub name: String,
    /// Creation time (ms since the Unix epoch).
    pub created_at_ms: i64,
    /// Campaign state as last set by [`Store::set_state`](super::Store::set_state)
    /// (`created` initially).
    pub state: StoredState,
    /// Observation model name.
    pub model: String,
    /// Seed.
    pub seed: u64,
    /// Cell configuration, verbatim TOML.
    pub config_toml: String,
    /// Nominal robot model, verbatim TOML.
    pub robot_toml: String,
}

/// An event type the journal keeps: the store writes its kind and JSON text and gives it back
/// typed. The store knows nothing else of it (the campaign's events implement it).
pub trait JournalEvent: Sized {
    /// The `kind` column (the event's tag).
    fn kind(&self) -> &str;
    /// The stored text (JSON).
    fn to_text(&self) -> Result<String, StoreError>;
    /// The event of a stored row. Never fails: a row the type cannot read (an old or unknown
    /// kind, a damaged text) becomes the type's own fallback, so an old journal stays readable.
    fn from_stored(kind: String, text: String) -> Self;
}

/// A stored journal entry: the event and the sequence number the store gave it.
#[derive(Debug, Clone, PartialEq)]
pub struct JournalEntry<E> {
    /// The `events` row id: increasing in insertion order across the whole database.
    pub seq: i64,
    /// When it was journalled (ms since the Unix epoch).
    pub at_ms: i64,
    /// The event.
    pub event: E,
}

/// A campaign's state as its row stores it: the engine's states plus the three set outside a
/// run. The serde and stored names are the snake-case variant names (`created`, `paused`, …).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StoredState {
    /// Created with its plan; no engine has run it yet.
    Created,
    /// Imported from a data set (nothing to run).
    Imported,
    /// Stored in a run's state by a process that is gone (shown, and stored by a starting
    /// daemon; resumable).
    Interrupted,
    /// An engine holds it, not armed.
    Idle,
    /// Armed, waiting for start.
    Armed,
    /// Measuring.
    Running,
    /// Paused (operator or fault).
    Paused,
    /// Identifying the parameters.
    Identifying,
    /// Finished with a result.
    Done,
    /// Aborted by the operator (resumable).
    Aborted,
    /// Stopped by a fault (resumable).
    Failed,
}

impl StoredState {
    /// Every state, in the order above.
    pub const ALL: [StoredState; 11] = [
        StoredState::Created,
        StoredState::Imported,
        StoredState::Interrupted,
        StoredState::Idle,
        StoredState::Armed,
        StoredState::Running,
        StoredState::Paused,
        StoredState::Identifying,
        StoredState::Done,
        StoredState::Aborted,
        StoredState::Failed,
    ];

    /// The states only a running engine is in (a campaign left in one by a process that is
    /// gone is [`StoredState::Interrupted`]).
    pub const RUN: [StoredState; 5] = [
        StoredState::Idle,
        StoredState::Armed,
        StoredState::Running,
        StoredState::Paused,
        StoredState::Identifying,
    ];

    /// The stored (and serde) name.
    pub const fn name(self) -> &'static str {
        match self {
            StoredState::Created => "created",
            StoredState::Imported => "imported",
            StoredState::Interrupted => "interrupted",
            StoredState::Idle => "idle",
            StoredState::Armed => "armed",
            StoredState::Running => "running",
            StoredState::Paused => "paused",
            StoredState::Identifying => "identifying",
            StoredState::Done => "done",
            StoredState::Aborted => "aborted",
            StoredState::Failed => "failed",
        }
    }

    /// The state stored as `name`, if it is one.
    pub fn from_name(name: &str) -> Option<StoredState> {
        StoredState::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Whether this is one of [`StoredState::RUN`].
    pub fn is_run(self) -> bool {
        StoredState::RUN.contains(&self)
    }
}

impl std::fmt::Display for StoredState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl PartialEq<&str> for StoredState {
    fn eq(&self, name: &&str) -> bool {
        self.name() == *name
    }
}

impl rusqlite::types::FromSql for StoredState {
    fn column_result(v: rusqlite::types::ValueRef<'_>) -> rusqlite::types::FromSqlResult<Self> {
        let text = v.as_str()?;
        StoredState::from_name(text).ok_or_else(|| {
            rusqlite::types::FromSqlError::Other(
                StoreError::Corrupt(format!("campaign state `{text}`")).into(),
            )
        })
    }
}

impl rusqlite::types::ToSql for StoredState {
    fn to_sql(&self) -> rusqlite::Result<rusqlite::types::ToSqlOutput<'_>> {
        Ok(self.name().into())
    }
}

/// Kind of a tracker point added outside a pose commit by
/// [`Store::add_point`](super::Store::add_point). (P1 and P2 rows are only written by
/// [`Store::commit_pose`](super::Store::commit_pose).)
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PointKind {
    /// Drift check on a reference point.
    Drift,
    /// Setup measurement (e.g. base or tool frame points).
    Setup,
    /// A measurement that was taken but not used (fault, re-measured).
    Discarded,
}

impl PointKind {
    /// Spelling in the `kind` column.
    pub fn as_str(self) -> &'static str {
        match self {
            PointKind::Drift => "drift",
            PointKind::Setup => "setup",
            PointKind::Discarded => "discarded",
        }
    }
}

/// `PoseSet` from its stored spelling.
pub(crate) fn parse_set(s: &str) -> Result<PoseSet, StoreError> {
    match s {
        "ident" => Ok(PoseSet::Ident),
        "verify" => Ok(PoseSet::Verify),
        other => Err(StoreError::Corrupt(format!("pose set `{other}`"))),
    }
}

/// Encode a joint vector as a JSON array of numbers in Rust's shortest round-trip spelling,
/// so decoding gives back the same bits. Non-finite values are refused.
pub(crate) fn encode_joints(q: &[f64], what: &str) -> Result<String, StoreError> {
    let mut s = String::from("[");
    for (i, v) in q.iter().enumerate() {
        if !v.is_finite() {
            return Err(StoreError::Invalid(format!(
                "{what}: joint {} = {v} is not finite",
                i + 1
            )));
        }
        if i > 0 {
            s.push(',');
        }
        s.push_str(&format!("{v:?}"));
    }
    s.push(']');
    Ok(s)
}

/// Decode what [`encode_joints`] wrote (any JSON array of plain numbers). Parsed with Rust's
/// correctly rounded `f64` parser, not serde_json's default (which may be off by one ulp).
pub(crate) fn decode_joints(text: &str) -> Result<Vec<f64>, StoreError> {
    let corrupt = || StoreError::Corrupt(format!("joint vector `{text}`"));
    let inner = text
        .trim()
        .strip_prefix('[')
        .and_then(|t| t.strip_suffix(']'))
        .ok_or_else(corrupt)?
        .trim();
    if inner.is_empty() {
        return Ok(Vec::new());
    }
    inner
        .split(',')
        .map(|t| match t.trim().parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(corrupt()),
        })
        .collect()
}

/// `usize` → SQL integer.
pub(crate) fn to_sql_index(i: usize, what: &str) -> Result<i64, StoreError> {
    i64::try_from(i).map_err(|_| StoreError::Invalid(format!("{what} {i} is too large")))
}

/// SQL integer → `usize`.
pub(crate) fn from_sql_index(i: i64, what: &str) -> Result<usize, StoreError> {
    usize::try_from(i).map_err(|_| StoreError::Corrupt(format!("{what} {i}")))
}

/// NaN ("not recorded") ↔ SQL NULL.
pub(crate) fn opt(v: f64) -> Option<f64> {
    (!v.is_nan()).then_some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joints_round_trip_bit_exact() {
        let q = [
            0.1,
            -0.0,
            1e-300,
            std::f64::consts::PI,
            -2.718_281_828_459_1,
            1.0 / 3.0,
            f64::MIN_POSITIVE,
            f64::MAX,
        ];
        let s = encode_joints(&q, "t").unwrap();
        let back = decode_joints(&s).unwrap();
        assert_eq!(
            q.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            back.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        assert!(
            serde_json::from_str::<Vec<f64>>(&s).is_ok(),
            "valid JSON: {s}"
        );
        assert_eq!(decode_joints("[]").unwrap(), Vec::<f64>::new());
        assert!(decode_joints("[1,x]").is_err());
        assert!(decode_joints("1,2").is_err());
        assert!(encode_joints(&[f64::NAN], "t").is_err());
    }
}
