//! What this binary was built from (set by `build.rs`): printed by `cellcal --version`,
//! recorded in reports and results.

/// Package version from Cargo.toml.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
/// Abbreviated git commit of the source, or "unknown" outside a git checkout.
pub const GIT_HASH: &str = env!("CELLCAL_GIT_HASH");
/// UTC build date `YYYY-MM-DD` (`SOURCE_DATE_EPOCH` when set).
pub const BUILD_DATE: &str = env!("CELLCAL_BUILD_DATE");

/// `0.1.0 (git 0123456789ab, built 2026-11-22)`: the `--version` line after the name.
pub const LONG_VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (git ",
    env!("CELLCAL_GIT_HASH"),
    ", built ",
    env!("CELLCAL_BUILD_DATE"),
    ")"
);
