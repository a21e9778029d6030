//! Frame references: the drift-reference measurement that defines a campaign's tracker frame.
//! Segment 0 is measured at the campaign's first start; every resume measures the reference
//! again and compares it with the latest segment's. A re-registration starts the next segment
//! with the rigid transform of its frame into segment 0's; a measurement belongs to the segment
//! whose reference row is the last one at or before its own row id.

use nalgebra::{Matrix3, Rotation3, Vector3};
use rusqlite::{params, TransactionBehavior};
use serde::{Deserialize, Serialize};

use super::error::{Ctx, StoreError};
use super::measurements::read_point;
use super::records::{from_sql_index, to_sql_index, PointRecord};
use super::Store;
use crate::model::Pose;

/// Where a re-registered segment's tracker frame lies in segment 0's, and how well the common
/// points agreed.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameTransform {
    /// Segment 0 ← this segment (p₀ = T · pₖ).
    pub to_first: Pose,
    /// RMS residual of the common points after the fit (mm).
    pub rms_mm: f64,
    /// Largest residual (mm).
    pub max_mm: f64,
    /// Common points the fit used.
    pub points: usize,
}

/// JSON of the `to_first` column.
#[derive(Serialize, Deserialize)]
struct TransformJson {
    rotation: [[f64; 3]; 3],
    translation_mm: [f64; 3],
    rms_mm: f64,
    max_mm: f64,
    points: usize,
}

impl FrameTransform {
    fn to_json(&self) -> Result<String, StoreError> {
        let m = &self.to_first.r;
        let t = self.to_first.p;
        let j = TransformJson {
            rotation: [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]),
            translation_mm: [t.x, t.y, t.z],
            rms_mm: self.rms_mm,
            max_mm: self.max_mm,
            points: self.points,
        };
        let all = j.rotation.iter().flatten().chain(&j.translation_mm);
        if !all.chain([&j.rms_mm, &j.max_mm]).all(|v| v.is_finite()) {
            return Err(StoreError::Invalid(
                "frame transform has a non-finite value".into(),
            ));
        }
        serde_json::to_string(&j).map_err(|e| StoreError::Invalid(e.to_string()))
    }

    fn from_json(text: &str) -> Result<FrameTransform, StoreError> {
        let j: TransformJson = serde_json::from_str(text)
            .map_err(|e| StoreError::Corrupt(format!("frame transform: {e}")))?;
        let m = Matrix3::from_fn(|i, k| j.rotation[i][k]);
        Ok(FrameTransform {
            to_first: Pose {
                r: Rotation3::from_matrix(&m).into_inner(),
                p: Vector3::from(j.translation_mm),
            },
            rms_mm: j.rms_mm,
            max_mm: j.max_mm,
            points: j.points,
        })
    }
}

/// A stored point with the joints it was measured at (a candidate common point of a
/// re-registration).
#[derive(Debug, Clone, PartialEq)]
pub struct JointPoint {
    /// Measurement row id.
    pub row: i64,
    /// `p1`, `drift` or `setup`.
    pub kind: String,
    /// Plan pose, if any.
    pub pose: Option<usize>,
    /// The point (tracker frame of its segment).
    pub point: PointRecord,
    /// Joints (rad).
    pub joints_rad: Vec<f64>,
}

/// Segment 0 ← the frame of the measurement at `row`, given the segments (oldest first).
pub fn to_first_frame(refs: &[FrameRef], row: i64) -> Pose {
    refs.iter()
        .rev()
        .find(|r| r.measurement_id <= row)
        .and_then(|r| r.to_first.as_ref())
        .map_or_else(Pose::identity, |t| t.to_first)
}

/// `p` (tracker frame of its segment) in segment 0's frame.
pub fn map_point(t: &Pose, p: Vector3<f64>) -> Vector3<f64> {
    t.transform_point(&p)
}

/// One frame segment of a campaign.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRef {
    /// Segment number (0 = the first start).
    pub segment: u32,
    /// The reference point as measured (tracker frame).
    pub point: PointRecord,
    /// The joints it was measured at (rad).
    pub joints_rad: Vec<f64>,
    /// Poses done when the segment began.
    pub poses_done: usize,
    /// The reference's measurement row (the segment's first row).
    pub measurement_id: i64,
    /// Segment 0 ← this segment (`None` for segment 0).
    pub to_first: Option<FrameTransform>,
}

