//! Build script: the git commit the binary is built from, as `CELLCAL_GIT_HASH` (read by
//! `src/build_info.rs`). Nothing is set outside a git checkout (a source archive), or when
//! `git` is missing; `CELLCAL_GIT_HASH` in the build environment wins (packagers).

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    if !out.status.success() {
        return None;
    }
    let s = String::from_utf8(out.stdout).ok()?.trim().to_owned();
    (!s.is_empty()).then_some(s)
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=CELLCAL_GIT_HASH");
    if std::env::var_os("CELLCAL_GIT_HASH").is_some() {
        return;
    }
    let Some(hash) = git(&["rev-parse", "HEAD"]) else {
        return;
    };
    // rebuild when the checked-out commit changes: HEAD, the branch it points to, packed refs
    // (only files that exist: a missing one would rerun this script, and rebuild, every time)
    let branch = git(&["symbolic-ref", "-q", "HEAD"]);
    for path in ["HEAD", "packed-refs"].into_iter().chain(branch.as_deref()) {
        let file = git(&["rev-parse", "--path-format=absolute", "--git-path", path]);
        if let Some(f) = file.filter(|f| std::path::Path::new(f).is_file()) {
            println!("cargo:rerun-if-changed={f}");
        }
    }
    println!("cargo:rustc-env=CELLCAL_GIT_HASH={hash}");
}
