//! docs/hardware.md, the first real cell, is true: every TOML block is a valid cell
//! configuration, every key it names exists, every `cellcal` command it shows is accepted by
//! the argument parser, and its check without `--arm` runs against `cellcal sim`, prints what
//! the page shows and moves nothing. Also the facts the page states: one robotlink port
//! everywhere, `cellcal sim` following `stage.kind`, `manual_gauge` reading its gauge.

use std::collections::BTreeSet;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

use cellcal::campaign::session::{open_session, SessionError};
use cellcal::cell::ScriptedPrompter;
use cellcal::config::{parse_cell_config, RobotSection};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn doc() -> String {
    std::fs::read_to_string(root().join("docs/hardware.md")).expect("docs/hardware.md exists")
}

/// The fenced blocks of `text`: (info string, body), in order.
fn fenced(text: &str) -> Vec<(String, String)> {
    let mut blocks = Vec::new();
    let mut open: Option<(String, String)> = None;
    for line in text.lines() {
        match (&mut open, line.strip_prefix("```")) {
            (None, Some(info)) => open = Some((info.trim().to_owned(), String::new())),
            (Some(_), Some(_)) => blocks.extend(open.take()),
            (Some((_, body)), None) => {
                body.push_str(line);
                body.push('\n');
            }
            (None, None) => {}
        }
    }
    assert!(open.is_none(), "an unclosed fence");
    blocks
}

/// Split a shell line into words (double quotes group; the page uses no other quoting).
fn words(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let (mut cur, mut quoted, mut any) = (String::new(), false, false);
    for c in line.chars() {
        match c {
            '"' => {
                quoted = !quoted;
                any = true;
            }
            c if c.is_whitespace() && !quoted => {
                if any {
                    out.push(std::mem::take(&mut cur));
                    any = false;
                }
            }
            c => {
                cur.push(c);
                any = true;
            }
        }
    }
    assert!(!quoted, "unbalanced quotes in {line:?}");
    if any {
        out.push(cur);
    }
    out
}

/// Every `cellcal …` command of the page: the lines of its `sh` blocks (after `sudo -u cellcal`)
/// and its inline code spans.
fn commands(text: &str) -> Vec<Vec<String>> {
    let mut lines: Vec<String> = fenced(text)
        .into_iter()
        .filter(|(info, _)| info == "sh")
        .flat_map(|(_, body)| body.lines().map(str::to_owned).collect::<Vec<_>>())
        .collect();
    lines.extend(
        text.split('`')
            .skip(1)
            .step_by(2)
            .map(str::to_owned)
            .filter(|s| s.starts_with("cellcal ")),
    );
    lines
        .iter()
        .map(|l| l.split(" #").next().unwrap_or(l).trim())
        .map(|l| l.strip_prefix("sudo -u cellcal ").unwrap_or(l))
        .filter(|l| l.starts_with("cellcal "))
        .map(words)
        .collect()
}

#[test]
fn every_toml_block_of_the_hardware_page_is_a_valid_cell_configuration() {
    let text = doc();
    let blocks: Vec<String> = fenced(&text)
        .into_iter()
        .filter(|(info, _)| info == "toml")
        .map(|(_, b)| b)
        .collect();
    assert!(blocks.len() >= 6, "{} TOML blocks", blocks.len());
    let sections: BTreeSet<&str> = [
        "[tracker]",
        "[robot_controller]",
        "[stage]",
        "[campaign]",
        "[api]",
    ]
    .into_iter()
    .collect();
    for s in &sections {
        assert!(
            blocks.iter().any(|b| b.contains(s)),
            "no block configures {s}"
        );
    }
    for b in &blocks {
        // the loader of every command: strict keys and types, each section's rules
        if let Err(e) = parse_cell_config(b, Path::new("/etc/cellcal/cell.toml")) {
            panic!("docs/hardware.md block does not load: {e}\n{b}");
        }
    }
}

/// (section, key) of every key the shipped configuration files show, set or commented.
fn shipped_keys() -> BTreeSet<(String, String)> {
    let mut keys = BTreeSet::new();
    for f in ["config/cell.example.toml", "config/cell.sim.toml"] {
        let text = std::fs::read_to_string(root().join(f)).expect("shipped file");
        let mut section = String::new();
        for line in text.lines() {
            let l = line.trim_start_matches('#').trim();
            if line.starts_with('[') {
                section = line
                    .split(']')
                    .next()
                    .unwrap_or("")
                    .trim_start_matches('[')
                    .to_owned();
                continue;
            }
            if let Some((k, _)) = l.split_once(" = ").or_else(|| l.split_once('=')) {
                let k = k.trim();
                if !k.is_empty() && k.chars().all(|c| c.is_ascii_lowercase() || c == '_') {
                    keys.insert((section.clone(), k.to_owned()));
                }
            }
        }
    }
    keys
}

