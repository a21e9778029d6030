//! `cellcal serve` under clients that hold connections or send hostile requests: an ABORT
//! reaches the robot (through a logging robotlink proxy) while idle connections fill the
//! descriptor limit; idle and slow connections are closed after their timeouts while busy ones
//! stay; huge unknown method names grow neither the daemon's memory, nor `/metrics`, nor its log.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::os::unix::process::CommandExt;
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::serve::{
    agent, arm_and_start, config_with_tokens, create, get, post, serve_command, start_command,
    start_logged, Server,
};

/// The lines a client sent through a [`LineProxy`], each with when it arrived.
type Lines = Arc<Mutex<Vec<(Instant, String)>>>;

/// A TCP proxy in front of a line protocol (robotlink): forwards every connection to
/// `upstream` and timestamps each line the client sends as it arrives.
struct LineProxy {
    addr: SocketAddr,
    lines: Lines,
}

impl LineProxy {
    fn start(upstream: SocketAddr) -> LineProxy {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind proxy");
        let addr = listener.local_addr().expect("proxy address");
        let lines: Lines = Arc::default();
        let log = Arc::clone(&lines);
        std::thread::spawn(move || {
            for client in listener.incoming() {
                let Ok(client) = client else { return };
                let Ok(server) = TcpStream::connect(upstream) else {
                    continue;
                };
                let _ = (client.set_nodelay(true), server.set_nodelay(true));
                let (mut back_from, mut back_to) = match (server.try_clone(), client.try_clone()) {
                    (Ok(s), Ok(c)) => (s, c),
                    _ => continue,
                };
                std::thread::spawn(move || {
                    let _ = std::io::copy(&mut back_from, &mut back_to);
                    let _ = back_to.shutdown(std::net::Shutdown::Both);
                });
                let log = Arc::clone(&log);
                std::thread::spawn(move || {
                    let (mut from, mut to) = (BufReader::new(client), server);
                    let mut line = Vec::new();
                    loop {
                        line.clear();
                        match from.read_until(b'\n', &mut line) {
                            Ok(0) | Err(_) => break,
                            Ok(_) => {}
                        }
                        let at = Instant::now();
                        let text = String::from_utf8_lossy(&line).trim_end().to_owned();
                        log.lock().expect("proxy log").push((at, text));
                        if to.write_all(&line).is_err() {
                            break;
                        }
                    }
                    let _ = to.shutdown(std::net::Shutdown::Both);
                });
            }
        });
        LineProxy { addr, lines }
    }

    /// When the first line with the word `word` arrived at or after `since`.
    fn first(&self, word: &str, since: Instant) -> Option<Instant> {
        self.lines
            .lock()
            .expect("proxy log")
            .iter()
            .find(|(at, l)| *at >= since && l.split_whitespace().any(|w| w == word))
            .map(|(at, _)| *at)
    }
}

/// `text` with `from` (which must be there) replaced by `to`.
fn replaced(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "`{from}` not in\n{text}");
    text.replace(from, to)
}

use super::common::free_port;

/// The resident set size of process `pid` (kB), from `/proc`.
fn rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or_else(|| panic!("no VmRSS in {status}"))
}

/// `host:port` of a plain-HTTP server.
fn authority(s: &Server) -> String {
    s.base
        .strip_prefix("http://")
        .expect("plain http")
        .to_owned()
}

/// Send `head` (a whole request head, or part of one) on a new connection.
fn connect_and_send(s: &Server, head: &str) -> TcpStream {
    let mut c = TcpStream::connect(authority(s)).expect("connect");
    c.write_all(head.as_bytes()).expect("write");
    c
}

/// Read until the server closes `c`; how long that took after `since` (`None`: still open
/// after `limit`).
fn closed_within(c: &mut TcpStream, since: Instant, limit: Duration) -> Option<Duration> {
    c.set_read_timeout(Some(Duration::from_millis(100)))
        .expect("read timeout");
    let mut buf = [0u8; 4096];
    loop {
        match c.read(&mut buf) {
            Ok(0) => return Some(since.elapsed()),
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(_) => return Some(since.elapsed()),
        }
        if since.elapsed() >= limit {
            return None;
        }
    }
}

/// Whether the server has closed `c` (a read now ends or fails instead of waiting).
fn is_closed(mut c: &TcpStream) -> bool {
    c.set_nonblocking(true).expect("nonblocking");
    let mut buf = [0u8; 64];
    !matches!(c.read(&mut buf), Err(e) if e.kind() == std::io::ErrorKind::WouldBlock)
}