impl Store {
    /// Start the next frame segment of campaign `id` at the stored measurement
    /// `measurement_id` (a `drift` point with joints); returns the segment number. Segment 0
    /// takes no transform; every later one needs its transform into segment 0's frame.
    pub fn add_frame_ref(
        &mut self,
        id: i64,
        measurement_id: i64,
        poses_done: usize,
        to_first: Option<&FrameTransform>,
    ) -> Result<u32, StoreError> {
        let json = to_first.map(FrameTransform::to_json).transpose()?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin add frame reference")?;
        Store::ensure_campaign(&tx, id)?;
        let next: i64 = tx
            .query_row(
                "SELECT coalesce(max(segment) + 1, 0) FROM frame_refs WHERE campaign_id = ?1",
                [id],
                |r| r.get(0),
            )
            .ctx("number a frame segment")?;
        if (next == 0) != json.is_none() {
            return Err(StoreError::Invalid(format!(
                "frame segment {next} of campaign {id}: {}",
                if next == 0 {
                    "the first segment defines the frame and takes no transform"
                } else {
                    "a re-registered segment needs its transform into segment 0's frame"
                }
            )));
        }
        let n = tx
            .execute(
                "INSERT INTO frame_refs (campaign_id, segment, measurement_id, poses_done, to_first) \
                 SELECT ?1, ?2, id, ?4, ?5 FROM measurements \
                 WHERE id = ?3 AND campaign_id = ?1 AND kind = 'drift' AND joints_rad IS NOT NULL",
                params![
                    id,
                    next,
                    measurement_id,
                    to_sql_index(poses_done, "poses done")?,
                    json
                ],
            )
            .ctx("add a frame reference")?;
        if n == 0 {
            return Err(StoreError::Invalid(format!(
                "measurement {measurement_id} is not a drift point of campaign {id} with joints"
            )));
        }
        tx.commit().ctx("commit add frame reference")?;
        u32::try_from(next).map_err(|_| StoreError::Corrupt(format!("frame segment {next}")))
    }

    /// The campaign's frame segments, oldest first.
    pub fn frame_refs(&self, id: i64) -> Result<Vec<FrameRef>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT segment, measurement_id, poses_done, to_first FROM frame_refs \
                 WHERE campaign_id = ?1 ORDER BY segment",
            )
            .ctx("read frame references")?;
        let raw = st
            .query_map([id], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, Option<String>>(3)?,
                ))
            })
            .ctx("read frame references")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read frame references")?;
        raw.into_iter()
            .map(|(segment, mid, done, to_first)| {
                let (point, joints) = read_point(&self.conn, mid)?;
                Ok(FrameRef {
                    segment: u32::try_from(segment)
                        .map_err(|_| StoreError::Corrupt(format!("frame segment {segment}")))?,
                    point,
                    joints_rad: joints.ok_or_else(|| {
                        StoreError::Corrupt(format!("frame reference {mid} has no joints"))
                    })?,
                    poses_done: from_sql_index(done, "poses done")?,
                    measurement_id: mid,
                    to_first: to_first
                        .as_deref()
                        .map(FrameTransform::from_json)
                        .transpose()?,
                })
            })
            .collect()
    }

    /// Points of campaign `id` with joints, kinds `p1`, `drift` and `setup`, measured at stage
    /// position `stage_mm` (± 1 µm), with row ids in `from..to`, oldest first.
    pub fn joint_points(
        &self,
        id: i64,
        rows: std::ops::Range<i64>,
        stage_mm: f64,
    ) -> Result<Vec<JointPoint>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT id, kind, pose_index FROM measurements \
                 WHERE campaign_id = ?1 AND id >= ?2 AND id < ?3 AND joints_rad IS NOT NULL \
                 AND kind IN ('p1', 'drift', 'setup') AND abs(stage_mm - ?4) <= 0.001 ORDER BY id",
            )
            .ctx("read points with joints")?;
        let raw = st
            .query_map(params![id, rows.start, rows.end, stage_mm], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, Option<i64>>(2)?,
                ))
            })
            .ctx("read points with joints")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read points with joints")?;
        raw.into_iter()
            .map(|(row, kind, pose)| {
                let (point, joints) = read_point(&self.conn, row)?;
                Ok(JointPoint {
                    row,
                    kind,
                    pose: pose.map(|p| from_sql_index(p, "pose index")).transpose()?,
                    point,
                    joints_rad: joints.unwrap_or_default(),
                })
            })
            .collect()
    }
}