#[test]
fn every_key_the_hardware_page_names_exists() {
    let text = doc();
    let known = shipped_keys();
    let sections = [
        "tracker",
        "robot_controller",
        "stage",
        "campaign",
        "setup",
        "api",
        "sim",
    ];
    let mut named = Vec::new();
    for span in text.split('`').skip(1).step_by(2) {
        // `section.key` and `[section] key`
        let pair = match span.strip_prefix('[').and_then(|s| s.split_once("] ")) {
            Some((s, k)) => Some((s.to_owned(), k.to_owned())),
            None => span
                .split_once('.')
                .map(|(s, k)| (s.to_owned(), k.to_owned())),
        };
        let Some((s, k)) = pair else { continue };
        let k = k.split([' ', '=']).next().unwrap_or("").to_owned();
        if sections.contains(&s.as_str()) && k.chars().all(|c| c.is_ascii_lowercase() || c == '_') {
            named.push((s, k));
        }
    }
    assert!(named.len() >= 15, "{named:?}");
    for (s, k) in &named {
        assert!(
            known.contains(&(s.clone(), k.clone())),
            "docs/hardware.md names `{s}.{k}`, which no shipped configuration file has"
        );
    }
}

#[test]
fn every_cellcal_command_of_the_hardware_page_is_accepted_by_the_argument_parser() {
    let dir = tempfile::tempdir().expect("tempdir");
    let missing = dir.path().join("no-such-cell.toml");
    let cmds = commands(&doc());
    assert!(cmds.len() >= 6, "{cmds:?}");
    for cmd in &cmds {
        let mut args: Vec<String> = cmd[1..].to_vec();
        // never a real device, store or listener: the configuration does not exist, so each
        // command ends right after its arguments parsed
        if ["run", "serve", "sim"].contains(&args[0].as_str()) {
            match args.iter().position(|a| a == "--config") {
                Some(i) => args[i + 1] = missing.to_string_lossy().into_owned(),
                None => args.extend(["--config".into(), missing.to_string_lossy().into_owned()]),
            }
        }
        let out = Command::new(env!("CARGO_BIN_EXE_cellcal"))
            .args(&args)
            .current_dir(dir.path())
            .stdin(Stdio::null())
            .output()
            .expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !err.contains("Usage:") && !err.contains("unexpected argument"),
            "`{}` is not accepted: {err}",
            cmd.join(" ")
        );
        if args[0] == "token" {
            assert!(out.status.success(), "{err}");
        } else {
            assert!(
                err.contains("no-such-cell.toml"),
                "`{}`: {err}",
                cmd.join(" ")
            );
        }
    }
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `cellcal sim --config FILE` in `dir`, and its device lines (tracker, robot, stage).
fn start_sim(dir: &Path, file: &str) -> (Killed, Vec<String>) {
    let mut child = Killed(
        Command::new(env!("CARGO_BIN_EXE_cellcal"))
            .args(["sim", "--config", file])
            .current_dir(dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .stdin(Stdio::null())
            .spawn()
            .expect("spawn cellcal sim"),
    );
    let stdout = child.0.stdout.take().expect("stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(l) = line else { break };
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let lines = (0..3)
        .map(|_| {
            rx.recv_timeout(Duration::from_secs(10))
                .expect("a device line within 10 s")
        })
        .collect();
    (child, lines)
}

/// The part of `line` after `prefix `.
fn after(lines: &[String], prefix: &str) -> String {
    lines
        .iter()
        .find_map(|l| l.strip_prefix(&format!("{prefix} ")))
        .unwrap_or_else(|| panic!("no `{prefix}` line in {lines:?}"))
        .to_owned()
}

#[test]
fn the_check_without_arm_of_the_hardware_page_runs_against_cellcal_sim_prints_what_it_shows_and_moves_nothing(
) {
    let text = doc();
    let blocks = fenced(&text);
    let rehearsal = blocks
        .iter()
        .find(|(i, b)| i == "toml" && b.starts_with("# rehearsal.toml"))
        .map(|(_, b)| b.clone())
        .expect("the rehearsal file");
    let sim_cmd = "cellcal sim --config rehearsal.toml";
    let check_cmd = "cellcal run --config rehearsal.toml";
    assert!(
        blocks.iter().any(|(i, b)| i == "sh" && b.trim() == sim_cmd),
        "the page starts the simulated cell with `{sim_cmd}`"
    );
    let at = blocks
        .iter()
        .position(|(i, b)| i == "sh" && b.trim() == check_cmd)
        .expect("the check command");
    let (info, shown) = &blocks[at + 1];
    assert_eq!(info, "text", "the check's output follows it");

    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    crate::campaign::write_config(d, "");
    let key = d.join("robotlink.key");
    let hex: String = (0..32)
        .map(|i| format!("{:02x}", (i * 53 + 7) % 256))
        .collect();
    std::fs::write(&key, &hex).expect("key");
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    }
    std::fs::write(d.join("rehearsal.toml"), &rehearsal).expect("write");
    let (_sim, lines) = start_sim(d, "rehearsal.toml");
    let tracker = after(&lines, "tracker");
    let robot = after(&lines, "robot");
    let stage = after(&lines, "stage");
    let tracker_port = tracker.rsplit(':').next().expect("port").to_owned();
    let robot_port = robot.rsplit(':').next().expect("port").to_owned();
    let fill = |s: &str| {
        s.replace("TRACKER_PORT", &tracker_port)
            .replace("ROBOT_PORT", &robot_port)
            .replace("/dev/pts/N", &stage)
    };
    std::fs::write(d.join("rehearsal.toml"), fill(&rehearsal)).expect("write");

    let out = Command::new(env!("CARGO_BIN_EXE_cellcal"))
        .args(&words(check_cmd)[1..])
        .current_dir(d)
        .stdin(Stdio::null())
        .output()
        .expect("run");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stdout}{stderr}");
    let printed: Vec<&str> = stdout.lines().chain(stderr.lines()).collect();
    let expected = fill(shown);
    for line in expected.lines() {
        assert!(
            printed.contains(&line),
            "the page shows\n{line}\nbut the check printed\n{}",
            printed.join("\n")
        );
    }
    for line in stdout.lines() {
        assert!(
            expected.lines().any(|l| l == line),
            "the check printed\n{line}\nwhich the page does not show"
        );
    }

    // nothing moved: the arm unpowered at its initial joints, the tracker never initialised,
    // the stage never homed
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let secret = robotlink::SharedSecret::read_file(&key).expect("secret");
        let c = robotlink::RobotClient::connect(
            robot.as_str(),
            robotlink::ClientConfig {
                secret: Some(secret),
                ..robotlink::ClientConfig::default()
            },
        )
        .await
        .expect("robot");
        c.hello().await.expect("hello");
        let st = c.state().await.expect("state");
        assert!(!st.power && !st.moving, "{st:?}");
        assert_eq!(
            c.joints().await.expect("joints"),
            [0.0, 0.0, 90.0, 0.0, 45.0, 0.0]
        );
        let t = emscon::Client::connect(tracker.as_str(), emscon::ClientConfig::default())
            .await
            .expect("tracker");
        assert!(!t.system_status().await.expect("status").is_initialized());
        let mut s = zaber::ZaberStage::open(&stage, zaber::StageConfig::default()).expect("stage");
        let pos = s.command("get pos").await.expect("get pos");
        assert_eq!(pos.data.trim(), "0", "{pos:?}");
        assert_eq!(pos.warning.as_str(), "WR", "never homed: {pos:?}");
    });
}

