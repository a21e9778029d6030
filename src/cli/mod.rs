//! Binary-only code of commands: `cellcal identify` (with `practical.rs`, its
//! practical-identifiability flags), `cellcal export`, `cellcal compensate`, `cellcal report`, `cellcal iso9283`, `cellcal token` and the access set-up of
//! `cellcal serve` (one module per command: its clap arguments and its run function; `main.rs`
//! only dispatches).

pub mod access;
pub mod compensate;
pub mod export;
pub mod identify;
pub mod iso9283;
pub mod practical;
pub mod report;
pub mod token;
