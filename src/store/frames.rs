//! Frame references: the drift-reference measurement that defines a campaign's tracker frame.
//! Segment 0 is measured at the campaign's first start; every resume measures the reference
//! again and compares it with the latest segment's.

use rusqlite::{params, TransactionBehavior};

use super::error::{Ctx, StoreError};
use super::measurements::read_point;
use super::records::{from_sql_index, to_sql_index, PointRecord};
use super::Store;

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
}

impl Store {
    /// Start the next frame segment of campaign `id` at the stored measurement
    /// `measurement_id` (a `drift` point with joints); returns the segment number.
    pub fn add_frame_ref(
        &mut self,
        id: i64,
        measurement_id: i64,
        poses_done: usize,
    ) -> Result<u32, StoreError> {
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
        let n = tx
            .execute(
                "INSERT INTO frame_refs (campaign_id, segment, measurement_id, poses_done) \
                 SELECT ?1, ?2, id, ?4 FROM measurements \
                 WHERE id = ?3 AND campaign_id = ?1 AND kind = 'drift' AND joints_rad IS NOT NULL",
                params![
                    id,
                    next,
                    measurement_id,
                    to_sql_index(poses_done, "poses done")?
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
                "SELECT segment, measurement_id, poses_done FROM frame_refs \
                 WHERE campaign_id = ?1 ORDER BY segment",
            )
            .ctx("read frame references")?;
        let raw = st
            .query_map([id], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                ))
            })
            .ctx("read frame references")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read frame references")?;
        raw.into_iter()
            .map(|(segment, mid, done)| {
                let (point, joints) = read_point(&self.conn, mid)?;
                Ok(FrameRef {
                    segment: u32::try_from(segment)
                        .map_err(|_| StoreError::Corrupt(format!("frame segment {segment}")))?,
                    point,
                    joints_rad: joints.ok_or_else(|| {
                        StoreError::Corrupt(format!("frame reference {mid} has no joints"))
                    })?,
                    poses_done: from_sql_index(done, "poses done")?,
                })
            })
            .collect()
    }
}
