//! Only cellcal moves the arm: the simulated controller's robotlink server refuses a client
//! without the shared secret, or from an address not on its allow-list, before any power or
//! motion; a real controller needs `[robot_controller] secret_file`, whose text never shows.

use std::io::{BufRead, BufReader, Write};
use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpStream};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use cellcal::cell::{LinkRobot, LinkRobotConfig, Robot};
use cellcal::config::parse_cell_config;
use cellcal::sim::{lock_world, start_cell, RunningSimCell, SimWorldConfig};
use robotlink::{ClientConfig, RobotClient, RobotError, SharedSecret};

use crate::common::tx60;

const KEY: &str = "3a5f0c1d2e4b69788796a5b4c3d2e1f0112233445566778899aabbccddeeff00";

async fn cell(cfg: SimWorldConfig) -> RunningSimCell {
    start_cell(tx60(), cfg, std::future::pending())
        .await
        .expect("simulated cell starts")
}

/// One line from a blocking raw connection ("" at EOF).
fn line(r: &mut BufReader<TcpStream>) -> String {
    let mut l = String::new();
    r.read_line(&mut l).expect("read");
    l.trim_end().to_owned()
}

/// Send `lines` on a fresh raw connection; every reply line, until the server closes.
fn stranger(addr: SocketAddr, lines: &[&str]) -> Vec<String> {
    let s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    let mut w = s.try_clone().unwrap();
    let mut r = BufReader::new(s);
    let mut got = Vec::new();
    for l in lines {
        if w.write_all(format!("{l}\n").as_bytes()).is_err() {
            break;
        }
        let reply = line(&mut r);
        if reply.is_empty() {
            break;
        }
        got.push(reply);
    }
    assert_eq!(line(&mut r), "", "the server closes the connection");
    got
}

