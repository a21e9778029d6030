//! Reports: the `cellcal identify` pipeline, its JSON contract and its printed summary.

pub mod identify_json;
pub mod summary;

pub use identify_json::{calibrate, CalibrateError, IdentifyReport};
pub use summary::summary_text;
