//! Binary-only code of commands: `cellcal identify`, `cellcal export`, `cellcal token` and the
//! access set-up of `cellcal serve` (one module per command: its clap arguments and its run
//! function; `main.rs` only dispatches).

pub mod access;
pub mod export;
pub mod identify;
pub mod token;
