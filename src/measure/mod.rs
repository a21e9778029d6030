//! Measurement geometry: rigid registration of point sets, sphere fits, the tool-frame setup
//! procedure and the base registration of the cell setup.

pub mod base_registration;
pub mod rigid;
pub mod sphere;
pub mod tool_frame;

pub use base_registration::{
    base_from_tool_frame, register_base, select_spread, BaseRegistration, BaseRegistrationError,
};
pub use rigid::{fit_rigid, RigidFitError};
pub use sphere::{fit_sphere, Sphere, SphereFitError};
pub use tool_frame::{
    plan_tool_frame, solve_tool_frame, SetupMark, SetupMeasurement, SetupTarget, ToolFrame,
    ToolFrameError, ToolFramePlanError, ToolFramePlanRequest,
};
