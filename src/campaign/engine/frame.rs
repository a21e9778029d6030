//! The campaign's tracker frame: the reference measured at the first start (segment 0), its
//! comparison at every start and every `drift_every` poses, and re-registration after the
//! tracker or the robot moved (a new segment whose rigid transform into segment 0's frame is
//! fitted on points re-measured at joints stored in the old frame), plus where the ball should be
//! now (the aim of a re-lock).

use std::collections::HashSet;

use nalgebra::Vector3;

use super::{Run, SetupResult, Step, Stop};
use crate::campaign::events::CampaignEvent;
use crate::measure::{fit_rigid, select_spread};
use crate::model::{forward, Pose, RobotModel};
use crate::store::{map_point, to_first_frame, FrameRef, FrameTransform, JointPoint, PointKind};

/// Spread points (beyond the unverified poses) a re-registration measures again.
const REREGISTER_SPREAD: usize = 8;
/// Fewest distinct common points a re-registration accepts (3 fix the frame; the rest check it).
const REREGISTER_MIN: usize = 4;

/// Where the ball should be in the current tracker frame: the nominal model with the registered
/// base and the measured tool (docs/method.md §4), in the frame of the segment being measured. The
/// `measured` events' deviation from it is the result's "before" (`before_base:
/// setup_registration`): the same model.
#[derive(Debug, Clone)]
pub(super) struct Aim {
    /// Nominal model, registered base (segment 0's frame), measured tool.
    model: RobotModel,
    stage_axis: Vector3<f64>,
    p1_mm: f64,
    /// The current segment ← segment 0.
    from_first: Pose,
}

impl Aim {
    /// The aim of a campaign with this setup; `None` without a registered base.
    pub(super) fn new(
        nominal: &RobotModel,
        setup: &SetupResult,
        stage_axis: Vector3<f64>,
        p1_mm: f64,
    ) -> Option<Aim> {
        setup.base.as_ref()?;
        let mut model = nominal.clone();
        let mut axis = stage_axis;
        setup.apply(&mut model, &mut axis, false);
        Some(Aim {
            model,
            stage_axis: axis,
            p1_mm,
            from_first: Pose::identity(),
        })
    }

    /// The predicted ball centre at joints `q` with the stage at `stage_mm` (tracker frame).
    pub(super) fn ball(&self, q: &[f64], stage_mm: f64) -> Option<Vector3<f64>> {
        if q.len() != self.model.dof() {
            return None;
        }
        let in_flange = self.model.tool + self.stage_axis * (stage_mm - self.p1_mm);
        let in_base = forward(&self.model, q).flange().transform_point(&in_flange);
        let first = self.model.base().transform_point(&in_base);
        Some(map_point(&self.from_first, first))
    }

    /// Aim in the frame of a segment (segment 0 ← it: `to_first`).
    fn in_segment(&mut self, to_first: Option<&FrameTransform>) {
        self.from_first = to_first.map_or_else(Pose::identity, |t| t.to_first.inverse());
    }
}

fn position(p: &JointPoint) -> Vector3<f64> {
    Vector3::new(p.point.x_mm, p.point.y_mm, p.point.z_mm)
}

/// The stored row of the last drift measurement of a segment that agreed with its reference
/// within `max_mm`: every pose committed before it is known to be in that segment's frame.
fn last_verified_row(points: &[JointPoint], reference: &FrameRef, max_mm: f64) -> i64 {
    let r = &reference.point;
    let at = Vector3::new(r.x_mm, r.y_mm, r.z_mm);
    points
        .iter()
        .filter(|p| p.kind == "drift" && (position(p) - at).norm() <= max_mm)
        .map(|p| p.row)
        .max()
        .unwrap_or(reference.measurement_id)
}