#[test]
fn one_robotlink_port_in_the_driver_the_configuration_the_controller_app_and_the_page() {
    let port = robotlink::DEFAULT_PORT;
    let ends = format!(":{port}");
    assert!(RobotSection::default().address.ends_with(&ends));
    assert!(cellcal::cell::LinkRobotConfig::default()
        .address
        .ends_with(&ends));
    let example = root().join("config/cell.example.toml");
    let cfg = parse_cell_config(
        &std::fs::read_to_string(&example).expect("example"),
        &example,
    )
    .expect("example loads");
    assert!(
        cfg.robot_controller.address.ends_with(&ends),
        "{}",
        cfg.robot_controller.address
    );
    let read = |f: &str| std::fs::read_to_string(root().join(f)).expect(f);
    assert!(read("deploy/staubli/README.md").contains(&format!("port e.g. **{port}**")));
    assert!(read("deploy/README.md").contains(&format!("{port} in")));
    assert!(read("drivers/robotlink/PROTOCOL.md").contains(&format!("uses {port} by default")));
    let page = doc();
    assert!(page.contains(&format!("TCP **{port}**")));
    assert!(page.contains(&format!("address = \"192.168.0.254:{port}\"")));
    // no other port is named for the controller anywhere a user reads
    for f in [
        "config/cell.example.toml",
        "deploy/README.md",
        "deploy/staubli/README.md",
    ] {
        assert!(!read(f).contains(":11000"), "{f} names 11000");
    }
    assert!(!page.contains("11000"));
}

