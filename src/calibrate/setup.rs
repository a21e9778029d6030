//! The cell setup a calibration is given: the measured tool frame (ball position, stage axis)
//! and the registered base, as the campaign stores them (JSON) once per campaign. The steps that
//! measure them and the recipe that applies them are `campaign::engine::setup`'s; the report
//! shows them.

use serde::{Deserialize, Serialize};

/// The measured tool frame (all vectors in the flange frame unless named `_tracker`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToolFrameResult {
    /// Ball centre at stage P1 in the flange frame (mm).
    pub tool_mm: [f64; 3],
    /// Unit stage axis in the flange frame.
    pub stage_axis: [f64; 3],
    /// Flange origin (the sphere centre) in the tracker frame (mm).
    pub flange_origin_tracker_mm: [f64; 3],
    /// Flange x, y, z axes in the tracker frame (unit vectors, rows).
    pub flange_axes_tracker: [[f64; 3]; 3],
    /// Sphere radius = |tool| (mm).
    pub sphere_radius_mm: f64,
    /// RMS of the sphere fit (mm).
    pub sphere_rms_mm: f64,
    /// Angle between the measured jog axes (deg; 90 for a square flange).
    pub jog_axes_angle_deg: f64,
    /// Measured stage travel P1 → P2 (mm, mean over the pairs).
    pub stage_travel_measured_mm: f64,
    /// Targets measured.
    pub targets: usize,
}

/// The registered base (tracker ← robot base, on the nominal model with the measured tool).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BaseResult {
    /// Translation robot base → tracker frame (mm).
    pub translation_mm: [f64; 3],
    /// Rotation robot base → tracker frame, rotation vector (rad).
    pub rotation_vector_rad: [f64; 3],
    /// RMS residual (mm): the nominal model's own error at these poses plus noise.
    pub rms_mm: f64,
    /// Largest residual (mm).
    pub max_mm: f64,
    /// The tracker's position in the robot base frame (mm).
    pub tracker_in_base_mm: [f64; 3],
    /// Poses used.
    pub poses: usize,
}

/// A campaign's cell setup (each part present when configured).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SetupResult {
    /// The tool-frame procedure.
    pub tool_frame: Option<ToolFrameResult>,
    /// The base registration.
    pub base: Option<BaseResult>,
}
