//! Reports: the `cellcal identify` pipeline, its JSON contract, its verdict, its printed
//! summary and the HTML calibration report.

pub mod html;
pub mod identify_json;
pub mod quality;
pub mod summary;

pub use identify_json::{calibrate, CalibrateError, IdentifyReport};
pub use quality::{Quality, QualityWarning};
pub use summary::summary_text;
