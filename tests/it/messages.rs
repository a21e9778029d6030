//! Messages that say what to do (issue 19): each cause once, times people read, the CSV
//! delimiter named, host names for `--listen`, a closed pipe ends quietly, data in a frame far
//! from the robot base diagnosed as such.

use std::path::Path;

use crate::common::rust_files;

/// The indentation of `line` in bytes.
fn indent(line: &str) -> usize {
    line.len() - line.trim_start().len()
}

/// `file:line` of every thiserror `#[error(...)]` but `transparent` with a `source()` field
/// (`#[from]`, `#[source]`, or a field named `source`).
fn causes_printed_twice(file: &str, text: &str) -> Vec<String> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let t = lines[i].trim_start();
        if !t.starts_with("#[error(") {
            i += 1;
            continue;
        }
        let at = i;
        let depth = indent(lines[i]);
        // the attribute (it may span lines)
        let mut attr = String::new();
        while i < lines.len() {
            attr.push_str(lines[i].trim());
            attr.push('\n');
            i += 1;
            if lines[i - 1].trim_end().ends_with(")]") {
                break;
            }
        }
        // the variant or struct it describes
        let mut body = String::new();
        while i < lines.len() {
            let l = lines[i];
            let t = l.trim();
            if t.starts_with("#[error(") || (!t.is_empty() && indent(l) < depth) {
                break;
            }
            body.push_str(t);
            body.push('\n');
            i += 1;
            let item_end = indent(l) == depth
                && (t.starts_with('}') || t.ends_with(',') || t.ends_with(';'))
                && !t.starts_with("///")
                && !t.starts_with("#[");
            if item_end {
                break;
            }
        }
        if attr.contains("#[error(transparent)]") {
            continue;
        }
        // the fields that are the source
        let mut sources = Vec::new();
        if body.contains("(#[from]") || body.contains("(#[source]") {
            sources.push("0".to_owned());
        }
        let body_lines: Vec<&str> = body.lines().collect();
        for (k, l) in body_lines.iter().enumerate() {
            let marked = l.starts_with("#[from]") || l.starts_with("#[source]");
            let field = if marked {
                let rest = l
                    .trim_start_matches("#[from]")
                    .trim_start_matches("#[source]");
                if rest.trim().is_empty() {
                    body_lines.get(k + 1).copied().unwrap_or("")
                } else {
                    rest
                }
            } else {
                l
            };
            let name = field.trim().trim_start_matches("pub ").split(':').next();
            let name = name.unwrap_or("").trim();
            if (marked || name == "source") && field.contains(':') && !name.is_empty() {
                sources.push(name.to_owned());
            }
        }
        for s in sources {
            let printed = attr.contains(&format!("{{{s}}}")) || attr.contains(&format!("{{{s}:"));
            let how = if printed { "prints" } else { "does not print" };
            found.push(format!(
                "{file}:{}: `{s}` is the source() (the message {how} it)",
                at + 1
            ));
        }
    }
    found
}

/// Every error type of `src/` and `drivers/*/src/` prints its cause in its own message and
/// gives no `source()` (a `transparent` one passes its inner error's on): printed with its
/// causes (anyhow's `{:#}`) no cause appears twice
/// (`No such file or directory (os error 2): No such file or directory (os error 2)`), and
/// `to_string()` (REST bodies, the journal, logs) has the whole message.
#[test]
fn every_error_message_prints_its_cause_and_none_is_also_a_source() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    for d in ["emscon", "lineio", "robotlink", "zaber"] {
        rust_files(&root.join("drivers").join(d).join("src"), &mut files);
    }
    let mut found = Vec::new();
    let mut checked = 0;
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        checked += text.matches("#[error(").count();
        let name = f.strip_prefix(root).unwrap().display().to_string();
        found.extend(causes_printed_twice(&name, &text));
    }
    assert!(checked > 100, "only {checked} error messages found");
    assert!(
        found.is_empty(),
        "{} errors give a source() (print the cause in the message as `{{cause}}` and drop \
         `#[from]`/`#[source]`, renaming a field `source`; or make the variant transparent):\n{}",
        found.len(),
        found.join("\n")
    );
}

