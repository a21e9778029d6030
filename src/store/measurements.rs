//! Raw tracker points, completed poses, and the observation view of a campaign.

use std::collections::HashSet;

use nalgebra::Vector3;
use rusqlite::{params, OptionalExtension, Transaction, TransactionBehavior};

use super::campaigns::{check_plan, insert_campaign};
use super::error::{Ctx, StoreError};
use super::frames::{map_point, to_first_frame};
use super::records::{
    decode_joints, encode_joints, from_sql_index, opt, parse_set, to_sql_index, NewCampaign,
    PlannedPose, PointKind, PointRecord, PoseMeasurement,
};
use super::Store;
use crate::dataset::{Observation, PoseSet};
use crate::model::Pose;

/// State given to campaigns made by [`Store::import_observations`].
pub const IMPORTED_STATE: &str = "imported";

const POINT_COLUMNS: &str = "x_mm, y_mm, z_mm, std_x_mm, std_y_mm, std_z_mm, std_total_mm, \
     temperature_c, pressure_mbar, humidity_pct, stage_mm, sent_at_ms, received_at_ms, joints_rad";

/// A stored setup point ([`Store::setup_points`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SetupPoint {
    /// Measurement row id.
    pub row: i64,
    /// The note naming its mark (`tool frame +x P1`, `base registration 2`, …).
    pub note: String,
    /// The point (the stage reading in `stage_mm`).
    pub point: PointRecord,
    /// Joints read back when it was measured (rad).
    pub joints_rad: Vec<f64>,
}

/// One tracker point of a measured pose as recorded, in the campaign's first tracker frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredPoint {
    /// Ball position (mm, the campaign's first tracker frame).
    pub position_mm: Vector3<f64>,
    /// Stage position when measured (mm); `None` when not recorded (an imported data set).
    pub stage_mm: Option<f64>,
    /// The tracker's total standard deviation of the point (mm); `None` when not recorded.
    /// (The per-axis σ stays in the raw [`PointRecord`]: its axes are the tracker frame of
    /// the point's segment, not the first frame.)
    pub sigma_mm: Option<f64>,
}

impl MeasuredPoint {
    /// The stored point `p` mapped by `to_first` into the first frame; NaN ("not recorded")
    /// becomes `None`.
    fn of(to_first: &Pose, p: &PointRecord) -> MeasuredPoint {
        let recorded = |v: f64| Some(v).filter(|v| !v.is_nan());
        MeasuredPoint {
            position_mm: map_point(to_first, Vector3::new(p.x_mm, p.y_mm, p.z_mm)),
            stage_mm: recorded(p.stage_mm),
            sigma_mm: recorded(p.std_total_mm),
        }
    }
}

/// A completely measured plan pose as the store keeps it ([`Store::measured`]): what was
/// measured, not a data-set row.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredPose {
    /// Plan pose index.
    pub index: usize,
    /// Identification or verification set (from the plan).
    pub set: PoseSet,
    /// Joint values read from the controller after settling (rad).
    pub joints_rad: Vec<f64>,
    /// Ball at stage position P1.
    pub p1: MeasuredPoint,
    /// Ball at stage position P2, when the stage direction was measured.
    pub p2: Option<MeasuredPoint>,
}

impl From<MeasuredPose> for Observation {
    /// The identification row of a measured pose: `id` = pose index, no rotation, `line` 0.
    fn from(m: MeasuredPose) -> Observation {
        Observation {
            line: 0,
            id: m.index.to_string(),
            set: m.set,
            q: m.joints_rad,
            p1: m.p1.position_mm,
            p2: m.p2.map(|p| p.position_mm),
            rotation: None,
        }
    }
}

/// The identification input of a campaign's measured poses (`cellcal export`, `identify
/// --store`, the engine): the one place a [`MeasuredPose`] becomes a data-set row.
pub fn identification_rows(poses: Vec<MeasuredPose>) -> Vec<Observation> {
    poses.into_iter().map(Observation::from).collect()
}