/// Power off, no motion, the joints where the cell started.
fn arm_untouched(c: &RunningSimCell) {
    let mut w = lock_world(&c.world);
    assert!(!w.power(), "arm power was switched on");
    assert!(!w.is_moving(), "the arm moves");
    let q0 = SimWorldConfig::default().initial_joints_deg;
    for (q, q0) in w.readback_joints_rad().iter().zip(q0) {
        assert!((q.to_degrees() - q0).abs() < 1e-6, "the arm moved");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulated_robot_refuses_a_stranger_before_any_power_or_motion() {
    // Issue 17's probe: HELLO, POWER ON, MOVEJ 90 0 0 0 0 0 from a client without the secret.
    let c = cell(SimWorldConfig::default()).await;
    let addr = c.robot_addr;
    let probe = tokio::task::spawn_blocking(move || {
        let old = stranger(addr, &["1 HELLO 2", "2 POWER ON", "3 MOVEJ 90 0 0 0 0 0"]);
        let v3 = stranger(addr, &["1 HELLO 3", "2 POWER ON", "3 MOVEJ 90 0 0 0 0 0"]);
        let direct = stranger(addr, &["1 MOVEJ 90 0 0 0 0 0"]);
        (old, v3, direct)
    })
    .await
    .unwrap();
    let (old, v3, direct) = probe;
    assert!(old[0].starts_with("1 ERR E_ARGS"), "{old:?}");
    assert!(
        old[0].contains("secret_file"),
        "tells the operator what to do: {old:?}"
    );
    assert!(old[1].starts_with("2 ERR E_AUTH"), "{old:?}");
    assert_eq!(old.len(), 2, "closed after the refused POWER ON: {old:?}");
    assert!(v3[0].starts_with("1 OK "), "{v3:?}");
    assert!(v3[1].starts_with("2 ERR E_AUTH"), "{v3:?}");
    assert_eq!(v3.len(), 2, "{v3:?}");
    assert_eq!(direct.len(), 1);
    assert!(direct[0].starts_with("1 ERR E_AUTH"), "{direct:?}");
    arm_untouched(&c);

    // A client with another secret gets a clear error and nothing else.
    let mut cfg = c.robot_config();
    cfg.secret = Some(SharedSecret::from_hex(KEY, "test").unwrap());
    let mut r = LinkRobot::new(cfg);
    let e = r
        .prepare(50.0)
        .await
        .expect_err("a wrong secret is refused");
    assert!(e.message.contains("secret_file"), "{e}");
    arm_untouched(&c);

    // cellcal itself (the cell's secret) prepares and moves.
    let mut r = LinkRobot::new(c.robot_config());
    r.prepare(50.0).await.expect("cellcal authenticates");
    let q = [0.1, 0.0, 1.5, 0.0, 0.8, 0.0];
    r.move_joints(&q).await.expect("move accepted");
    r.wait_settled(Duration::from_secs(5))
        .await
        .expect("settles");
    c.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_simulated_robot_serves_only_its_allow_list_and_its_joint_limits() {
    let c = cell(SimWorldConfig {
        robot_allow: vec![IpAddr::V4(Ipv4Addr::LOCALHOST)],
        ..SimWorldConfig::default()
    })
    .await;
    // 127.0.0.2 is loopback too, but another address: refused even with the secret
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.bind(SocketAddr::from(([127, 0, 0, 2], 0))).unwrap();
    let stream = sock.connect(c.robot_addr).await.unwrap();
    let client_cfg = ClientConfig {
        secret: c.robot_config().secret,
        ..ClientConfig::default()
    };
    let client = RobotClient::from_stream(stream, client_cfg);
    let e = client.hello().await.expect_err("refused by address");
    assert!(e.to_string().contains("address not allowed"), "{e}");
    drop(client);
    arm_untouched(&c);
    // From the allowed address, authenticated: a MOVEJ beyond the model's joint limits is
    // refused by the controller itself, whatever the client checked.
    let client = RobotClient::connect(c.robot_addr, c.robot_config().client_config())
        .await
        .unwrap();
    client.hello().await.expect("authenticated");
    client.power(true).await.unwrap();
    let e = client
        .move_joints([0.0, 0.0, 90.0, 0.0, 45.0, 400.0], None)
        .await
        .expect_err("outside joint 6's limits");
    assert!(
        matches!(
            e,
            RobotError::Rejected {
                code: robotlink::ErrorCode::Limit,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(!lock_world(&c.world).is_moving());
    c.stop().await;
}

/// The README's simulated cell with a real robot controller (nobody listens at its address).
fn real_robot_config(dir: &Path, secret_line: Option<&str>) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let robot = crate::cli::robot();
    let sim = std::fs::read_to_string(root.join("config/cell.sim.toml")).unwrap();
    let controller = format!(
        "[robot_controller]\nmode = \"real\"\naddress = \"127.0.0.1:9\"\n{}\n",
        secret_line.unwrap_or("")
    );
    let text = sim
        .replace(
            "robot = \"robots/staubli_tx60.toml\"",
            &format!("robot = {:?}", robot.to_string_lossy()),
        )
        .replace("[robot_controller]\nmode = \"sim\"\n", &controller);
    assert!(text.contains("mode = \"real\""));
    let f = dir.join("cell.toml");
    std::fs::write(&f, text).unwrap();
    f
}

fn set_mode(p: &Path, mode: u32) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap();
}

#[test]
fn a_real_controller_needs_a_private_secret_file_and_its_text_never_shows() {
    let dir = tempfile::tempdir().unwrap();
    let run = |cfg: &Path| {
        Command::new(env!("CARGO_BIN_EXE_cellcal"))
            .args(["run", "--config"])
            .arg(cfg)
            .arg("--store")
            .arg(dir.path().join("c.db"))
            .stdin(Stdio::null())
            .output()
            .expect("run cellcal")
    };
    // no secret_file: refused before anything starts, saying what to do
    let out = run(&real_robot_config(dir.path(), None));
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("robot_controller.secret_file: not set") && err.contains("openssl rand"),
        "{err}"
    );
    // the daemon refuses to start on it too, before it listens (not a 5xx on the first create)
    let out = Command::new(env!("CARGO_BIN_EXE_cellcal"))
        .args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(real_robot_config(dir.path(), None))
        .arg("--store")
        .arg(dir.path().join("c.db"))
        .stdin(Stdio::null())
        .output()
        .expect("serve");
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("robot_controller.secret_file: not set"),
        "{err}"
    );
    // a secret every user may read: refused, the file named, its text not shown
    let key = dir.path().join("robot.key");
    std::fs::write(&key, format!("{KEY}\n")).unwrap();
    set_mode(&key, 0o644);
    let cfg = real_robot_config(dir.path(), Some("secret_file = \"robot.key\""));
    let out = run(&cfg);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("robot.key") && err.contains("chmod 600"),
        "{err}"
    );
    // private, not hex: refused without quoting it
    std::fs::write(&key, "correct horse battery staple\n").unwrap();
    set_mode(&key, 0o600);
    let err = String::from_utf8_lossy(&run(&cfg).stderr).into_owned();
    assert!(
        err.contains("64 hex digits") && !err.contains("horse"),
        "{err}"
    );
    // private and well formed: the campaign is stored, nothing moves without --arm; the
    // check of every device finds nobody at the controller's address (exit 1, naming it)
    std::fs::write(&key, format!("{KEY}\n")).unwrap();
    let out = run(&cfg);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert!(
        stdout.contains("campaign 1 is not armed: nothing moves")
            && stdout.contains("robot 127.0.0.1:9: FAILED"),
        "{stdout}"
    );
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("device check failed: robot."),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!text.contains(&KEY[..16]), "the secret was printed: {text}");
    assert!(!text.contains("secret_file: not set"), "{text}");
    // the configuration keeps the path only; no Debug or serialisation carries the secret
    let parsed = parse_cell_config(&std::fs::read_to_string(&cfg).unwrap(), &cfg).unwrap();
    assert_eq!(
        parsed.robot_controller.secret_file.as_deref(),
        Some(key.as_path())
    );
    let link = LinkRobotConfig {
        secret: Some(cellcal::cell::controller_secret(&parsed.robot_controller).unwrap()),
        ..LinkRobotConfig::default()
    };
    for shown in [
        format!("{parsed:?}"),
        format!("{link:?}"),
        format!("{:?}", LinkRobot::new(link.clone())),
        serde_json::to_string(&link).unwrap(),
        toml::to_string(&link).unwrap(),
    ] {
        assert!(!shown.contains(&KEY[..16]), "{shown}");
    }
}