/// `cellcal args…` run in `dir`: its exit code and stderr.
fn cellcal_in(dir: &Path, args: &[&str]) -> (Option<i32>, String) {
    let out = super::common::cellcal_process()
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The `: `-separated parts of a message that appear more than once.
fn repeated_parts(message: &str) -> Vec<&str> {
    let parts: Vec<&str> = message.split(": ").map(str::trim).collect();
    let mut repeated: Vec<&str> = parts
        .iter()
        .enumerate()
        .filter(|(i, p)| !p.is_empty() && parts[..*i].contains(p))
        .map(|(_, p)| *p)
        .collect();
    repeated.dedup();
    repeated
}

/// Representative failures of the commands (a missing configuration, robot file, data file
/// or store; a data file that is a directory; a store that is a directory, not a database, or in
/// a missing directory; a robot file that does not parse): each exits 2 with one line that names
/// the file and says every cause once.
#[test]
fn every_cause_is_printed_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let robot = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/robots/staubli_tx60.toml");
    let robot = robot.to_str().unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/cell.sim.toml");
    let config = config.to_str().unwrap();
    std::fs::create_dir(d.join("folder")).unwrap();
    std::fs::write(d.join("junk.db"), "not a database\n").unwrap();
    std::fs::write(d.join("bad.toml"), "[[joints]]\na_mm = [\n").unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["run", "--config", "missing.toml"], "missing.toml"),
        (&["serve", "--config", "missing.toml"], "missing.toml"),
        (
            &[
                "identify",
                "--robot",
                "missing.toml",
                "--data",
                "d.csv",
                "--model",
                "op",
            ],
            "missing.toml",
        ),
        (
            &[
                "identify",
                "--robot",
                robot,
                "--data",
                "missing.csv",
                "--model",
                "op",
            ],
            "missing.csv",
        ),
        (
            &[
                "identify", "--robot", robot, "--data", "folder", "--model", "op",
            ],
            "folder",
        ),
        (
            &[
                "identify", "--robot", "bad.toml", "--data", "d.csv", "--model", "op",
            ],
            "bad.toml",
        ),
        (&["identify", "--store", "missing.db"], "missing.db"),
        (
            &["report", "--store", "junk.db", "--out", "r.html"],
            "not a database",
        ),
        (&["export", "--store", "folder", "--out", "e.csv"], "folder"),
        (
            &["run", "--config", config, "--store", "no/such/dir/c.db"],
            "no/such/dir/c.db",
        ),
        (&["run", "--config", config, "--store", "folder"], "folder"),
    ];
    let mut bad = Vec::new();
    for (args, names) in cases {
        let (code, err) = cellcal_in(d, args);
        let message = err.trim_end();
        let repeated = repeated_parts(message);
        let os_errors = message.matches("(os error").count();
        let one_line = message.lines().count() == 1 && message.starts_with("cellcal: error: ");
        if code != Some(2)
            || !repeated.is_empty()
            || os_errors > 1
            || !one_line
            || !message.contains(names)
        {
            bad.push(format!(
                "cellcal {}: exit {code:?}, repeated {repeated:?}, {os_errors} os errors, \
                 naming `{names}`: {message}",
                args.join(" ")
            ));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// Who holds a campaign or the cell is told with the time they took it as people read it
/// (local ISO 8601 with its offset, to the second), not as milliseconds since the epoch.
#[test]
fn lock_holders_say_since_when_in_local_iso_8601() {
    use cellcal::campaign::cell_lock::CellHolder;
    use cellcal::store::LockHolder;
    let at_ms = 1_795_666_135_248;
    let when = cellcal::units::human::fmt_local_time(at_ms);
    // 2026-11-26T04:08:55 in whatever zone this machine is in
    let (date, offset) = when.split_at(19);
    assert!(
        date.starts_with("2026-11-2") && date.ends_with(":55"),
        "{when}"
    );
    let offset_ok =
        offset.len() == 6 && offset.starts_with(['+', '-']) && offset.as_bytes()[3] == b':';
    assert!(offset_ok, "{when}");
    let run = LockHolder {
        pid: 42,
        host: "cell-pc".into(),
        pid_start: 7,
        acquired_at_ms: at_ms,
    };
    let cell = CellHolder {
        pid: 42,
        host: "cell-pc".into(),
        pid_start: 7,
        acquired_at_ms: at_ms,
        campaign: Some(3),
        store: "c.db".into(),
        cell: "robot 10.0.0.2:7000".into(),
    };
    for text in [run.to_string(), cell.to_string()] {
        assert!(text.contains(&format!("since {when}")), "{text}");
        assert!(
            !text.contains("epoch") && !text.contains("1795666135"),
            "{text}"
        );
    }
}

/// The TX60 robot file and the simulated cell's configuration.
fn robot_and_config() -> (String, String) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let robot = root.join("config/robots/staubli_tx60.toml");
    let config = root.join("config/cell.sim.toml");
    (
        robot.to_str().unwrap().to_owned(),
        config.to_str().unwrap().to_owned(),
    )
}

/// A simulated data set `name` in `dir` (60 poses, 30 to identify), `extra` options.
fn simulated(dir: &Path, name: &str, extra: &[&str]) {
    let (robot, _) = robot_and_config();
    let mut args = vec!["simulate-data", "--robot", &robot, "--out", name];
    args.extend(["--poses", "60", "--ident", "30"]);
    args.extend(extra);
    let (code, err) = cellcal_in(dir, &args);
    assert_eq!(code, Some(0), "{err}");
}

/// `identify … | head`: stdout closed before anything is printed. No panic, no broken-pipe
/// text, the command's own exit code, and its files still written.
#[test]
fn a_closed_stdout_ends_identify_quietly_and_its_files_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d, "d.csv", &[]);
    let (robot, _) = robot_and_config();
    let mut child = super::common::cellcal_process()
        .current_dir(d)
        .args([
            "identify", "--robot", &robot, "--data", "d.csv", "--model", "op",
        ])
        .args(["--json", "r.json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        matches!(out.status.code(), Some(0 | 3)),
        "{:?}: {err}",
        out.status
    );
    assert!(
        !err.contains("panicked") && !err.to_lowercase().contains("broken pipe"),
        "{err}"
    );
    assert!(d.join("r.json").is_file(), "the JSON is still written");
}

