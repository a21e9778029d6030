//! Renderings of a calibration result ([`crate::calibrate`]): the printed summary, the
//! corrected model file and the HTML calibration report.

pub mod extended;
pub mod html;
pub mod model_file;
pub mod summary;

pub use model_file::corrected_model_toml;
pub use summary::{campaign_time_rows, campaign_time_text, setup_summary_lines, summary_text};
