//! The cell setup steps, run once per campaign before the drift baseline: the tool-frame
//! procedure of docs/method.md §4 and the base registration. Every point is stored (`setup` rows, with
//! the mark in the note) before the robot moves on; the result is stored as JSON and reused on
//! resume. A setup resumed before its result was stored reuses the points already taken (a
//! manual stage's readings are not asked again) once one of them, measured again at its
//! joints, shows the tracker frame unmoved; a setup whose fit is refused marks its points
//! refused (a `discarded` marker row: measurements are append-only) and is measured afresh.

use std::collections::HashMap;

use nalgebra::Vector3;

use super::{settle_error, CampaignError, Run, Step, Stop};
use crate::campaign::events::CampaignEvent;
use crate::identify::IdentifyOptions;
use crate::measure::{
    plan_tool_frame, register_base, select_spread, solve_tool_frame, SetupMeasurement, SetupTarget,
    ToolFramePlanRequest,
};
use crate::model::RobotModel;
use crate::plan::setup::home_tool_frame_targets;
use crate::store::{PointKind, SetupPoint, Store, StoreError};

pub use crate::calibrate::setup::{BaseResult, SetupResult, ToolFrameResult};

impl SetupResult {
    /// The campaign's stored setup, if any.
    pub fn load(store: &Store, id: i64) -> Result<Option<SetupResult>, StoreError> {
        match store.latest_setup(id)? {
            None => Ok(None),
            Some(t) => serde_json::from_str(&t)
                .map(Some)
                .map_err(|e| StoreError::Corrupt(format!("setup result: {e}"))),
        }
    }

    /// The measured tool and stage axis into `model` and `stage_axis`, and the registered base
    /// when `identify_base` is false (the live deviation's model: `frame::Aim`, with false).
    /// The campaign's identification recipe is [`Self::apply_to_identification`].
    pub fn apply(
        &self,
        model: &mut RobotModel,
        stage_axis: &mut Vector3<f64>,
        identify_base: bool,
    ) {
        if let Some(t) = &self.tool_frame {
            model.tool = Vector3::from(t.tool_mm);
            *stage_axis = Vector3::from(t.stage_axis);
        }
        if let (Some(b), false) = (&self.base, identify_base) {
            model.base_translation = Vector3::from(b.translation_mm);
            model.base_rotation =
                crate::model::rotation::from_rotation_vector(&Vector3::from(b.rotation_vector_rad));
        }
    }
}

impl SetupResult {
    /// The campaign's recipe: the measured tool and stage axis into `model` and `opts`, and the
    /// registered base into `model` whenever there is one (`opts.registered_base`): held when
    /// the base is not identified, else the base of the "before" (as the live deviation's).
    pub fn apply_to_identification(&self, model: &mut RobotModel, opts: &mut IdentifyOptions) {
        self.apply(model, &mut opts.obs.stage_axis, false);
        opts.registered_base = self.base.is_some();
    }
}

/// A stored point's position (mm, tracker frame).
fn position(p: &SetupPoint) -> Vector3<f64> {
    Vector3::new(p.point.x_mm, p.point.y_mm, p.point.z_mm)
}

