//! Binary-only code of commands that are not thin calls into the library: `cellcal token`
//! and the access set-up of `cellcal serve`.

pub mod access;
pub mod token;
