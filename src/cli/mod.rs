//! Binary-only code of commands that are not thin calls into the library: `cellcal token`
//! the access set-up of `cellcal serve`, the practical-identifiability
//! flags of `cellcal identify`.

pub mod access;
pub mod practical;
pub mod token;
