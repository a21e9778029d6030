//! Measurement data sets in the `cellcal identify` CSV format, and their conversion to
//! observations.

pub mod convert;
pub mod csv_format;
pub mod read;

pub use convert::{split, split_measured, to_measured, ConvertError};
pub use csv_format::{
    parse_csv, parse_setup_header, parse_vec3, write_csv, CsvError, CsvSetup, Observation, PoseSet,
    Required,
};
pub use read::{read_csv, read_text, ReadError};