#[test]
fn an_abort_stops_the_robot_within_200_ms_while_idle_connections_fill_the_descriptor_limit() {
    // the test itself holds ~250 sockets
    cellcal::api::conns::raise_descriptor_limit().expect("descriptor limit");
    let dir = tempfile::tempdir().expect("tempdir");
    // the simulated robot on a known port, reached through the logging proxy
    let robot_port = free_port();
    let proxy = LineProxy::start(SocketAddr::from(([127, 0, 0, 1], robot_port)));
    let cfg = config_with_tokens(dir.path(), "");
    let text = std::fs::read_to_string(&cfg).expect("config");
    let text = replaced(
        &text,
        "[robot_controller]\nmode = \"sim\"",
        &super::common::real_controller(dir.path(), proxy.addr),
    );
    let text = replaced(
        &text,
        "robot_port = 0",
        &format!("robot_port = {robot_port}"),
    );
    // moves that take a while: the robot is moving when the abort comes
    let text = replaced(
        &text,
        "move_speed_deg_s = 200000.0",
        "move_speed_deg_s = 60.0",
    );
    std::fs::write(&cfg, text).expect("write config");
    let log = std::fs::File::create(dir.path().join("serve.log")).expect("log");
    let mut cmd = serve_command(&cfg, &dir.path().join("c.db"), "127.0.0.1:0");
    cmd.stderr(Stdio::from(log));
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            nix::sys::resource::setrlimit(nix::sys::resource::Resource::RLIMIT_NOFILE, 256, 256)
                .map_err(std::io::Error::from)
        });
    }
    let s = start_command(cmd, "operator-token");
    let id = create(&s, "{}");
    arm_and_start(&s, id);
    let (code, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(
        (code, &v["state"]),
        (200, &serde_json::json!("running")),
        "{v}"
    );
    let started = Instant::now();
    while proxy.first("MOVEJ", started).is_none() {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the robot never moved"
        );
        std::thread::sleep(Duration::from_millis(20));
    }

    // 245 idle, unauthenticated connections (nothing sent on them)
    let mut idle = Vec::new();
    for _ in 0..245 {
        let addr: SocketAddr = authority(&s).parse().expect("address");
        match TcpStream::connect_timeout(&addr, Duration::from_secs(5)) {
            Ok(c) => idle.push(c),
            Err(e) => eprintln!("an idle connection failed: {e}"),
        }
    }
    assert_eq!(idle.len(), 245);
    std::thread::sleep(Duration::from_millis(500));

    // a viewer's ABORT, on a new connection
    let viewer: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(5)))
        .build()
        .into();
    let sent = Instant::now();
    let answer = viewer
        .post(&format!("{}/api/campaigns/{id}/commands", s.base))
        .header("authorization", "Bearer viewer-token")
        .header("content-type", "application/json")
        .send(r#"{"command": "abort"}"#);
    let answered = sent.elapsed();
    let stop = proxy.first("STOP", sent).map(|at| at.duration_since(sent));
    eprintln!(
        "{} idle connections opened; ABORT answered {:?} after {answered:?}; STOP at the robot after {stop:?}",
        idle.len(),
        answer.as_ref().map(|r| r.status())
    );
    let answer = answer.unwrap_or_else(|e| panic!("ABORT got no answer in {answered:?}: {e}"));
    assert_eq!(answer.status().as_u16(), 200);
    let stop = stop.expect("no STOP reached the robot");
    assert!(stop < Duration::from_millis(200), "STOP after {stop:?}");
    // the idle connections made room: the oldest were closed, the daemon answers
    let closed = idle.iter().filter(|c| is_closed(c)).count();
    eprintln!("{closed} of the idle connections were closed by the daemon");
    assert!(closed > 0);
    let (code, v) = get(&s, &format!("/api/campaigns/{id}"));
    assert_eq!(
        (code, &v["state"]),
        (200, &serde_json::json!("aborted")),
        "{v}"
    );
}