/// Insert one measurement row; returns its id.
fn insert_point(
    tx: &Transaction<'_>,
    campaign: i64,
    pose: Option<i64>,
    kind: &str,
    joints: Option<&str>,
    p: &PointRecord,
    note: &str,
) -> Result<i64, StoreError> {
    let mut st = tx
        .prepare_cached(&format!(
            "INSERT INTO measurements (campaign_id, pose_index, kind, {POINT_COLUMNS}, note) \
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, \
             ?18)"
        ))
        .ctx("insert a measurement")?;
    st.execute(params![
        campaign,
        pose,
        kind,
        p.x_mm,
        p.y_mm,
        p.z_mm,
        opt(p.std_mm[0]),
        opt(p.std_mm[1]),
        opt(p.std_mm[2]),
        opt(p.std_total_mm),
        opt(p.temperature_c),
        opt(p.pressure_mbar),
        opt(p.humidity_pct),
        opt(p.stage_mm),
        p.sent_at_ms,
        p.received_at_ms,
        joints,
        note
    ])
    .ctx("insert a measurement")?;
    Ok(tx.last_insert_rowid())
}

/// Read one measurement row by id: the point and its joints (if stored).
pub(super) fn read_point(
    conn: &rusqlite::Connection,
    row_id: i64,
) -> Result<(PointRecord, Option<Vec<f64>>), StoreError> {
    let mut st = conn
        .prepare_cached(&format!(
            "SELECT {POINT_COLUMNS} FROM measurements WHERE id = ?1"
        ))
        .ctx("read a measurement")?;
    let nan = |v: Option<f64>| v.unwrap_or(f64::NAN);
    let (point, joints) = st
        .query_row([row_id], |r| {
            Ok((
                PointRecord {
                    x_mm: r.get(0)?,
                    y_mm: r.get(1)?,
                    z_mm: r.get(2)?,
                    std_mm: [nan(r.get(3)?), nan(r.get(4)?), nan(r.get(5)?)],
                    std_total_mm: nan(r.get(6)?),
                    temperature_c: nan(r.get(7)?),
                    pressure_mbar: nan(r.get(8)?),
                    humidity_pct: nan(r.get(9)?),
                    stage_mm: nan(r.get(10)?),
                    sent_at_ms: r.get(11)?,
                    received_at_ms: r.get(12)?,
                },
                r.get::<_, Option<String>>(13)?,
            ))
        })
        .optional()
        .ctx("read a measurement")?
        .ok_or_else(|| StoreError::Corrupt(format!("measurement row {row_id} is missing")))?;
    Ok((point, joints.as_deref().map(decode_joints).transpose()?))
}

/// The planned joint count of a pose, or `NotInPlan`.
fn planned_dof(tx: &Transaction<'_>, campaign: i64, pose: usize) -> Result<usize, StoreError> {
    let q: Option<String> = tx
        .query_row(
            "SELECT q_rad FROM plan_poses WHERE campaign_id = ?1 AND pose_index = ?2",
            params![campaign, to_sql_index(pose, "pose index")?],
            |r| r.get(0),
        )
        .optional()
        .ctx("look up a plan pose")?;
    match q {
        Some(q) => Ok(decode_joints(&q)?.len()),
        None => Err(StoreError::NotInPlan { campaign, pose }),
    }
}

/// Write P1, P2 and the done mark of one pose inside `tx` (checks already done).
fn write_pose(
    tx: &Transaction<'_>,
    campaign: i64,
    m: &PoseMeasurement,
    joints: &str,
    note: &str,
) -> Result<(), StoreError> {
    let pose = to_sql_index(m.index, "pose index")?;
    let p1 = insert_point(tx, campaign, Some(pose), "p1", Some(joints), &m.p1, note)?;
    #[cfg(test)]
    super::tests::crash_point("after_p1");
    let p2 = match &m.p2 {
        Some(p2) => Some(insert_point(
            tx,
            campaign,
            Some(pose),
            "p2",
            Some(joints),
            p2,
            note,
        )?),
        None => None,
    };
    tx.execute(
        "INSERT INTO pose_done (campaign_id, pose_index, p1_id, p2_id) VALUES (?1, ?2, ?3, ?4)",
        params![campaign, pose, p1, p2],
    )
    .ctx("mark a pose done")?;
    Ok(())
}