/// `serve --listen localhost:PORT` listens on the loopback address (no token needed there), and
/// a closed stdout (its lines read by nobody) does not stop the daemon.
#[test]
fn serve_listens_on_localhost_and_outlives_its_closed_stdout() {
    use std::io::{Read, Write};
    let dir = tempfile::tempdir().unwrap();
    let (_, config) = robot_and_config();
    let port = super::common::free_port();
    let mut child = super::common::cellcal_process()
        .current_dir(dir.path())
        .args(["serve", "--config", &config, "--store", "c.db"])
        .args(["--listen", &format!("localhost:{port}")])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    let answer = loop {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("serve ended: {status:?}");
        }
        let asked = std::net::TcpStream::connect(("127.0.0.1", port)).and_then(|mut s| {
            write!(
                s,
                "GET /api/health HTTP/1.1\r\nHost: localhost:{port}\r\nConnection: close\r\n\r\n"
            )?;
            let mut text = String::new();
            s.read_to_string(&mut text)?;
            Ok(text)
        });
        match asked {
            Ok(text) if !text.is_empty() => break text,
            _ if std::time::Instant::now() > deadline => panic!("serve never answered"),
            _ => std::thread::sleep(std::time::Duration::from_millis(100)),
        }
    };
    let alive = child.try_wait().unwrap().is_none();
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(alive, "serve ended after printing to its closed stdout");
}

/// A semicolon- or tab-separated file is refused naming the separator found and the one this
/// format takes (today: "missing column `set`").
#[test]
fn a_data_file_with_another_separator_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d, "d.csv", &[]);
    let text = std::fs::read_to_string(d.join("d.csv")).unwrap();
    let (robot, _) = robot_and_config();
    for (sep, named) in [(";", "`;` (semicolon)"), ("\t", "a tab")] {
        let other: String = text
            .lines()
            .map(|l| {
                if l.starts_with('#') {
                    format!("{l}\n")
                } else {
                    format!("{}\n", l.replace(',', sep))
                }
            })
            .collect();
        std::fs::write(d.join("other.csv"), other).unwrap();
        let (code, err) = cellcal_in(
            d,
            &[
                "identify",
                "--robot",
                &robot,
                "--data",
                "other.csv",
                "--model",
                "op",
            ],
        );
        assert_eq!(code, Some(2), "{err}");
        assert!(
            err.contains(&format!("separated by {named}, not by commas")) && err.contains("line 3"),
            "{err}"
        );
        assert!(!err.contains("missing column"), "{err}");
    }
}

/// Data measured in the tracker's frame (2.5 m away, turned 155°), identified without
/// `--identify-base`: the frame is named with the flag to add, not the stage axis; with the
/// flag it identifies.
#[test]
fn data_in_the_tracker_frame_without_identify_base_is_diagnosed_as_such() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let frame = [
        "--base-translation-mm",
        "2400,-700,-200",
        "--base-rotvec-deg",
        "0,0,155",
    ];
    simulated(d, "d.csv", &frame);
    let (robot, _) = robot_and_config();
    for model in ["op", "np", "position"] {
        let (code, err) = cellcal_in(
            d,
            &[
                "identify", "--robot", &robot, "--data", "d.csv", "--model", model,
            ],
        );
        assert_eq!(code, Some(2), "{model}: {err}");
        assert!(
            err.contains("the data is in another frame than the robot base (the tracker's)")
                && err.contains("Add --identify-base")
                && err.contains("turned 155.0°"),
            "{model}: {err}"
        );
        assert!(!err.contains("stage axis"), "{model}: {err}");
    }
    let (code, err) = cellcal_in(
        d,
        &[
            "identify",
            "--robot",
            &robot,
            "--data",
            "d.csv",
            "--model",
            "op",
            "--identify-base",
        ],
    );
    assert!(matches!(code, Some(0 | 3)), "{err}");
}
