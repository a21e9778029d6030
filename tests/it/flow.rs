//! The operator's and technician's flow (issue 19, item 7): every command × state pair of the
//! command route either acts or says why not, a pause answers while a question is open, setup
//! readings survive a resume, and a manual campaign without a terminal is refused at start.

use std::process::Stdio;

use super::serve::fast_config;

/// The binary as a plain process (stdin set by the caller).
fn cellcal() -> std::process::Command {
    std::process::Command::new(assert_cmd::cargo::cargo_bin("cellcal"))
}

/// `cellcal run --arm` of a manual-stage campaign with stdin from /dev/null (no terminal):
/// refused with exit 2 and what to do, before anything is planned, stored, locked or moved.
#[test]
fn a_manual_campaign_without_a_terminal_is_refused_at_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    for kind in ["manual", "manual_gauge"] {
        let cfg = fast_config(dir.path(), kind, 20, 14);
        let store = dir.path().join(format!("{kind}.db"));
        let out = cellcal()
            .args(["run", "--arm", "--config"])
            .arg(&cfg)
            .arg("--store")
            .arg(&store)
            .stdin(Stdio::null())
            .output()
            .expect("run");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{kind}: {err}");
        for says in ["not a terminal", "cellcal serve", "in a terminal", kind] {
            assert!(err.contains(says), "{kind}: `{says}` missing: {err}");
        }
        assert!(!store.exists(), "{kind}: a store was created: {err}");
    }
    // a motorised stage asks nobody: the same run measures without a terminal
    let cfg = fast_config(dir.path(), "serial", 20, 14);
    let out = cellcal()
        .args(["run", "--arm", "--quiet", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(dir.path().join("serial.db"))
        .stdin(Stdio::null())
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
