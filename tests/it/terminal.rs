//! The technician's terminal: the real `cellcal run` binary on a pseudo-terminal with a manual
//! micrometer stage, answered the way a person would (a typo, an out-of-tolerance reading, then
//! an abort).

use std::io::{Read, Write};
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cellcal::store::Store;

use super::campaign::{config_text, write_config};

/// A child process whose stdin, stdout and stderr are one pseudo-terminal.
struct PtyChild {
    child: std::process::Child,
    master: std::fs::File,
    output: Arc<Mutex<String>>,
    seen: usize,
}

impl PtyChild {
    fn spawn(mut cmd: Command) -> PtyChild {
        let pty = nix::pty::openpty(None, None).expect("openpty");
        let slave: OwnedFd = pty.slave;
        let io = |fd: &OwnedFd| Stdio::from(fd.try_clone().expect("dup slave"));
        cmd.stdin(io(&slave)).stdout(io(&slave)).stderr(io(&slave));
        let child = cmd.spawn().expect("spawn");
        drop(slave);
        let master = std::fs::File::from(pty.master);
        let mut reader = master.try_clone().expect("dup master");
        let output = Arc::new(Mutex::new(String::new()));
        let sink = Arc::clone(&output);
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            // EIO once the child and every slave copy are gone
            while let Ok(n) = reader.read(&mut buf) {
                if n == 0 {
                    break;
                }
                sink.lock()
                    .expect("output")
                    .push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        });
        PtyChild {
            child,
            master,
            output,
            seen: 0,
        }
    }

    /// Wait until `text` appears after what was already matched; returns the output up to it.
    fn expect(&mut self, text: &str) -> String {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            {
                let out = self.output.lock().expect("output");
                if let Some(i) = out[self.seen..].find(text) {
                    let upto = out[self.seen..self.seen + i + text.len()].to_owned();
                    self.seen += i + text.len();
                    return upto;
                }
            }
            assert!(
                Instant::now() < deadline,
                "`{text}` did not appear; terminal so far:\n{}",
                self.output.lock().expect("output")
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Wait for the process to exit.
    fn wait_exit(&mut self) -> std::process::ExitStatus {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(s) = self.child.try_wait().expect("wait") {
                return s;
            }
            assert!(Instant::now() < deadline, "cellcal did not exit");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Type a line.
    fn send_line(&mut self, line: &str) {
        self.master
            .write_all(format!("{line}\r").as_bytes())
            .expect("type");
    }
}

/// `cellcal run --arm` on a pseudo-terminal: a 20-pose campaign with a manual micrometer in
/// `dir`; returns the child and the store path.
fn manual_run(dir: &Path) -> (PtyChild, PathBuf) {
    let text = config_text("", "", "")
        .replace("kind = \"serial\"", "kind = \"manual\"")
        // the setup questions are the same kind; these tests follow the pose questions
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false")
        .replace("poses = 300", "poses = 20")
        // 14 × 6 equations ≥ 3 × 28 parameters (OP with base): the fewest a run accepts
        .replace("ident = 100", "ident = 14");
    let cfg = write_config(dir, &text);
    let store = dir.join("c.db");
    let mut cmd = Command::new(assert_cmd::cargo::cargo_bin("cellcal"));
    cmd.args(["run", "--arm", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store);
    (PtyChild::spawn(cmd), store)
}

#[test]
fn technician_prompts_at_the_terminal_validate_readings_and_abort() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut t, store) = manual_run(dir.path());
    // the drift reference at P1, with its context (pieces in ASCII: the pty output is read in
    // chunks that may split a character)
    let asked = t.expect("Set the micrometer to 0.000 mm and enter the reading");
    for part in ["[drift check at the reference pose", "P1", "robot stopped"] {
        assert!(asked.contains(part), "{part}: {asked}");
    }
    t.send_line("0.000");
    // before the robot moves to the first pose: the cell confirmed clear, with its own key (a
    // bare Enter, which answers the other questions, does not release the robot)
    let asked = t.expect("Confirm that the cell is clear");
    for part in ["[pose 1 of 20", "robot stopped"] {
        assert!(asked.contains(part), "{part}: {asked}");
    }
    t.expect("[type c and Enter when the cell is clear, or a to abort]");
    t.send_line("");
    t.expect("the robot moves only after c");
    t.send_line("c");
    // first pose: P1 is already set, so the first question is P2
    let asked = t.expect("Set the micrometer to 10.000 mm and enter the reading");
    for part in ["[pose 1 of 20", "P2", "robot stopped", "safe to approach"] {
        assert!(asked.contains(part), "{part}: {asked}");
    }
    t.send_line("ten");
    t.expect("`ten` is not a number");
    t.send_line("10.5");
    t.expect("The reading 10.500 mm, 0.500 mm from the requested 10.000 mm");
    // a decimal comma is a decimal point
    t.send_line("10,004");
    // second pose, once the cell is confirmed clear (asked at once: the progress line
    // `progress: pose 1/20` may print before or after it): the stage stands at P2, read first,
    // so the one question is P1 (one stage move per pose)
    t.expect("Confirm that the cell is clear");
    t.send_line("c");
    t.expect("Set the micrometer to 0.000 mm and enter the reading");
    t.send_line("0.001");
    // third pose: P1 read where the stage stands, then abort at the question for P2
    t.expect("Confirm that the cell is clear");
    t.send_line("c");
    t.expect("Set the micrometer to 10.000 mm and enter the reading");
    t.send_line("a");
    t.expect("aborted");
    let status = t.wait_exit();
    assert_eq!(status.code(), Some(130), "abort exit code");
    let printed = t.output.lock().expect("output").clone();
    for line in ["progress: pose 1/20 ", "progress: pose 2/20 "] {
        assert!(printed.contains(line), "{line}: {printed}");
    }
    let s = Store::open(&store).expect("store");
    let done = s.done_poses(1).expect("done");
    assert_eq!(done.len(), 2, "two poses measured before the abort");
    // the typed readings are what was stored as stage positions
    let mut p2: Vec<f64> = s
        .measured_poses(1)
        .expect("measured")
        .iter()
        .map(|(_, m)| m.p2.as_ref().expect("P2").stage_mm)
        .collect();
    p2.sort_by(f64::total_cmp);
    // pose 2 read P2 where pose 1 left the stage
    assert_eq!(p2, vec![10.004, 10.004]);
}

#[test]
fn a_fault_pauses_at_the_terminal_and_enter_resumes() {
    let dir = tempfile::tempdir().expect("tempdir");
    // the first 7 measurements find the beam broken: 5 attempts fail, the campaign pauses
    let text = config_text("", "", "")
        .replace("poses = 300", "poses = 24")
        // 16 × 6 equations: a little above the fewest a run accepts (14), so the result of
        // this short campaign is not judged overfit by chance
        .replace("ident = 100", "ident = 16")
        .replace("tool_frame = true", "tool_frame = false")
        .replace("base_registration = true", "base_registration = false")
        .replace(
            "beam_break_before_measure = 0",
            "beam_break_before_measure = 7",
        );
    let cfg = write_config(dir.path(), &text);
    let store = dir.path().join("c.db");
    let mut cmd = Command::new(assert_cmd::cargo::cargo_bin("cellcal"));
    cmd.args(["run", "--arm", "--config"])
        .arg(&cfg)
        .arg("--store")
        .arg(&store);
    let mut t = PtyChild::spawn(cmd);
    t.expect("Campaign paused: tracker: no acceptable point after 5 attempts");
    t.expect("press Enter to resume, or type a to abort");
    t.send_line("");
    t.expect("progress: pose 24/24 ");
    t.expect("verify  after");
    let status = t.wait_exit();
    let printed = t.output.lock().expect("output").clone();
    assert!(status.success(), "{status:?}: {printed}");
    let s = Store::open(&store).expect("store");
    assert_eq!(s.done_poses(1).expect("done").len(), 24);
}

#[test]
fn ctrl_c_at_a_technician_question_aborts_at_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut t, store) = manual_run(dir.path());
    t.expect("Set the micrometer to 0.000 mm and enter the reading");
    // Ctrl-C: the terminal sends SIGINT; nothing is typed afterwards
    let asked = Instant::now();
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(t.child.id() as i32),
        nix::sys::signal::Signal::SIGINT,
    )
    .expect("SIGINT");
    let status = t.wait_exit();
    assert_eq!(status.code(), Some(130), "Ctrl-C exit code");
    assert!(
        asked.elapsed() < Duration::from_secs(10),
        "aborted at once, not after another answer"
    );
    t.expect("aborted by SIGINT");
    let s = Store::open(&store).expect("store");
    assert_eq!(s.campaign(1).expect("row").state, "aborted");
}