#[test]
fn idle_and_slow_connections_are_closed_after_their_timeouts_and_busy_ones_stay() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = config_with_tokens(dir.path(), "");
    let mut cmd = serve_command(&cfg, &dir.path().join("c.db"), "127.0.0.1:0");
    cmd.stderr(Stdio::null())
        .env(cellcal::api::conns::HEADER_READ_TIMEOUT_ENV, "500")
        .env(cellcal::api::conns::IDLE_TIMEOUT_ENV, "1500");
    let s = start_command(cmd, "operator-token");
    let id = create(&s, "{}");
    let host = authority(&s);
    let limit = Duration::from_secs(5);

    // nothing sent: closed by the first-request (header-read) timeout
    let t = Instant::now();
    let mut silent = connect_and_send(&s, "");
    // half a request head, then nothing
    let mut slow = connect_and_send(&s, &format!("GET /api/health HTTP/1.1\r\nhost: {host}\r\n"));
    // a whole request, then an idle keep-alive connection
    let mut kept = connect_and_send(
        &s,
        &format!("GET /api/health HTTP/1.1\r\nhost: {host}\r\n\r\n"),
    );
    // an event stream (authenticated, in flight): it stays open however long it is quiet
    let mut stream = connect_and_send(
        &s,
        &format!(
            "GET /api/campaigns/{id}/stream HTTP/1.1\r\nhost: {host}\r\n\
             authorization: Bearer operator-token\r\n\r\n"
        ),
    );
    let silent_after = closed_within(&mut silent, t, limit);
    let slow_after = closed_within(&mut slow, t, limit);
    let kept_after = closed_within(&mut kept, t, limit);
    eprintln!("closed after: silent {silent_after:?}, half a head {slow_after:?}, keep-alive {kept_after:?}");
    for (what, after) in [
        ("a silent connection", silent_after),
        ("half a request head", slow_after),
        ("an idle keep-alive connection", kept_after),
    ] {
        let after = after.unwrap_or_else(|| panic!("{what}: still open after {limit:?}"));
        assert!(
            after >= Duration::from_millis(400),
            "{what}: closed after {after:?}"
        );
    }
    assert_eq!(
        closed_within(&mut stream, Instant::now(), Duration::from_secs(2)),
        None,
        "the event stream was closed while in flight"
    );
    assert_eq!(get(&s, "/api/health").0, 200);
}

#[test]
fn huge_unknown_methods_grow_neither_memory_nor_metrics_nor_the_log() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = super::serve::fast_config(dir.path(), "serial", 20, 14);
    let log = dir.path().join("serve.log");
    let s = start_logged(&cfg, &dir.path().join("c.db"), &log, &[]);
    let host = authority(&s);
    let request = |i: usize| {
        let method = format!("M{i:05}{}", "A".repeat(60 * 1024));
        let mut c = connect_and_send(
            &s,
            &format!(
                "{method} /api/campaigns HTTP/1.1\r\nhost: {host}\r\nconnection: close\r\n\r\n"
            ),
        );
        c.set_read_timeout(Some(Duration::from_secs(20)))
            .expect("timeout");
        let mut answer = Vec::new();
        let _ = c.read_to_end(&mut answer);
        assert!(
            answer.starts_with(b"HTTP/1.1 4"),
            "{:?}",
            String::from_utf8_lossy(&answer[..answer.len().min(200)])
        );
    };
    // warm up (buffers, allocator arenas, the first log lines)
    for i in 0..40 {
        request(i);
    }
    let (before_kb, log_before) = (rss_kb(s.pid()), std::fs::metadata(&log).expect("log").len());
    for i in 1000..1300 {
        request(i);
    }
    let grown_kb = rss_kb(s.pid()).saturating_sub(before_kb);
    let log_grown = std::fs::metadata(&log).expect("log").len() - log_before;
    // at most 1 MiB of it
    let r = agent()
        .get(&format!("{}/metrics", s.base))
        .header("authorization", &format!("Bearer {}", s.token))
        .call()
        .expect("GET /metrics");
    assert_eq!(r.status().as_u16(), 200);
    let mut metrics = String::new();
    r.into_body()
        .into_reader()
        .take(1 << 20)
        .read_to_string(&mut metrics)
        .expect("metrics text");
    eprintln!(
        "300 requests with 60 KB methods: RSS +{grown_kb} kB, log +{log_grown} bytes, /metrics {} bytes",
        metrics.len()
    );
    assert!(grown_kb < 2048, "RSS grew by {grown_kb} kB");
    assert!(
        metrics.len() < 100 * 1024,
        "/metrics is {} bytes",
        metrics.len()
    );
    assert!(!metrics.contains("AAAAAAAA"), "a raw method became a label");
    assert!(
        metrics.contains(r#"method="other",route="/api/campaigns",status="401""#),
        "{metrics}"
    );
    // every logged value cut to 200 characters
    assert!(log_grown < 300 * 2048, "the log grew by {log_grown} bytes");
    let text = std::fs::read_to_string(&log).expect("log");
    let longest = text.lines().map(str::len).max().unwrap_or(0);
    assert!(longest < 2048, "a log line of {longest} bytes");
    assert!(
        text.contains("M01299AAAA"),
        "the refused requests are logged"
    );
    // the daemon still serves
    assert_eq!(post(&s, "/api/campaigns", "{}").0, 201);
}
