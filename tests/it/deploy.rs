//! What a plant installs: the systemd unit (checked by `systemd-analyze verify` where it
//! exists; CI installs it and sets `CELLCAL_REQUIRE_SYSTEMD=1`), the version line, the
//! license files Cargo.toml declares, the container file.

use std::path::Path;
use std::process::Command;

const REQUIRE_SYSTEMD: &str = "CELLCAL_REQUIRE_SYSTEMD";

fn repo_file(path: &str) -> String {
    let full = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    std::fs::read_to_string(&full).unwrap_or_else(|e| panic!("{}: {e}", full.display()))
}

/// The `[Service]` lines of the shipped unit a plant relies on (dedicated user, read-only
/// system, state directory, serial access by group, restart policy, SIGTERM handling, the
/// writable default lock directory of the cell locks, loopback listen, descriptor limit, the
/// log and the progress lines in the journal under the tag `cellcal`).
const REQUIRED_UNIT_LINES: [&str; 15] = [
    "User=cellcal",
    "RuntimeDirectory=lock/cellcal",
    "SupplementaryGroups=dialout",
    "ProtectSystem=strict",
    "NoNewPrivileges=yes",
    "StateDirectory=cellcal",
    "ConfigurationDirectory=cellcal",
    "Restart=on-failure",
    "RestartPreventExitStatus=2",
    "KillSignal=SIGTERM",
    "CapabilityBoundingSet=",
    // loopback by default (a drop-in names the cell network's address, deploy/README.md)
    "ExecStart=/usr/local/bin/cellcal serve --config /etc/cellcal/cell.toml --listen 127.0.0.1:8080 --store /var/lib/cellcal/cellcal.db",
    // room for the connection cap (512) and the reserve (64) of `cellcal serve`
    "LimitNOFILE=1024",
    "StandardError=journal",
    "SyslogIdentifier=cellcal",
];

#[test]
fn the_systemd_unit_is_hardened_and_passes_systemd_analyze_verify() {
    let unit = repo_file("deploy/systemd/cellcal.service");
    let lines: Vec<&str> = unit.lines().map(str::trim).collect();
    for required in REQUIRED_UNIT_LINES {
        assert!(lines.contains(&required), "unit lacks `{required}`");
    }

    let Ok(version) = Command::new("systemd-analyze").arg("--version").output() else {
        assert!(
            std::env::var(REQUIRE_SYSTEMD).as_deref() != Ok("1"),
            "{REQUIRE_SYSTEMD}=1 but systemd-analyze is missing (apt-get install systemd)"
        );
        eprintln!(
            "\n*** SKIPPED systemd-analyze verify: systemd-analyze not found; set \
             {REQUIRE_SYSTEMD}=1 to make this a failure ***\n"
        );
        return;
    };
    assert!(version.status.success());
    // verify checks that ExecStart's program exists: point it at the binary under test
    let dir = tempfile::tempdir().expect("tempdir");
    let local = unit.replace("/usr/local/bin/cellcal", env!("CARGO_BIN_EXE_cellcal"));
    let path = dir.path().join("cellcal.service");
    std::fs::write(&path, local).expect("write unit");
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .expect("run systemd-analyze");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "systemd-analyze verify: {stderr}");
    let complaints: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("cellcal.service"))
        .collect();
    assert!(complaints.is_empty(), "{complaints:#?}");
}

#[test]
fn the_version_line_names_the_git_commit_and_the_build_date() {
    let out = Command::new(env!("CARGO_BIN_EXE_cellcal"))
        .arg("--version")
        .output()
        .expect("run cellcal --version");
    assert!(out.status.success());
    let line = String::from_utf8(out.stdout).expect("utf-8");
    let line = line.trim();
    let rest = line
        .strip_prefix(&format!("cellcal {} (git ", env!("CARGO_PKG_VERSION")))
        .unwrap_or_else(|| panic!("{line}"));
    let (hash, date) = rest
        .strip_suffix(')')
        .and_then(|r| r.split_once(", built "))
        .unwrap_or_else(|| panic!("{line}"));
    let date_ok = date.len() == 10
        && date.chars().enumerate().all(|(i, c)| match i {
            4 | 7 => c == '-',
            _ => c.is_ascii_digit(),
        });
    assert!(date_ok, "build date {date:?} in {line}");
    // in a git checkout (CI clones one) it is this checkout's commit
    let head = Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output();
    match head {
        Ok(h) if h.status.success() => {
            assert_eq!(hash, String::from_utf8_lossy(&h.stdout).trim(), "{line}")
        }
        _ => assert!(!hash.is_empty(), "{line}"),
    }
}

#[test]
fn the_license_files_match_the_declared_licenses() {
    let manifest = repo_file("Cargo.toml");
    assert!(manifest.contains(r#"license = "MIT OR Apache-2.0""#));
    assert!(repo_file("LICENSE-MIT").starts_with("MIT License"));
    let apache = repo_file("LICENSE-APACHE");
    assert!(apache.contains("Apache License") && apache.contains("Version 2.0, January 2004"));
    for driver in ["emscon", "robotlink", "zaber"] {
        let m = repo_file(&format!("drivers/{driver}/Cargo.toml"));
        assert!(m.contains(r#"license = "MIT OR Apache-2.0""#), "{driver}");
    }
}

#[test]
fn the_container_builds_in_one_stage_and_runs_the_daemon_in_another() {
    let file = repo_file("deploy/Containerfile");
    let froms: Vec<&str> = file.lines().filter(|l| l.starts_with("FROM ")).collect();
    assert_eq!(froms.len(), 2, "{froms:?}");
    assert!(froms[0].ends_with(" AS build"), "{froms:?}");
    assert!(file.contains("COPY --from=build "));
    assert!(
        file.contains("USER cellcal"),
        "the daemon must not run as root"
    );
    // the image's command is the unit's (same config and store), listening on every interface of
    // the container's own network namespace; the example publishes the port on loopback only
    let cmd = file
        .lines()
        .find_map(|l| l.strip_prefix("CMD "))
        .expect("CMD");
    let args: Vec<String> = serde_json::from_str(cmd).expect("CMD is a JSON array");
    assert_eq!(
        args.join(" "),
        "serve --config /etc/cellcal/cell.toml --listen 0.0.0.0:8080 --store /var/lib/cellcal/cellcal.db"
    );
    assert!(file.contains("docker run -d --name cellcal -p 127.0.0.1:8080:8080 "));
}
