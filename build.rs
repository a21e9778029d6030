//! Build script: the git commit and build date that `cellcal --version` prints
//! (`CELLCAL_GIT_HASH`, `CELLCAL_BUILD_DATE`; see `src/build_info.rs`).
//!
//! The hash comes from `git rev-parse` when the source is a git checkout, else from the
//! `CELLCAL_GIT_HASH` environment variable (a container build without `.git`), else "unknown".
//! The date is UTC, from `SOURCE_DATE_EPOCH` when set (reproducible builds), else the clock.

use std::process::Command;
use std::time::{SystemTime, UNIX_EPOCH};

fn main() {
    println!("cargo:rerun-if-env-changed=CELLCAL_GIT_HASH");
    println!("cargo:rerun-if-env-changed=SOURCE_DATE_EPOCH");
    for path in git_paths_to_watch() {
        println!("cargo:rerun-if-changed={path}");
    }
    let hash = git(&["rev-parse", "--short=12", "HEAD"])
        .or_else(|| std::env::var("CELLCAL_GIT_HASH").ok())
        .unwrap_or_else(|| "unknown".to_owned());
    println!("cargo:rustc-env=CELLCAL_GIT_HASH={hash}");
    println!("cargo:rustc-env=CELLCAL_BUILD_DATE={}", build_date());
}

/// `HEAD`, the branch file it names and `packed-refs`, those that exist (a missing path would
/// re-run this script, and so rebuild the crate, on every build): a new commit re-runs it.
fn git_paths_to_watch() -> Vec<String> {
    let (Some(git_dir), Some(common_dir)) = (
        git(&["rev-parse", "--git-dir"]),
        git(&["rev-parse", "--git-common-dir"]),
    ) else {
        return Vec::new();
    };
    let mut paths = vec![
        format!("{git_dir}/HEAD"),
        format!("{common_dir}/packed-refs"),
    ];
    if let Some(reference) = git(&["symbolic-ref", "-q", "HEAD"]) {
        paths.push(format!("{common_dir}/{reference}"));
    }
    paths.retain(|p| std::path::Path::new(p).exists());
    paths
}

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    let text = String::from_utf8(out.stdout).ok()?.trim().to_owned();
    (out.status.success() && !text.is_empty()).then_some(text)
}

fn build_date() -> String {
    let secs = std::env::var("SOURCE_DATE_EPOCH")
        .ok()
        .and_then(|s| s.trim().parse::<i64>().ok())
        .unwrap_or_else(|| {
            SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_secs() as i64)
        });
    let (y, m, d) = civil_from_days(secs.div_euclid(86_400));
    format!("{y:04}-{m:02}-{d:02}")
}

/// Proleptic Gregorian date of a day count since 1970-01-01 (H. Hinnant's `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}