impl Run<'_> {
    /// The reference point of the campaign's tracker frame. At the first start it is measured
    /// and stored (frame segment 0); every later start measures it again at the same joints
    /// and compares: farther than `drift_max_mm` means the tracker or the robot moved between
    /// sessions, and measuring on would mix two frames in one campaign — an operator fault,
    /// unless a re-registration was asked for (then a new segment starts here).
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// `guarded`), never by dropping it.
    pub(super) async fn frame_reference(
        &mut self,
        poses_done: usize,
    ) -> Result<Vector3<f64>, Stop> {
        // a re-registration asked for applies to this check only, moved or not
        let reregister = self.ctx.control.take_reregister();
        let id = self.ctx.campaign_id;
        let refs = self.store(move |s| s.frame_refs(id)).await?;
        let max = self.ctx.cfg.campaign.drift_max_mm;
        let Some(last) = refs.last().cloned() else {
            let q = self.ctx.plan.drift_reference.clone();
            let (p, row) = self.drift_point(&q).await?;
            self.store(move |s| s.add_frame_ref(id, row, poses_done, None))
                .await?;
            self.drift_q = q;
            self.journal(CampaignEvent::Drift {
                drift_mm: 0.0,
                max_mm: max,
            })
            .await?;
            return Ok(p);
        };
        self.drift_q = last.joints_rad.clone();
        if let Some(aim) = self.aim.as_mut() {
            aim.in_segment(last.to_first.as_ref());
        }
        let stored = Vector3::new(last.point.x_mm, last.point.y_mm, last.point.z_mm);
        let q = self.drift_q.clone();
        let (p, _) = self.drift_point(&q).await?;
        let moved = (p - stored).norm();
        self.journal(CampaignEvent::Drift {
            drift_mm: moved,
            max_mm: max,
        })
        .await?;
        if moved <= max {
            return Ok(stored);
        }
        if reregister {
            return self.reregister(&refs, poses_done, moved).await;
        }
        Err(Stop::Fault(format!(
            "the tracker or the robot moved by {moved:.3} mm since pose {poses_done} (limit {max} mm): \
             measuring on would mix two tracker frames in one campaign. Put it back and resume \
             (the reference is measured again), re-register (the old frame's points are measured \
             again and the new frame fitted to them), or abort"
        )))
    }

    /// Measure the drift reference again and compare with `baseline`.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// `guarded`), never by dropping it.
    pub(super) async fn check_drift(&mut self, baseline: &Vector3<f64>) -> Result<(), Stop> {
        let q = self.drift_q.clone();
        let (p, _) = self.drift_point(&q).await?;
        let drift = (p - baseline).norm();
        let max = self.ctx.cfg.campaign.drift_max_mm;
        self.journal(CampaignEvent::Drift {
            drift_mm: drift,
            max_mm: max,
        })
        .await?;
        if drift > max {
            return Err(Stop::Fault(format!(
                "drift {drift:.4} mm at the reference pose exceeds {max} mm: check the tracker and the mounting; resuming measures the reference again"
            )));
        }
        Ok(())
    }

    /// Start a new frame segment: measure its reference first (every later row belongs to it),
    /// then, at joints stored in the latest segment, the poses not yet confirmed by a drift check
    /// and a spread of confirmed points; fit the rigid transform into segment 0's frame (every
    /// residual within `drift_max_mm`, else refused) and store the segment with it. Returns the
    /// new reference (the baseline of later drift checks).
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// `guarded`), never by dropping it.
    async fn reregister(
        &mut self,
        refs: &[FrameRef],
        poses_done: usize,
        moved_mm: f64,
    ) -> Result<Vector3<f64>, Stop> {
        let id = self.ctx.campaign_id;
        let max = self.ctx.cfg.campaign.drift_max_mm;
        let s1 = self.ctx.cfg.stage.p1_mm;
        let last = refs
            .last()
            .cloned()
            .ok_or_else(|| Stop::Failed("re-registration without a frame to re-register".into()))?;
        let q = self.drift_q.clone();
        let (reference, ref_row) = self.drift_point(&q).await?;
        let from = last.measurement_id;
        let old = self
            .store(move |s| s.joint_points(id, from..ref_row, s1))
            .await?;
        let chosen = self.common_points(&old, &last, max);
        if chosen.len() < REREGISTER_MIN {
            return Err(Stop::Fault(format!(
                "cannot re-register: only {} distinct points with joints were measured in the \
                 current frame (at least {REREGISTER_MIN} needed); put the tracker back, or abort \
                 and start a new campaign",
                chosen.len()
            )));
        }
        let mut now = Vec::with_capacity(chosen.len());
        let mut first = Vec::with_capacity(chosen.len());
        self.step = Step::Reregister;
        for c in &chosen {
            self.wait_unpaused().await?;
            let joints = self.move_to(&c.joints_rad).await?;
            let s = self.stage_to(s1).await?;
            let p = self.measure_point(None, &joints, s).await?;
            let note = match c.pose {
                Some(i) => format!("re-registration: pose {i} (row {})", c.row),
                None => format!("re-registration: {} row {}", c.kind, c.row),
            };
            self.keep_point(PointKind::Drift, None, &joints, &p, s, note)
                .await?;
            now.push(p.p_mm);
            first.push(map_point(&to_first_frame(refs, c.row), position(c)));
        }
        let to_first =
            fit_rigid(&now, &first).map_err(|e| Stop::Fault(format!("cannot re-register: {e}")))?;
        let residuals: Vec<f64> = now
            .iter()
            .zip(&first)
            .map(|(a, b)| (map_point(&to_first, *a) - b).norm())
            .collect();
        let worst = residuals
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, r)| (i, *r))
            .unwrap_or((0, 0.0));
        if worst.1 > max {
            let c = &chosen[worst.0];
            return Err(Stop::Fault(format!(
                "re-registration refused: after the best rigid fit, the point of row {} ({}) \
                 disagrees by {:.3} mm (limit {max} mm): the old frame's points do not form one \
                 rigid frame with the new ones (the cell moved while measuring?); abort",
                c.row,
                c.pose
                    .map_or_else(|| c.kind.clone(), |i| format!("pose {i}")),
                worst.1
            )));
        }
        let rms = (residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64).sqrt();
        let transform = FrameTransform {
            to_first,
            rms_mm: rms,
            max_mm: worst.1,
            points: now.len(),
        };
        if let Some(aim) = self.aim.as_mut() {
            aim.in_segment(Some(&transform));
        }
        let segment = self
            .store(move |s| s.add_frame_ref(id, ref_row, poses_done, Some(&transform)))
            .await?;
        let step = to_first_frame(refs, ref_row - 1)
            .inverse()
            .compose(&to_first);
        self.journal(CampaignEvent::Note {
            text: format!(
                "tracker frame re-registered (segment {segment}): the reference had moved by \
                 {moved_mm:.3} mm; the new frame is {:.3} mm and {:.3} mrad from the previous one, \
                 fitted on {} points re-measured at stored joints (rms {rms:.4} mm, max {:.4} mm)",
                step.p.norm(),
                step.rotation_angle() * 1e3,
                now.len(),
                worst.1
            ),
        })
        .await?;
        Ok(reference)
    }

    /// The points of the latest segment a re-registration measures again: every pose after the
    /// last drift check that agreed (it may have been measured after the move), then a spread
    /// of the others; distinct joints, each target passing the safety checks.
    fn common_points(&self, old: &[JointPoint], last: &FrameRef, max_mm: f64) -> Vec<JointPoint> {
        let model = &self.ctx.nominal;
        let mut seen = HashSet::new();
        let usable: Vec<&JointPoint> = old
            .iter()
            .filter(|p| p.joints_rad.len() == model.dof() && self.target_safe(&p.joints_rad))
            .filter(|p| seen.insert(p.joints_rad.iter().map(|v| v.to_bits()).collect::<Vec<_>>()))
            .collect();
        let verified = last_verified_row(old, last, max_mm);
        let (unverified, confirmed): (Vec<&JointPoint>, Vec<&JointPoint>) = usable
            .into_iter()
            .partition(|p| p.kind == "p1" && p.row > verified);
        let joints: Vec<Vec<f64>> = confirmed.iter().map(|p| p.joints_rad.clone()).collect();
        let spread = select_spread(model, &joints, REREGISTER_SPREAD);
        unverified
            .into_iter()
            .chain(spread.into_iter().map(|i| confirmed[i]))
            .cloned()
            .collect()
    }
}