#[test]
fn cellcal_sim_uses_the_configured_secret_file() {
    // `cellcal sim` and another process with the same secret_file: that process drives the
    // simulated robot; a client without it does not.
    let dir = tempfile::tempdir().unwrap();
    let key = dir.path().join("robot.key");
    std::fs::write(&key, format!("{KEY}\n")).unwrap();
    set_mode(&key, 0o600);
    let robot = crate::cli::robot();
    let cfg = dir.path().join("cell.toml");
    std::fs::write(
        &cfg,
        format!(
            "robot = {:?}\n\n[robot_controller]\nsecret_file = \"robot.key\"\n\n[sim]\nseed = 7\n",
            robot.to_string_lossy()
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_cellcal"))
        .args(["sim", "--config"])
        .arg(&cfg)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .stdin(Stdio::null())
        .spawn()
        .expect("spawn cellcal sim");
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut robot_addr = None;
    for _ in 0..3 {
        let mut l = String::new();
        out.read_line(&mut l).unwrap();
        if let Some(a) = l.trim().strip_prefix("robot ") {
            robot_addr = Some(a.to_owned());
        }
    }
    let addr = robot_addr.expect("a robot line");
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let result = rt.block_on(async {
        let with = ClientConfig {
            secret: Some(SharedSecret::read_file(&key).unwrap()),
            ..ClientConfig::default()
        };
        let c = RobotClient::connect(addr.as_str(), with).await.unwrap();
        let id = c.hello().await;
        drop(c);
        tokio::time::sleep(Duration::from_millis(300)).await;
        let c = RobotClient::connect(addr.as_str(), ClientConfig::default())
            .await
            .unwrap();
        (id, c.hello().await)
    });
    let _ = child.kill();
    let _ = child.wait();
    let (id, without) = result;
    assert_eq!(
        id.expect("authenticated with the file's secret").ctrl,
        "CELLCAL-SIM"
    );
    assert!(matches!(without, Err(RobotError::Auth(_))), "{without:?}");
}

/// The VAL3 application's files (not run in CI: no controller here), parsed as XML.
fn val3_files() -> Vec<(String, String)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/staubli/cellcal");
    let mut files: Vec<(String, String)> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read_to_string(&p).unwrap())
        })
        .collect();
    files.sort();
    files
}

