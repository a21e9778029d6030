//! Partial-pose measurement geometry: rigid registration of point sets (base frame).

pub mod rigid;

pub use rigid::{fit_rigid, RigidFitError};
