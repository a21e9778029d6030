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
pub mod predict;
pub mod report;
pub mod run;
pub mod select_poses;
pub mod serve;
pub mod significance;
pub mod sim;
pub mod simulate_data;
pub mod stored;
#[cfg(test)]
mod tests;
pub mod token;

/// Set once stdout is found closed or broken: later output is dropped.
static STDOUT_GONE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Write `args` to stdout and flush: what `print!`/`println!` do in every command (main.rs
/// shadows them). A closed stdout (EPIPE: the reader, e.g. `head`, went away) is no failure:
/// the output is dropped and the command goes on (it still writes its files and exits with its
/// own code; `serve` keeps serving; SIGPIPE stays ignored, so a device's or client's closed
/// socket is an error, never the process's death); any other write error is said once on
/// stderr.
pub fn print_out(args: std::fmt::Arguments<'_>) {
    use std::io::Write;
    use std::sync::atomic::Ordering;
    if STDOUT_GONE.load(Ordering::Relaxed) {
        return;
    }
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if !STDOUT_GONE.swap(true, Ordering::Relaxed) && e.kind() != std::io::ErrorKind::BrokenPipe
        {
            eprintln!("cellcal: cannot write to stdout ({e}); the rest of its output is dropped");
        }
    }
}

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
