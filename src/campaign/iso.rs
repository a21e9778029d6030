//! The ISO 9283 figures of a stored ISO campaign, from the store alone (its kind's plan, its
//! stored configuration, its setup result and its measured visits): what the campaign stores
//! as its result at the end of `run` and what `cellcal iso9283` recomputes.
//!
//! Frame: the robot base frame. The attained points (tracker frame, segment 0) are mapped into
//! it by the compensated model's base when the targets were compensated (the frame those
//! targets were placed in), else by the setup's base registration (nominal model, measured
//! tool); the commanded positions are the plan's Cartesian targets. The commanded axis
//! direction is the stage axis (the setup's measured one, else the configured one) turned by
//! the commanded flange orientation.

use std::path::PathBuf;

use nalgebra::Vector3;

use super::engine::SetupResult;
use crate::config::parse_cell_config;
use crate::iso9283::{
    complete_cycles, group_complete_cycles, pose_figures, IsoError, IsoReport, Visit,
    ORIENTATION_NOTE,
};
use crate::model::kinematics::Pose;
use crate::model::rotation::from_rotation_vector;
use crate::plan::iso9283::IsoPlan;
use crate::store::{Store, StoreError, ISO9283_KIND};

/// Why a stored campaign has no ISO 9283 figures.
#[derive(Debug, thiserror::Error)]
pub enum IsoResultError {
    /// The store could not be read, or the campaign does not exist.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A calibration campaign.
    #[error("campaign {0} is not an ISO 9283 campaign")]
    NotIso(i64),
    /// The stored plan, configuration or a visit no longer reads.
    #[error("campaign {id}: {message}")]
    Stored {
        /// Campaign id.
        id: i64,
        /// What does not read.
        message: String,
    },
    /// Neither a compensated model's base nor a base registration.
    #[error("campaign {0} has no robot base frame (no base registration stored yet)")]
    NoFrame(i64),
    /// Repeatability needs at least two complete cycles.
    #[error("campaign {id}: {complete} complete cycle(s); ISO 9283 figures need at least 2")]
    TooFewCycles {
        /// Campaign id.
        id: i64,
        /// Complete cycles measured.
        complete: usize,
    },
    /// The figures of a pose.
    #[error("campaign {id}: {cause}")]
    Figures {
        /// Campaign id.
        id: i64,
        /// Why.
        cause: IsoError,
    },
}

/// Whether campaign `id` is an ISO 9283 campaign (not a calibration).
pub fn is_iso_campaign(store: &Store, id: i64) -> Result<bool, StoreError> {
    Ok(store
        .campaign_kind(id)?
        .is_some_and(|k| k.kind == ISO9283_KIND))
}

/// The ISO plan of campaign `id`; `NotIso` for a calibration campaign.
pub fn stored_iso_plan(store: &Store, id: i64) -> Result<IsoPlan, IsoResultError> {
    let kind = store
        .campaign_kind(id)?
        .filter(|k| k.kind == ISO9283_KIND)
        .ok_or(IsoResultError::NotIso(id))?;
    serde_json::from_str(&kind.plan_json).map_err(|e| IsoResultError::Stored {
        id,
        message: format!("its ISO plan: {e}"),
    })
}

/// The robot base frame (tracker ← base) of the figures and how it was realised.
fn report_frame(
    plan: &IsoPlan,
    setup: Option<&SetupResult>,
    id: i64,
) -> Result<(Pose, &'static str), IsoResultError> {
    if let Some(b) = &plan.model_base {
        return Ok((
            b.pose(),
            "robot base frame (realised by the compensated model's base)",
        ));
    }
    let b = setup
        .and_then(|s| s.base.as_ref())
        .ok_or(IsoResultError::NoFrame(id))?;
    Ok((
        Pose {
            r: from_rotation_vector(&Vector3::from(b.rotation_vector_rad)),
            p: Vector3::from(b.translation_mm),
        },
        "robot base frame (realised by the setup's base registration on the nominal model)",
    ))
}

/// The ISO 9283 figures of campaign `id` over its complete cycles (a partly measured campaign
/// says so in `partial`).
pub fn iso_report(store: &Store, id: i64) -> Result<IsoReport, IsoResultError> {
    let plan = stored_iso_plan(store, id)?;
    let stored = |message: String| IsoResultError::Stored { id, message };
    let row = store.campaign(id)?;
    let label = PathBuf::from(format!("campaign {id}.toml"));
    let cfg = parse_cell_config(&row.config_toml, &label)
        .map_err(|e| stored(format!("its stored configuration: {e}")))?;
    let rows = store.measured(id)?;
    let complete = complete_cycles(rows.iter().map(|m| m.index));
    if complete < 2 {
        return Err(IsoResultError::TooFewCycles { id, complete });
    }
    let setup = SetupResult::load(store, id)?;
    let (base, frame) = report_frame(&plan, setup.as_ref(), id)?;
    let to_base = base.inverse();
    let visits: Vec<Visit> = rows
        .into_iter()
        .map(|m| Visit {
            index: m.index,
            p1_mm: to_base.transform_point(&m.p1.position_mm),
            p2_mm: m.p2.map(|p| to_base.transform_point(&p.position_mm)),
        })
        .collect();
    let axis = setup
        .as_ref()
        .and_then(|s| s.tool_frame.as_ref())
        .map(|t| Vector3::from(t.stage_axis))
        .or_else(|| cfg.stage.axis_vector())
        .unwrap_or_else(Vector3::y);
    let r = plan.rotation();
    let mut commanded = [Vector3::zeros(); 5];
    for (k, c) in commanded.iter_mut().enumerate() {
        let p = plan
            .pose(k + 1)
            .ok_or_else(|| stored(format!("its ISO plan has no P{}", k + 1)))?;
        *c = Vector3::from(p.target_mm);
    }
    let (complete, per_pose) = group_complete_cycles(&visits, &commanded, &[r * axis; 5]);
    let poses = per_pose
        .iter()
        .map(pose_figures)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|cause| IsoResultError::Figures { id, cause })?;
    Ok(IsoReport {
        kind: ISO9283_KIND.to_owned(),
        frame: frame.to_owned(),
        orientation_note: ORIENTATION_NOTE.to_owned(),
        cycles_planned: plan.cycles,
        cycles_complete: complete,
        partial: complete < plan.cycles,
        compensated: plan.compensated,
        compensated_model: cfg
            .iso9283
            .and_then(|i| i.compensated_model)
            .map(|p| p.display().to_string()),
        poses,
    })
}
