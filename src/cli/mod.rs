//! The binary's commands, one module each (its clap arguments and its run function; `main.rs`
//! only dispatches), and what they share: [`Failure`] (a failure and its exit code) and the
//! tokio runtime of the front ends. `practical.rs` holds `identify`'s practical-identifiability
//! flags, `access.rs` who may reach `serve`.

pub mod access;
pub mod compensate;
pub mod export;
pub mod identify;
pub mod import;
pub mod iso9283;
pub mod practical;
pub mod report;
pub mod run;
pub mod serve;
pub mod significance;
pub mod sim;
pub mod simulate_data;
pub mod stored;
#[cfg(test)]
mod tests;
pub mod token;

/// A failure and its exit code (2 = bad input, 1 = anything else, 3 = a poor result).
pub struct Failure(pub u8, pub anyhow::Error);

/// A bad-input failure (exit 2).
pub fn input<E: Into<anyhow::Error>>(e: E) -> Failure {
    Failure(2, e.into())
}

/// Any other failure (exit 1).
pub fn other<E: Into<anyhow::Error>>(e: E) -> Failure {
    Failure(1, e.into())
}

/// The runtime of the campaign front ends (two workers: the engine and the store/front end).
pub fn runtime() -> Result<tokio::runtime::Runtime, Failure> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(other)
}