#[test]
fn cellcal_sim_follows_stage_kind_and_a_contradicting_sim_stage_mode_names_both_keys() {
    let dir = tempfile::tempdir().expect("tempdir");
    crate::campaign::write_config(dir.path(), "");
    let robot = "robot = \"robots/staubli_tx60.toml\"\n";
    std::fs::write(
        dir.path().join("manual.toml"),
        format!("{robot}[stage]\nkind = \"manual\"\n[sim]\nseed = 3\n"),
    )
    .expect("write");
    let (_sim, lines) = start_sim(dir.path(), "manual.toml");
    assert_eq!(lines[2], "stage manual", "{lines:?}");

    std::fs::write(
        dir.path().join("both.toml"),
        format!("{robot}[sim]\nstage_mode = \"manual\"\n"),
    )
    .expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_cellcal"))
        .args(["sim", "--config", "both.toml"])
        .current_dir(dir.path())
        .stdin(Stdio::null())
        .output()
        .expect("sim");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    for want in [
        "both.toml",
        "sim.stage_mode",
        "stage.kind = \"serial\"",
        "set stage.kind = \"manual\"",
        "delete sim.stage_mode",
    ] {
        assert!(err.contains(want), "{want}: {err}");
    }
}

/// A simulated cell whose stage is a real `manual_gauge` micrometer at `gauge_path`.
fn gauge_cell(dir: &Path, gauge_path: &str) -> (PathBuf, cellcal::config::CellConfig) {
    let text = crate::campaign::config_text("", "", "").replace(
        "[stage]\nmode = \"sim\"\nkind = \"serial\"",
        &format!("[stage]\nmode = \"real\"\ngauge_path = {gauge_path:?}\nkind = \"manual_gauge\""),
    );
    assert!(text.contains("manual_gauge"), "{text}");
    let path = crate::campaign::write_config(dir, &text);
    let cfg = parse_cell_config(&text, &path).expect("config");
    (path, cfg)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_manual_gauge_stage_reads_its_gauge_and_a_missing_gauge_is_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let gauge = zaber::pty::spawn_gauge_pty(zaber::sim::GaugeSim::new(Arc::new(|| 12.345)))
        .expect("gauge pty");
    let (_, cfg) = gauge_cell(dir.path(), &gauge.path());
    assert_eq!(cfg.stage.kind, cellcal::config::StageMode::ManualGauge);
    let mut session = open_session(
        cfg,
        &dir.path().join("c.db"),
        None,
        Arc::new(ScriptedPrompter::exact()),
    )
    .await
    .expect("session");
    let said = tokio::time::timeout(Duration::from_secs(10), session.devices.stage.check())
        .await
        .expect("in time")
        .expect("the gauge answers");
    assert!(said.contains("gauge reads 12.345 mm"), "{said}");
    assert!(
        session
            .devices
            .stage
            .identity()
            .is_some_and(|i| i.contains("RS-232 gauge")),
        "{:?}",
        session.devices.stage.identity()
    );
    session.sim.take().expect("sim").stop().await;
    drop(session);

    let dir = tempfile::tempdir().expect("tempdir");
    let (_, cfg) = gauge_cell(dir.path(), "/dev/no-such-gauge");
    let e = match open_session(
        cfg,
        &dir.path().join("c.db"),
        None,
        Arc::new(ScriptedPrompter::exact()),
    )
    .await
    {
        Ok(_) => panic!("a missing gauge was accepted"),
        Err(e) => e,
    };
    assert!(matches!(e, SessionError::Invalid(_)), "{e:?}");
    let e = e.to_string();
    assert!(
        e.contains("stage.gauge_path") && e.contains("/dev/no-such-gauge"),
        "{e}"
    );
}
