//! Reports: the `cellcal identify` pipeline, its JSON contract, its verdict, its printed
//! summary, the corrected model file and the HTML calibration report.

pub mod html;
pub mod identify_json;
pub mod model_file;
pub mod quality;
pub mod summary;

pub use identify_json::{calibrate, CalibrateError, IdentifyReport, ParamStatus};
pub use model_file::{corrected_model, corrected_model_toml, BaseSource, ModelFileError};
pub use quality::{Quality, QualityWarning};
pub use summary::summary_text;