#[test]
fn the_val3_app_is_well_formed_and_calls_only_its_own_programs() {
    let files = val3_files();
    let programs: Vec<String> = files
        .iter()
        .filter_map(|(n, _)| n.strip_suffix(".pgx").map(str::to_owned))
        .collect();
    let project = &files.iter().find(|(n, _)| n == "cellcal.pjx").unwrap().1;
    for (name, text) in &files {
        let doc = roxmltree::Document::parse(text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let Some(stem) = name.strip_suffix(".pgx") else {
            continue;
        };
        assert!(
            project.contains(&format!("<Program file=\"{name}\" />")),
            "{name} is not in cellcal.pjx"
        );
        let program = doc
            .descendants()
            .find(|n| n.has_tag_name("Program"))
            .unwrap();
        assert_eq!(program.attribute("name"), Some(stem), "{name}");
        let code = doc
            .descendants()
            .find(|n| n.has_tag_name("Code"))
            .and_then(|n| n.text())
            .unwrap_or_default();
        for call in code.split("call ").skip(1) {
            let callee = call.split('(').next().unwrap().trim();
            assert!(
                programs.iter().any(|p| p == callee),
                "{name} calls {callee}, which is no program of the application"
            );
        }
    }
    assert!(programs.len() >= 20, "{programs:?}");
}

/// `name`'s values in cellcal.dtx, in key order.
fn dtx_numbers(dtx: &roxmltree::Document, name: &str) -> Vec<u64> {
    let data = dtx
        .descendants()
        .find(|n| n.has_tag_name("Data") && n.attribute("name") == Some(name))
        .unwrap_or_else(|| panic!("no {name} in cellcal.dtx"));
    let mut v: Vec<(usize, u64)> = data
        .children()
        .filter(|n| n.has_tag_name("Value"))
        .map(|n| {
            let key = n.attribute("key").unwrap().parse().unwrap();
            (key, n.attribute("value").unwrap().parse().unwrap())
        })
        .collect();
    v.sort();
    assert!(v.iter().enumerate().all(|(i, (k, _))| i == *k), "{name}");
    v.into_iter().map(|(_, x)| x).collect()
}

#[test]
fn the_val3_sha256_tables_and_hmac_labels_are_the_protocols() {
    // The controller computes HMAC-SHA256 itself (shaBlock.pgx): its round constants and
    // initial state must be SHA-256's, its labels the ones robotlink uses.
    let text = &val3_files()
        .into_iter()
        .find(|(n, _)| n == "cellcal.dtx")
        .unwrap()
        .1;
    let dtx = roxmltree::Document::parse(text).unwrap();
    let k: Vec<u32> = dtx_numbers(&dtx, "nK").iter().map(|&x| x as u32).collect();
    let h0: Vec<u32> = dtx_numbers(&dtx, "nH0").iter().map(|&x| x as u32).collect();
    assert_eq!((k.len(), h0.len()), (64, 8));
    let label = |name| -> Vec<u8> { dtx_numbers(&dtx, name).iter().map(|&x| x as u8).collect() };
    assert_eq!(label("nLblC"), robotlink::auth::CLIENT_LABEL);
    assert_eq!(label("nLblS"), robotlink::auth::SERVER_LABEL);
    assert_eq!(label("nLblN").len(), 18);
    // FIPS 180-4 with the controller's tables, against the sha2 crate
    let sha256 = |msg: &[u8]| -> Vec<u8> {
        let mut h: [u32; 8] = h0.clone().try_into().unwrap();
        let mut m = msg.to_vec();
        m.push(0x80);
        while m.len() % 64 != 56 {
            m.push(0);
        }
        m.extend_from_slice(&((msg.len() as u64) * 8).to_be_bytes());
        for block in m.chunks(64) {
            let mut w = [0u32; 64];
            for t in 0..64 {
                w[t] = if t < 16 {
                    u32::from_be_bytes(block[4 * t..4 * t + 4].try_into().unwrap())
                } else {
                    let s0 =
                        w[t - 15].rotate_right(7) ^ w[t - 15].rotate_right(18) ^ (w[t - 15] >> 3);
                    let s1 =
                        w[t - 2].rotate_right(17) ^ w[t - 2].rotate_right(19) ^ (w[t - 2] >> 10);
                    w[t - 16]
                        .wrapping_add(s0)
                        .wrapping_add(w[t - 7])
                        .wrapping_add(s1)
                };
            }
            let mut v = h;
            for t in 0..64 {
                let e = v[4];
                let s1 = e.rotate_right(6) ^ e.rotate_right(11) ^ e.rotate_right(25);
                let ch = v[6] ^ (e & (v[5] ^ v[6]));
                let t1 = v[7]
                    .wrapping_add(s1)
                    .wrapping_add(ch)
                    .wrapping_add(k[t])
                    .wrapping_add(w[t]);
                let a = v[0];
                let s0 = a.rotate_right(2) ^ a.rotate_right(13) ^ a.rotate_right(22);
                let maj = (a & v[1]) ^ (v[2] & (a ^ v[1]));
                v = [
                    t1.wrapping_add(s0.wrapping_add(maj)),
                    a,
                    v[1],
                    v[2],
                    v[3].wrapping_add(t1),
                    e,
                    v[5],
                    v[6],
                ];
            }
            for (x, y) in h.iter_mut().zip(v) {
                *x = x.wrapping_add(y);
            }
        }
        h.iter().flat_map(|x| x.to_be_bytes()).collect()
    };
    use sha2::Digest;
    for msg in [
        &b""[..],
        b"abc",
        &[0x5a; 200][..],
        robotlink::auth::CLIENT_LABEL,
    ] {
        assert_eq!(sha256(msg), sha2::Sha256::digest(msg).to_vec(), "{msg:?}");
    }
}

#[test]
fn the_deploy_guide_says_the_controller_network_must_be_isolated_and_how() {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/README.md"))
            .unwrap();
    let section = text
        .split("## 2a. Isolate the robot controller network")
        .nth(1)
        .expect("the isolation section")
        .split("\n## ")
        .next()
        .unwrap();
    for needed in [
        "The\ncontroller network must be isolated",
        "only the cellcal PC may reach the controller",
        "VLAN",
        "Firewall",
        "only from the cellcal PC's address",
        "nc -vz",
    ] {
        assert!(
            section.contains(needed),
            "deploy/README.md §2a lacks {needed:?}"
        );
    }
    assert!(text.contains("secret_file = \"robotlink.key\""));
}

#[test]
fn adding_or_changing_the_secret_file_does_not_block_a_resume() {
    // Access to the controller is not part of what a campaign measured: a campaign created
    // before its cell had a secret_file (or with another one) resumes without an override.
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let robot = crate::cli::robot();
    let sim = std::fs::read_to_string(root.join("config/cell.sim.toml"))
        .unwrap()
        .replace(
            "robot = \"robots/staubli_tx60.toml\"",
            &format!("robot = {:?}", robot.to_string_lossy()),
        );
    let cfg = dir.path().join("cell.toml");
    let key = dir.path().join("robot.key");
    std::fs::write(&key, format!("{KEY}\n")).unwrap();
    set_mode(&key, 0o600);
    let run = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_cellcal"))
            .args(["run", "--config"])
            .arg(&cfg)
            .arg("--store")
            .arg(dir.path().join("c.db"))
            .args(extra)
            .stdin(Stdio::null())
            .output()
            .expect("run cellcal")
    };
    std::fs::write(&cfg, &sim).unwrap();
    let out = run(&[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let with_key = sim.replace(
        "[robot_controller]\n",
        "[robot_controller]\nsecret_file = \"robot.key\"\n",
    );
    assert_ne!(with_key, sim);
    std::fs::write(&cfg, &with_key).unwrap();
    let out = run(&["--campaign", "1"]);
    assert!(
        out.status.success(),
        "resume refused: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}