/// Check a measurement's values; returns the encoded joints.
fn check_measurement(m: &PoseMeasurement) -> Result<String, StoreError> {
    let what = format!("pose {}", m.index);
    m.p1.check(&format!("{what} P1"))?;
    if let Some(p2) = &m.p2 {
        p2.check(&format!("{what} P2"))?;
    }
    encode_joints(&m.joints_rad, &what)
}

impl Store {
    /// Commit a completely measured plan pose: its P1 row, P2 row (if any) and done mark in
    /// one transaction. When this returns `Ok` the pose is on disk (WAL, `synchronous=FULL`).
    ///
    /// Errors, all writing nothing: [`StoreError::AlreadyMeasured`] if the pose is already
    /// done, [`StoreError::NotInPlan`], [`StoreError::NoCampaign`], [`StoreError::Invalid`]
    /// (non-finite values, joint count differing from the plan's).
    pub fn commit_pose(&mut self, id: i64, m: &PoseMeasurement) -> Result<(), StoreError> {
        let joints = check_measurement(m)?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin commit pose")?;
        Store::ensure_campaign(&tx, id)?;
        let dof = planned_dof(&tx, id, m.index)?;
        if dof != m.joints_rad.len() {
            return Err(StoreError::Invalid(format!(
                "pose {}: {} joints read, the plan has {dof}",
                m.index,
                m.joints_rad.len()
            )));
        }
        let done: Option<i64> = tx
            .query_row(
                "SELECT 1 FROM pose_done WHERE campaign_id = ?1 AND pose_index = ?2",
                params![id, to_sql_index(m.index, "pose index")?],
                |r| r.get(0),
            )
            .optional()
            .ctx("check whether a pose is done")?;
        if done.is_some() {
            return Err(StoreError::AlreadyMeasured {
                campaign: id,
                pose: m.index,
            });
        }
        write_pose(&tx, id, m, &joints, "")?;
        tx.commit().ctx("commit a pose")
    }

    /// Append a tracker point that is not a pose's P1/P2 (drift check, setup, discarded).
    /// `pose_index`, when given, must be a plan pose. Returns the measurement row id.
    pub fn add_point(
        &mut self,
        id: i64,
        kind: PointKind,
        pose_index: Option<usize>,
        joints_rad: Option<&[f64]>,
        point: &PointRecord,
        note: &str,
    ) -> Result<i64, StoreError> {
        point.check(kind.as_str())?;
        let joints = joints_rad
            .map(|q| encode_joints(q, kind.as_str()))
            .transpose()?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin add point")?;
        Store::ensure_campaign(&tx, id)?;
        let pose = match pose_index {
            Some(p) => {
                planned_dof(&tx, id, p)?;
                Some(to_sql_index(p, "pose index")?)
            }
            None => None,
        };
        let row = insert_point(&tx, id, pose, kind.as_str(), joints.as_deref(), point, note)?;
        tx.commit().ctx("commit add point")?;
        Ok(row)
    }

