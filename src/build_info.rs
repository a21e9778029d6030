//! What this build is: the crate version and the git commit it was built from (set by
//! `build.rs`, or by `CELLCAL_GIT_HASH` in the build environment). The one place that says so:
//! the report's provenance and any `--version` read it from here.

/// The software identity of this build.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct BuildInfo {
    /// The crate version (`Cargo.toml`).
    pub version: &'static str,
    /// The full git commit hash the build was made from; `None` outside a git checkout.
    pub git_hash: Option<&'static str>,
}

/// This build's version and git commit.
pub fn build_info() -> BuildInfo {
    BuildInfo {
        version: env!("CARGO_PKG_VERSION"),
        git_hash: option_env!("CELLCAL_GIT_HASH"),
    }
}