fn arr(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl Run<'_> {
    /// The campaign's setup: the stored one on resume, else measured now and stored.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// `guarded`), never by dropping it.
    pub(super) async fn setup(&mut self) -> Result<SetupResult, Stop> {
        let id = self.ctx.campaign_id;
        if let Some(done) = self.store(move |s| SetupResult::load(s, id)).await? {
            return Ok(done);
        }
        let cfg = &self.ctx.cfg.setup;
        if !cfg.tool_frame && !cfg.base_registration {
            return Ok(SetupResult::default());
        }
        let (do_tool, do_base) = (cfg.tool_frame, cfg.base_registration);
        self.step = Step::Setup;
        let kept = self.kept_setup_points().await?;
        let mut model = self.ctx.nominal.clone();
        let mut result = SetupResult::default();
        if do_tool {
            let t = self.tool_frame(&kept).await?;
            model.tool = Vector3::from(t.tool_mm);
            result.tool_frame = Some(t);
        }
        if do_base {
            result.base = Some(self.base_registration(&model, &kept).await?);
        }
        let json = serde_json::to_string(&result)
            .map_err(|e| Stop::Store(CampaignError::Task(e.to_string())))?;
        self.store(move |s| s.save_setup(id, &json)).await?;
        self.journal(CampaignEvent::Setup {
            result: Box::new(result.clone()),
        })
        .await?;
        Ok(result)
    }

    /// The setup points stored before (a setup resumed after an abort, a kill or a fault),
    /// by the mark in their note (the latest of each), when the tracker frame has not moved
    /// since: the latest of them at P1 is measured again at its joints and must agree within
    /// `campaign.drift_max_mm` (the check a resume makes at the frame reference); otherwise
    /// they are marked refused and nothing is reused. Not cancel-safe: one step of the
    /// run, ended by the abort token (every device wait is `guarded`), never by dropping it.
    async fn kept_setup_points(&mut self) -> Result<HashMap<String, SetupPoint>, Stop> {
        let id = self.ctx.campaign_id;
        let stored = self.store(move |s| s.setup_points(id)).await?;
        let s1 = self.ctx.cfg.stage.p1_mm;
        let tol = self.ctx.cfg.stage.tolerance_mm;
        let dof = self.ctx.nominal.dof();
        let Some(check) = stored
            .iter()
            .rev()
            .find(|p| (p.point.stage_mm - s1).abs() <= tol && p.joints_rad.len() == dof)
            .cloned()
        else {
            return Ok(HashMap::new());
        };
        self.wait_unpaused().await?;
        let joints = self.move_to(&check.joints_rad).await?;
        let a1 = self.stage_to(s1).await?;
        let p = self.measure_point(None, &joints, a1).await?;
        let note = format!(
            "setup check: {} measured again (row {})",
            check.note, check.row
        );
        self.keep_point(PointKind::Drift, None, &joints, &p, a1, note)
            .await?;
        let moved = (p.p_mm - position(&check)).norm();
        let max = self.ctx.cfg.campaign.drift_max_mm;
        if moved.is_nan() || moved > max {
            self.discard_setup(format!("the tracker frame moved by {moved:.3} mm"))
                .await?;
            self.journal(CampaignEvent::Note {
                text: format!(
                    "setup: the tracker or the robot moved by {moved:.3} mm since the setup \
                     points were taken (limit {max} mm): the setup is measured again"
                ),
            })
            .await?;
            return Ok(HashMap::new());
        }
        self.journal(CampaignEvent::Note {
            text: format!(
                "setup: {} points taken before are reused (the tracker frame checked at {}: \
                 {moved:.3} mm, limit {max} mm)",
                stored.len(),
                check.note
            ),
        })
        .await?;
        Ok(stored.into_iter().map(|p| (p.note.clone(), p)).collect())
    }

    /// How far (rad) settled joints may be from their target (`settle_tolerance_deg`).
    pub(super) fn settle_tolerance(&self) -> f64 {
        self.ctx
            .cfg
            .robot_controller
            .settle_tolerance_deg
            .to_radians()
    }

    /// Mark every stored setup point refused with `why` (a setup measured again does not
    /// reuse them). Cancel-safe in effect, as [`super::with_store`].
    async fn discard_setup(&self, why: String) -> Result<(), CampaignError> {
        let id = self.ctx.campaign_id;
        self.store(move |s| s.discard_setup_points(id, &why))
            .await
            .map(|_| ())
    }

    /// docs/method.md §4: jogs along flange x and y, rotations about them, P1/P2 pairs for the stage.
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// `guarded`), never by dropping it.
    async fn tool_frame(
        &mut self,
        kept: &HashMap<String, SetupPoint>,
    ) -> Result<ToolFrameResult, Stop> {
        let cfg = &self.ctx.cfg.setup;
        let req = cfg.tool_frame_request();
        let max_rms = cfg.max_sphere_rms_mm;
        let targets = match &cfg.home_deg {
            Some(h) => {
                let q0: Vec<f64> = h.iter().map(|d| d.to_radians()).collect();
                let t = plan_tool_frame(&self.ctx.nominal, &q0, &req)
                    .map_err(|e| Stop::Failed(format!("setup: {e}")))?;
                if let Some(bad) = t.iter().find(|t| !self.target_safe(&t.q_rad)) {
                    return Err(Stop::Failed(format!(
                        "setup: target {} from setup.home_deg fails the joint-limit/workspace check",
                        bad.mark.label()
                    )));
                }
                t
            }
            None => self.home_targets(&req)?,
        };
        let s1 = self.ctx.cfg.stage.p1_mm;
        let s2 = s1 + self.ctx.cfg.stage.travel_mm;
        let tol = self.settle_tolerance();
        let mut meas = Vec::with_capacity(targets.len());
        for t in &targets {
            let label = t.mark.label();
            // a point of this mark taken at this target's joints (a changed setup is measured)
            let stored = |at: &str| {
                kept.get(&format!("tool frame {label} {at}"))
                    .filter(|p| settle_error(&t.q_rad, &p.joints_rad, tol).is_none())
                    .map(position)
            };
            // taken before (P2 too, when the target measures one): reused, not asked again
            let p2 = if t.measure_p2 {
                stored("P2").map(Some)
            } else {
                Some(None)
            };
            if let (Some(p1), Some(p2)) = (stored("P1"), p2) {
                meas.push(SetupMeasurement {
                    mark: t.mark,
                    p1,
                    p2,
                });
                continue;
            }
            self.wait_unpaused().await?;
            let joints = self.move_to(&t.q_rad).await?;
            let a1 = self.stage_to(s1).await?;
            let p1 = self.measure_point(None, &joints, a1).await?;
            self.keep_point(
                PointKind::Setup,
                None,
                &joints,
                &p1,
                a1,
                format!("tool frame {label} P1"),
            )
            .await?;
            let p2 = if t.measure_p2 {
                let a2 = self.stage_to(s2).await?;
                let p2 = self.measure_point(None, &joints, a2).await?;
                self.keep_point(
                    PointKind::Setup,
                    None,
                    &joints,
                    &p2,
                    a2,
                    format!("tool frame {label} P2"),
                )
                .await?;
                Some(p2.p_mm)
            } else {
                None
            };
            meas.push(SetupMeasurement {
                mark: t.mark,
                p1: p1.p_mm,
                p2,
            });
        }
        let f = match solve_tool_frame(&meas) {
            Ok(f) => f,
            Err(e) => {
                self.discard_setup(format!("tool frame refused: {e}"))
                    .await?;
                return Err(Stop::Fault(format!("tool frame: {e}")));
            }
        };
        if f.sphere.rms_mm > max_rms {
            self.discard_setup(format!(
                "tool frame refused: sphere fit RMS {:.4} mm",
                f.sphere.rms_mm
            ))
            .await?;
            return Err(Stop::Fault(format!(
                "tool frame: sphere fit RMS {:.4} mm above {max_rms} mm: check that the ball sits firmly in its nest, then resume to measure the tool frame again",
                f.sphere.rms_mm
            )));
        }
        Ok(ToolFrameResult {
            tool_mm: arr(&f.tool_mm),
            stage_axis: arr(&f.stage_axis),
            flange_origin_tracker_mm: arr(&f.origin_mm),
            flange_axes_tracker: [arr(&f.x_axis), arr(&f.y_axis), arr(&f.z_axis)],
            sphere_radius_mm: f.sphere.radius_mm,
            sphere_rms_mm: f.sphere.rms_mm,
            jog_axes_angle_deg: f.jog_axes_angle_rad.to_degrees(),
            stage_travel_measured_mm: f.stage_travel_mm,
            targets: meas.len(),
        })
    }

    /// The tool-frame targets from the planned pose nearest the box centre whose every target
    /// solves and passes the safety checks ([`home_tool_frame_targets`]).
    fn home_targets(&self, req: &ToolFramePlanRequest) -> Result<Vec<SetupTarget>, Stop> {
        let ctx = self.ctx;
        home_tool_frame_targets(&ctx.nominal, &ctx.plan, &ctx.plan_request, req).map_err(|last| {
            Stop::Failed(format!(
                "setup: no planned pose near the box centre can carry the tool-frame jogs and rotations ({last}); set setup.home_deg"
            ))
        })
    }

    /// Tracker ← robot base from spread planned poses on `model` (nominal + measured tool).
    /// Not cancel-safe: one step of the run, ended by the abort token (every device wait is
    /// `guarded`), never by dropping it.
    async fn base_registration(
        &mut self,
        model: &RobotModel,
        kept: &HashMap<String, SetupPoint>,
    ) -> Result<BaseResult, Stop> {
        let n = self.ctx.cfg.setup.base_poses;
        let max_rms = self.ctx.cfg.setup.max_base_rms_mm;
        let candidates: Vec<Vec<f64>> = self
            .ctx
            .plan
            .poses
            .iter()
            .map(|p| p.q_rad.clone())
            .collect();
        let chosen = select_spread(model, &candidates, n);
        let s1 = self.ctx.cfg.stage.p1_mm;
        let tol = self.settle_tolerance();
        let mut pairs = Vec::with_capacity(chosen.len());
        for (k, i) in chosen.into_iter().enumerate() {
            let stored = kept
                .get(&format!("base registration {}", k + 1))
                .filter(|p| settle_error(&candidates[i], &p.joints_rad, tol).is_none());
            if let Some(p) = stored {
                // taken before: reused, not asked again
                pairs.push((p.joints_rad.clone(), position(p)));
                continue;
            }
            self.wait_unpaused().await?;
            let joints = self.move_to(&candidates[i]).await?;
            let a1 = self.stage_to(s1).await?;
            let p = self.measure_point(None, &joints, a1).await?;
            self.keep_point(
                PointKind::Setup,
                None,
                &joints,
                &p,
                a1,
                format!("base registration {}", k + 1),
            )
            .await?;
            pairs.push((joints, p.p_mm));
        }
        let reg = match register_base(model, &pairs) {
            Ok(reg) => reg,
            Err(e) => {
                self.discard_setup(format!("base registration refused: {e}"))
                    .await?;
                return Err(Stop::Fault(format!("base registration: {e}")));
            }
        };
        if reg.rms_mm > max_rms {
            self.discard_setup(format!(
                "base registration refused: RMS {:.3} mm",
                reg.rms_mm
            ))
            .await?;
            return Err(Stop::Fault(format!(
                "base registration RMS {:.3} mm above {max_rms} mm: check the robot model file, the tool and the tracker's view, then resume",
                reg.rms_mm
            )));
        }
        let tracker_in_base = reg.base.r.transpose() * (-reg.base.p);
        Ok(BaseResult {
            translation_mm: arr(&reg.base.p),
            rotation_vector_rad: arr(&reg.base.rotation_vector()),
            rms_mm: reg.rms_mm,
            max_mm: reg.max_mm,
            tracker_in_base_mm: arr(&tracker_in_base),
            poses: pairs.len(),
        })
    }
}