    /// The campaign's `setup` points with joints taken after the latest refusal marker
    /// ([`Store::discard_setup_points`]), oldest first: what a setup resumed before its result
    /// was stored reuses (by the mark in the note).
    pub fn setup_points(&self, id: i64) -> Result<Vec<SetupPoint>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT id, note FROM measurements WHERE campaign_id = ?1 AND kind = 'setup' \
                 AND joints_rad IS NOT NULL AND id > coalesce((SELECT max(id) FROM measurements \
                 WHERE campaign_id = ?1 AND kind = 'discarded' AND note LIKE 'setup refused:%'), 0) \
                 ORDER BY id",
            )
            .ctx("read setup points")?;
        let raw = st
            .query_map([id], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?)))
            .ctx("read setup points")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read setup points")?;
        raw.into_iter()
            .map(|(row, note)| {
                let (point, joints) = read_point(&self.conn, row)?;
                Ok(SetupPoint {
                    row,
                    note,
                    point,
                    joints_rad: joints.unwrap_or_default(),
                })
            })
            .collect()
    }

    /// Refuse the campaign's `setup` points for reuse (measurements are append-only): a
    /// `discarded` copy of the latest one, noted `setup refused: <why>`, marks every setup
    /// point before it as not reused ([`Store::setup_points`]); how many rows were added (0
    /// without a setup point).
    pub fn discard_setup_points(&mut self, id: i64, why: &str) -> Result<usize, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .execute(
                &format!(
                    "INSERT INTO measurements (campaign_id, pose_index, kind, {POINT_COLUMNS}, \
                     note) SELECT campaign_id, NULL, 'discarded', {POINT_COLUMNS}, \
                     'setup refused: ' || ?2 FROM measurements WHERE campaign_id = ?1 AND \
                     kind = 'setup' ORDER BY id DESC LIMIT 1"
                ),
                params![id, why],
            )
            .ctx("mark setup points refused")
    }

    /// How many points of `kind` the campaign has stored.
    pub fn point_count(&self, id: i64, kind: PointKind) -> Result<usize, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let n: i64 = self
            .conn
            .query_row(
                "SELECT count(*) FROM measurements WHERE campaign_id = ?1 AND kind = ?2",
                params![id, kind.as_str()],
                |r| r.get(0),
            )
            .ctx("count points")?;
        from_sql_index(n, "point count")
    }

    /// Indices of the campaign's completely measured poses, ascending.
    pub fn done_poses(&self, id: i64) -> Result<Vec<usize>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare("SELECT pose_index FROM pose_done WHERE campaign_id = ?1 ORDER BY pose_index")
            .ctx("read done poses")?;
        let raw = st
            .query_map([id], |r| r.get::<_, i64>(0))
            .ctx("read done poses")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read done poses")?;
        raw.into_iter()
            .map(|i| from_sql_index(i, "pose index"))
            .collect()
    }

    /// The campaign's measured poses with their set, in plan (move) order.
    pub fn measured_poses(&self, id: i64) -> Result<Vec<(PoseSet, PoseMeasurement)>, StoreError> {
        Ok(self
            .measured_rows(id)?
            .into_iter()
            .map(|(set, m, _)| (set, m))
            .collect())
    }

    /// [`Store::measured_poses`] with each pose's P1 row id.
    fn measured_rows(&self, id: i64) -> Result<Vec<(PoseSet, PoseMeasurement, i64)>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT d.pose_index, p.set_name, d.p1_id, d.p2_id FROM pose_done d \
                 JOIN plan_poses p ON p.campaign_id = d.campaign_id AND p.pose_index = d.pose_index \
                 WHERE d.campaign_id = ?1 ORDER BY p.move_order",
            )
            .ctx("read measured poses")?;
        let raw = st
            .query_map([id], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, Option<i64>>(3)?,
                ))
            })
            .ctx("read measured poses")?
            .collect::<Result<Vec<_>, _>>()
            .ctx("read measured poses")?;
        raw.into_iter()
            .map(|(index, set, p1_id, p2_id)| {
                let index = from_sql_index(index, "pose index")?;
                let (p1, joints) = read_point(&self.conn, p1_id)?;
                let joints_rad = joints.ok_or_else(|| {
                    StoreError::Corrupt(format!("pose {index}: P1 row {p1_id} has no joints"))
                })?;
                let p2 = p2_id
                    .map(|r| read_point(&self.conn, r).map(|(p, _)| p))
                    .transpose()?;
                Ok((
                    parse_set(&set)?,
                    PoseMeasurement {
                        index,
                        joints_rad,
                        p1,
                        p2,
                    },
                    p1_id,
                ))
            })
            .collect()
    }

    /// The campaign's measured poses as measured, in plan (move) order: set from the plan,
    /// joints read after settling, P1 and P2 with their recorded stage positions and the
    /// tracker's σ, every point in segment 0's tracker frame (a re-registered segment's points
    /// mapped by its stored transform). What `cellcal export`, the measurements route and
    /// identification ([`identification_rows`]) read.
    pub fn measured(&self, id: i64) -> Result<Vec<MeasuredPose>, StoreError> {
        let refs = self.frame_refs(id)?;
        Ok(self
            .measured_rows(id)?
            .into_iter()
            .map(|(set, m, p1_row)| {
                let t = to_first_frame(&refs, p1_row);
                let point = |p: PointRecord| MeasuredPoint::of(&t, &p);
                MeasuredPose {
                    index: m.index,
                    set,
                    joints_rad: m.joints_rad,
                    p1: point(m.p1),
                    p2: m.p2.map(point),
                }
            })
            .collect())
    }

    /// Create a campaign from data-set rows (`cellcal import`), in one transaction: the plan
    /// is the rows' joints, in row order, with their sets; every pose is done, with P1/P2
    /// rows that carry only positions (other values not recorded, note `imported`). Pose
    /// indices are the rows' ids when all are distinct non-negative integers (so an export
    /// imports back unchanged), else the row numbers 0, 1, …. State is [`IMPORTED_STATE`].
    /// Rows with a rotation are refused (the store keeps tracker points only).
    pub fn import_observations(
        &mut self,
        campaign: &NewCampaign,
        rows: &[Observation],
    ) -> Result<i64, StoreError> {
        if let Some(r) = rows.iter().find(|r| r.rotation.is_some()) {
            return Err(StoreError::Invalid(format!(
                "row {} has a measured rotation, which the campaign store cannot keep",
                r.id
            )));
        }
        let parsed: Vec<Option<usize>> = rows.iter().map(|r| r.id.trim().parse().ok()).collect();
        let distinct: HashSet<usize> = parsed.iter().flatten().copied().collect();
        let use_ids = parsed.iter().all(Option::is_some) && distinct.len() == rows.len();
        let at = campaign.created_at_ms;
        let point = |v: &Vector3<f64>| PointRecord::position_only(v.x, v.y, v.z, at);
        let mut plan = Vec::with_capacity(rows.len());
        let mut poses = Vec::with_capacity(rows.len());
        for (i, r) in rows.iter().enumerate() {
            let index = if use_ids { parsed[i].unwrap_or(i) } else { i };
            plan.push(PlannedPose {
                index,
                set: r.set,
                order: i,
                q_rad: r.q.clone(),
            });
            poses.push(PoseMeasurement {
                index,
                joints_rad: r.q.clone(),
                p1: point(&r.p1),
                p2: r.p2.as_ref().map(point),
            });
        }
        let encoded = check_plan(&plan)?;
        for m in &poses {
            check_measurement(m)?;
        }
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin import")?;
        let id = insert_campaign(&tx, campaign, &plan, &encoded)?;
        tx.execute(
            "UPDATE campaigns SET state = ?2 WHERE id = ?1",
            params![id, IMPORTED_STATE],
        )
        .ctx("set the imported state")?;
        for (m, q) in poses.iter().zip(&encoded) {
            write_pose(&tx, id, m, q, "imported")?;
        }
        tx.commit().ctx("commit import")?;
        Ok(id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::schema::MIGRATIONS;
    use crate::store::tests::setup;

    fn recorded(x: f64, stage_mm: f64, sigma_mm: f64) -> PointRecord {
        PointRecord {
            stage_mm,
            std_mm: [0.001, 0.002, 0.003],
            std_total_mm: sigma_mm,
            ..PointRecord::position_only(x, -2.5, 1.0 / 3.0, 7)
        }
    }

    #[test]
    fn a_measured_pose_keeps_stage_positions_and_the_trackers_sigma() {
        let mut s = Store::open_in_memory().unwrap();
        let id = setup(&mut s);
        let q = vec![0.1, -0.2, 0.3, 0.4, -0.5, 0.6];
        s.commit_pose(
            id,
            &PoseMeasurement {
                index: 1,
                joints_rad: q.clone(),
                p1: recorded(1.5, 2.25, 0.0041),
                p2: Some(recorded(11.5, 12.25, 0.0052)),
            },
        )
        .unwrap();
        s.commit_pose(
            id,
            &PoseMeasurement {
                index: 0,
                joints_rad: q.clone(),
                p1: PointRecord::position_only(3.0, 4.0, 5.0, 9),
                p2: None,
            },
        )
        .unwrap();
        let got = s.measured(id).unwrap();
        assert_eq!(
            got[1],
            MeasuredPose {
                index: 1,
                set: PoseSet::Ident,
                joints_rad: q.clone(),
                p1: MeasuredPoint {
                    position_mm: Vector3::new(1.5, -2.5, 1.0 / 3.0),
                    stage_mm: Some(2.25),
                    sigma_mm: Some(0.0041),
                },
                p2: Some(MeasuredPoint {
                    position_mm: Vector3::new(11.5, -2.5, 1.0 / 3.0),
                    stage_mm: Some(12.25),
                    sigma_mm: Some(0.0052),
                }),
            }
        );
        // what was not recorded reads back as not recorded, not as a number
        assert_eq!(got[0].p1.stage_mm, None);
        assert_eq!(got[0].p1.sigma_mm, None);
        assert_eq!(got[0].p2, None);
        // the identification row of it: the same joints and points, id = pose index
        let rows = identification_rows(got);
        assert_eq!(rows[1].id, "1");
        assert_eq!(rows[1].q, q);
        assert_eq!(rows[1].p2, Some(Vector3::new(11.5, -2.5, 1.0 / 3.0)));
    }

    #[test]
    fn a_store_written_by_the_first_schema_reads_as_measured_poses() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("v1.db");
        {
            // a store as the first cellcal wrote it: schema version 1, rows by hand
            let c = rusqlite::Connection::open(&path).unwrap();
            c.execute_batch(MIGRATIONS[0]).unwrap();
            c.pragma_update(None, "user_version", 1).unwrap();
            c.execute_batch(
                "INSERT INTO campaigns VALUES (1, 'old', 0, 'done', 'np', 4, '', '');
                 INSERT INTO plan_poses VALUES (1, 0, 'verify', 0, '[0.5,0.25]');
                 INSERT INTO measurements (id, campaign_id, pose_index, kind, x_mm, y_mm, z_mm,
                     std_total_mm, stage_mm, sent_at_ms, received_at_ms, joints_rad)
                 VALUES (1, 1, 0, 'p1', 1.0, 2.0, 3.0, 0.004, 0.0, 1, 2, '[0.5,0.25]'),
                        (2, 1, 0, 'p2', 1.0, 12.0, 3.0, NULL, 10.0, 3, 4, '[0.5,0.25]');
                 INSERT INTO pose_done VALUES (1, 0, 1, 2);",
            )
            .unwrap();
        }
        let s = Store::open(&path).unwrap();
        let got = s.measured(1).unwrap();
        assert_eq!(got.len(), 1);
        let m = &got[0];
        assert_eq!((m.index, m.set), (0, PoseSet::Verify));
        assert_eq!(m.joints_rad, vec![0.5, 0.25]);
        assert_eq!(m.p1.position_mm, Vector3::new(1.0, 2.0, 3.0));
        assert_eq!((m.p1.stage_mm, m.p1.sigma_mm), (Some(0.0), Some(0.004)));
        let p2 = m.p2.unwrap();
        assert_eq!((p2.stage_mm, p2.sigma_mm), (Some(10.0), None));
    }
}
