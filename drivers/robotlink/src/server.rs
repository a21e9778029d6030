//! Protocol server over a [`RobotBackend`], with deterministic fault injection.
//!
//! The server owns the protocol (framing, sequencing, the one-client rule, `WAIT` polling,
//! events); the backend owns the physics. A second client receives
//! `* EVT REFUSED another client is connected` and is closed at once.

use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex as StdMutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::net::TcpListener;
use tokio::sync::{watch, Mutex};
use tracing::{debug, info, warn};

use crate::codec::{
    self, format_event, format_reply, parse_request, request_seq, ErrorCode, Event, EventName,
    Identity, Pose, Reply, ReplyBody, Request, RobotState, MAX_LINE, PROTO_VERSION,
};
use crate::lineio::{read_line_limited, LineRead};

/// Rejection from a backend, turned into `ERR <code> <text>`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{code} {text}")]
pub struct BackendError {
    /// Protocol error code to send.
    pub code: ErrorCode,
    /// Human-readable text.
    pub text: String,
}

impl BackendError {
    /// Build a backend error.
    pub fn new(code: ErrorCode, text: impl Into<String>) -> Self {
        Self {
            code,
            text: text.into(),
        }
    }
}

/// The physical (or simulated) arm behind the server. Synchronous and cheap: the server polls it.
pub trait RobotBackend: Send + Sync {
    /// Controller / arm / software identity for `HELLO`.
    fn identity(&self) -> Identity {
        Identity {
            ctrl: "SIM".into(),
            arm: "SIM6".into(),
            sw: env!("CARGO_PKG_VERSION").into(),
        }
    }
    /// Controller mode token for `STATE` (e.g. `remote`); `MOVEJ` needs [`Self::remote_ok`].
    fn mode(&self) -> String {
        "remote".into()
    }
    /// Whether the mode allows remote motion (otherwise `E_MODE`).
    fn remote_ok(&self) -> bool {
        true
    }
    /// Check a joint target (degrees) against joint limits and reachability.
    fn check_target(&self, joints_deg: &[f64; 6]) -> Result<(), BackendError>;
    /// Start a joint move to `joints_deg` at `vel_pct` percent of nominal joint speed.
    fn start_move(&self, joints_deg: [f64; 6], vel_pct: f64) -> Result<(), BackendError>;
    /// Current joint positions in degrees.
    fn joints_deg(&self) -> [f64; 6];
    /// Current pose (mm, degrees) in the world frame.
    fn pose(&self) -> Result<Pose, BackendError>;
    /// True while a motion is executing.
    fn is_moving(&self) -> bool;
    /// True when no motion is pending and the arm is settled.
    fn is_settled(&self) -> bool;
    /// Abort any motion (VAL3 `resetMotion`).
    fn stop(&self);
    /// Switch arm power.
    fn set_power(&self, on: bool) -> Result<(), BackendError>;
    /// Arm power state.
    fn power(&self) -> bool;
    /// Hardware emergency stop state.
    fn estop(&self) -> bool;
}

/// Shared fault configuration; lock it briefly from tests to arm faults.
pub type FaultHandle = Arc<StdMutex<FaultConfig>>;

/// Joint read-back hook: maps true joints (degrees) to reported joints.
pub type JointHook = Arc<dyn Fn([f64; 6]) -> [f64; 6] + Send + Sync>;

/// Fault injection. Counters are one-shot: each trigger decrements its counter.
#[derive(Clone)]
pub struct FaultConfig {
    /// Reject the next N `MOVEJ` with `reject_code`.
    pub reject_movej: u32,
    /// Code used by `reject_movej` (e.g. Unreachable, Limit, Power, EStop).
    pub reject_code: ErrorCode,
    /// For the next N accepted `MOVEJ`, raise an E-stop `estop_delay` after acceptance.
    pub estop_during_move: u32,
    /// Delay between `MOVEJ` acceptance and the injected E-stop.
    pub estop_delay: Duration,
    /// Latched injected E-stop (set by `estop_during_move`; clear it to reset the E-stop).
    pub estop_latched: bool,
    /// The next N accepted `MOVEJ` never settle (WAIT ends with `E_TIMEOUT`).
    pub never_settle: u32,
    /// The next N accepted `MOVEJ` settle `slow_settle_extra` later than the backend says.
    pub slow_settle: u32,
    /// Extra settle time for `slow_settle`.
    pub slow_settle_extra: Duration,
    /// Constant offset (degrees) added to every joint read-back (`JOINTS`, `WAIT`).
    pub joint_offset_deg: [f64; 6],
    /// Optional read-back hook (noise etc.) applied after the offset.
    pub joint_hook: Option<JointHook>,
    /// Delay the next N replies by `reply_delay`.
    pub delay_reply: u32,
    /// Delay used by `delay_reply`.
    pub reply_delay: Duration,
    /// Write the next N replies in 3-byte pieces with a flush and 1 ms pause between pieces.
    pub split_reply: u32,
    /// Before the next N replies, send `extra_line` (an unsolicited line).
    pub extra_line: u32,
    /// Text of the extra line, without terminator.
    pub extra_line_text: String,
    /// Send the next N replies with a wrong sequence number (seq + 1000).
    pub wrong_seq: u32,
    /// Replace the second data field of the next N replies carrying numbers by `abc`.
    pub non_numeric: u32,
    /// After accepting the next N `MOVEJ`, reply OK and then drop the connection.
    pub disconnect_during_move: u32,
}

impl Default for FaultConfig {
    fn default() -> Self {
        Self {
            reject_movej: 0,
            reject_code: ErrorCode::Unreachable,
            estop_during_move: 0,
            estop_delay: Duration::from_millis(50),
            estop_latched: false,
            never_settle: 0,
            slow_settle: 0,
            slow_settle_extra: Duration::from_millis(200),
            joint_offset_deg: [0.0; 6],
            joint_hook: None,
            delay_reply: 0,
            reply_delay: Duration::from_millis(200),
            split_reply: 0,
            extra_line: 0,
            extra_line_text: "* EVT NOTE unsolicited".into(),
            wrong_seq: 0,
            non_numeric: 0,
            disconnect_during_move: 0,
        }
    }
}

impl std::fmt::Debug for FaultConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaultConfig")
            .field("reject_movej", &self.reject_movej)
            .field("reject_code", &self.reject_code)
            .field("estop_during_move", &self.estop_during_move)
            .field("estop_latched", &self.estop_latched)
            .field("never_settle", &self.never_settle)
            .field("slow_settle", &self.slow_settle)
            .field("joint_offset_deg", &self.joint_offset_deg)
            .field("joint_hook", &self.joint_hook.is_some())
            .field("delay_reply", &self.delay_reply)
            .field("split_reply", &self.split_reply)
            .field("extra_line", &self.extra_line)
            .field("wrong_seq", &self.wrong_seq)
            .field("non_numeric", &self.non_numeric)
            .field("disconnect_during_move", &self.disconnect_during_move)
            .finish_non_exhaustive()
    }
}

impl FaultConfig {
    /// New shared handle with no faults armed.
    pub fn handle() -> FaultHandle {
        Arc::new(StdMutex::new(FaultConfig::default()))
    }
}

fn take(counter: &mut u32) -> bool {
    if *counter > 0 {
        *counter -= 1;
        true
    } else {
        false
    }
}

fn lock_faults(f: &FaultHandle) -> std::sync::MutexGuard<'_, FaultConfig> {
    f.lock().unwrap_or_else(|e| e.into_inner())
}

/// Longest `WAIT` the server accepts (ms); larger values are clamped.
pub const MAX_WAIT_MS: u64 = 600_000;
const POLL: Duration = Duration::from_millis(5);
const MONITOR_PERIOD: Duration = Duration::from_millis(10);
const WRITE_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a new client waits for the previous session to end before being refused.
const REFUSE_GRACE: Duration = Duration::from_millis(200);

/// Accept clients on `listener` until `shutdown` completes; one client at a time.
pub async fn serve(
    listener: TcpListener,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    shutdown: impl Future<Output = ()>,
) -> std::io::Result<()> {
    let (stop_tx, stop_rx) = watch::channel(false);
    let busy = Arc::new(AtomicBool::new(false));
    let mut tasks = tokio::task::JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            acc = listener.accept() => {
                let (mut stream, peer) = match acc {
                    Ok(x) => x,
                    Err(e) => {
                        warn!(error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let _ = stream.set_nodelay(true);
                let backend = backend.clone();
                let faults = faults.clone();
                let busy = busy.clone();
                let stop_rx = stop_rx.clone();
                tasks.spawn(async move {
                    // Grace period: the previous session may still be winding down.
                    let mut got = false;
                    for _ in 0..(REFUSE_GRACE.as_millis() / 10) {
                        if !busy.swap(true, Ordering::SeqCst) {
                            got = true;
                            break;
                        }
                        tokio::time::sleep(Duration::from_millis(10)).await;
                    }
                    if !got {
                        info!(%peer, "refusing second client");
                        let line = format_event(&Event {
                            name: EventName::Refused,
                            data: "another client is connected".into(),
                        });
                        let _ = tokio::time::timeout(WRITE_TIMEOUT, async {
                            stream.write_all(line.as_bytes()).await?;
                            stream.shutdown().await
                        })
                        .await;
                        return;
                    }
                    info!(%peer, "client connected");
                    serve_connection(stream, backend, faults, stop_rx).await;
                    busy.store(false, Ordering::SeqCst);
                    info!(%peer, "client disconnected");
                });
            }
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
        }
    }
    let _ = stop_tx.send(true);
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        while tasks.join_next().await.is_some() {}
    })
    .await;
    tasks.abort_all();
    Ok(())
}

type SharedWriter<W> = Arc<Mutex<W>>;

struct Conn<W> {
    writer: SharedWriter<W>,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    speed_pct: f64,
    /// Set by the never_settle fault for the current move.
    never_settle: bool,
    /// Extra settle time for the current move (slow_settle fault).
    extra_settle: Duration,
    /// Power switched off on purpose (suppresses POWER_LOST).
    power_cmd_off: Arc<AtomicBool>,
}

/// Serve one client on any stream until it disconnects, sends a malformed line, or `stop` flips.
/// Motion is always stopped when this returns.
pub async fn serve_connection<S>(
    stream: S,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    mut stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Send + 'static,
{
    let (rd, wr) = tokio::io::split(stream);
    let mut rd = BufReader::new(rd);
    let writer = Arc::new(Mutex::new(wr));
    let power_cmd_off = Arc::new(AtomicBool::new(!backend.power()));
    let monitor = tokio::spawn(monitor_task(
        writer.clone(),
        backend.clone(),
        faults.clone(),
        power_cmd_off.clone(),
    ));
    let mut conn = Conn {
        writer,
        backend: backend.clone(),
        faults,
        speed_pct: 100.0,
        never_settle: false,
        extra_settle: Duration::ZERO,
        power_cmd_off,
    };
    loop {
        let read = tokio::select! {
            r = read_line_limited(&mut rd, MAX_LINE) => r,
            _ = stopped(&mut stop) => break,
        };
        let line = match read {
            Ok(LineRead::Line(l)) => l,
            Ok(LineRead::Eof) => break,
            Ok(LineRead::Bad(why)) => {
                let _ = conn.send_err(0, ErrorCode::Syntax, &why).await;
                break;
            }
            Err(e) => {
                debug!(error = %e, "read failed");
                break;
            }
        };
        let req = match parse_request(&line) {
            Ok(r) => r,
            Err(e) if e.is_args_error() => {
                let seq = request_seq(&line).unwrap_or(0);
                if conn
                    .send_err(seq, ErrorCode::Args, &e.to_string())
                    .await
                    .is_err()
                {
                    break;
                }
                continue;
            }
            Err(e) => {
                let seq = request_seq(&line).unwrap_or(0);
                let _ = conn.send_err(seq, ErrorCode::Syntax, &e.to_string()).await;
                break;
            }
        };
        // Handle the request while watching for EOF so that a vanished client stops motion.
        let outcome = tokio::select! {
            o = conn.handle(req.seq, req.request) => o,
            _ = eof_watch(&mut rd) => Outcome::Close,
            _ = stopped(&mut stop) => Outcome::Close,
        };
        if matches!(outcome, Outcome::Close) {
            break;
        }
    }
    backend.stop();
    monitor.abort();
    let mut w = conn.writer.lock().await;
    let _ = tokio::time::timeout(Duration::from_millis(200), w.shutdown()).await;
}

/// Resolves once `stop` holds `true`; never resolves if its sender is gone.
async fn stopped(stop: &mut watch::Receiver<bool>) {
    loop {
        if *stop.borrow_and_update() {
            return;
        }
        if stop.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// Resolves when the peer closes (EOF or error); stays pending if the peer sends data early.
async fn eof_watch<R: tokio::io::AsyncBufRead + Unpin>(rd: &mut R) {
    match rd.fill_buf().await {
        Ok([]) | Err(_) => {}
        Ok(_) => std::future::pending::<()>().await,
    }
}

async fn monitor_task<W: AsyncWrite + Send + Unpin>(
    writer: SharedWriter<W>,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    power_cmd_off: Arc<AtomicBool>,
) {
    let mut was_estop = backend.estop() || lock_faults(&faults).estop_latched;
    let mut was_power = backend.power();
    loop {
        tokio::time::sleep(MONITOR_PERIOD).await;
        let estop = backend.estop() || lock_faults(&faults).estop_latched;
        let power = backend.power();
        let ev = if estop && !was_estop {
            Some(Event {
                name: EventName::EStop,
                data: "emergency stop active".into(),
            })
        } else if was_power && !power && !estop && !power_cmd_off.load(Ordering::SeqCst) {
            Some(Event {
                name: EventName::PowerLost,
                data: "arm power dropped".into(),
            })
        } else {
            None
        };
        was_estop = estop;
        was_power = power;
        if let Some(ev) = ev {
            let line = format_event(&ev);
            let mut w = writer.lock().await;
            let r = tokio::time::timeout(WRITE_TIMEOUT, async {
                w.write_all(line.as_bytes()).await?;
                w.flush().await
            })
            .await;
            if !matches!(r, Ok(Ok(()))) {
                return;
            }
        }
    }
}

enum Outcome {
    Continue,
    Close,
}

enum Answer {
    Ok(Vec<String>),
    Err(ErrorCode, String),
}

impl From<BackendError> for Answer {
    fn from(e: BackendError) -> Self {
        Answer::Err(e.code, e.text)
    }
}

impl<W: AsyncWrite + Send + Unpin + 'static> Conn<W> {
    fn estop(&self) -> bool {
        self.backend.estop() || lock_faults(&self.faults).estop_latched
    }

    fn readback(&self) -> [f64; 6] {
        let mut j = self.backend.joints_deg();
        let f = lock_faults(&self.faults);
        for (v, o) in j.iter_mut().zip(f.joint_offset_deg) {
            *v += o;
        }
        match &f.joint_hook {
            Some(h) => h(j),
            None => j,
        }
    }

    async fn handle(&mut self, seq: u32, req: Request) -> Outcome {
        let numeric = matches!(req, Request::Joints | Request::Pose | Request::Wait { .. });
        let is_move = matches!(req, Request::MoveJ { .. });
        let answer = self.execute(req).await;
        let accepted_move = is_move && matches!(answer, Answer::Ok(_));
        let sent = match answer {
            Answer::Ok(data) => self.send(seq, ReplyBody::Ok(data), numeric).await,
            Answer::Err(code, text) => self.send(seq, ReplyBody::Err { code, text }, false).await,
        };
        if sent.is_err() {
            return Outcome::Close;
        }
        if accepted_move && take(&mut lock_faults(&self.faults).disconnect_during_move) {
            info!("fault: dropping connection during move");
            return Outcome::Close;
        }
        Outcome::Continue
    }

    async fn execute(&mut self, req: Request) -> Answer {
        match req {
            Request::Hello { proto_ver } => {
                if proto_ver != PROTO_VERSION {
                    return Answer::Err(
                        ErrorCode::Args,
                        format!("unsupported protocol version {proto_ver}, server speaks {PROTO_VERSION}"),
                    );
                }
                Answer::Ok(codec::format_identity(&self.backend.identity()))
            }
            Request::Ping => Answer::Ok(vec![]),
            Request::State => {
                let settled = self.backend.is_settled() && !self.never_settle;
                Answer::Ok(codec::format_state(&RobotState {
                    power: self.backend.power(),
                    mode: self.backend.mode(),
                    estop: self.estop(),
                    moving: self.backend.is_moving(),
                    settled,
                }))
            }
            Request::Power(on) => {
                if on && self.estop() {
                    return Answer::Err(ErrorCode::EStop, "emergency stop active".into());
                }
                if !on {
                    self.power_cmd_off.store(true, Ordering::SeqCst);
                    self.backend.stop();
                }
                match self.backend.set_power(on) {
                    Ok(()) => {
                        if on {
                            self.power_cmd_off.store(false, Ordering::SeqCst);
                        }
                        Answer::Ok(vec![])
                    }
                    Err(e) => e.into(),
                }
            }
            Request::Speed { pct } => {
                if !(pct > 0.0 && pct <= 100.0) {
                    return Answer::Err(ErrorCode::Args, format!("speed {pct} not in (0, 100]"));
                }
                self.speed_pct = pct;
                Answer::Ok(vec![])
            }
            Request::MoveJ {
                joints_deg,
                vel_pct,
            } => self.movej(joints_deg, vel_pct),
            Request::Wait { timeout_ms } => self.wait(timeout_ms.min(MAX_WAIT_MS)).await,
            Request::Joints => Answer::Ok(codec::format_joints(&self.readback())),
            Request::Pose => match self.backend.pose() {
                Ok(p) => Answer::Ok(codec::format_pose(&p)),
                Err(e) => e.into(),
            },
            Request::Stop => {
                self.backend.stop();
                self.never_settle = false;
                self.extra_settle = Duration::ZERO;
                Answer::Ok(vec![])
            }
        }
    }

    fn movej(&mut self, joints_deg: [f64; 6], vel_pct: Option<f64>) -> Answer {
        let vel = vel_pct.unwrap_or(100.0);
        if !(vel > 0.0 && vel <= 100.0) {
            return Answer::Err(ErrorCode::Args, format!("velocity {vel} not in (0, 100]"));
        }
        if self.estop() {
            return Answer::Err(ErrorCode::EStop, "emergency stop active".into());
        }
        if !self.backend.remote_ok() {
            return Answer::Err(ErrorCode::Mode, "controller not in remote mode".into());
        }
        if !self.backend.power() {
            return Answer::Err(ErrorCode::Power, "arm power is off".into());
        }
        if self.backend.is_moving() {
            return Answer::Err(ErrorCode::Busy, "a motion is in progress".into());
        }
        {
            let mut f = lock_faults(&self.faults);
            if take(&mut f.reject_movej) {
                let code = f.reject_code.clone();
                return Answer::Err(code, "injected fault".into());
            }
        }
        if let Err(e) = self.backend.check_target(&joints_deg) {
            return e.into();
        }
        if let Err(e) = self
            .backend
            .start_move(joints_deg, vel * self.speed_pct / 100.0)
        {
            return e.into();
        }
        let mut f = lock_faults(&self.faults);
        self.never_settle = take(&mut f.never_settle);
        self.extra_settle = if take(&mut f.slow_settle) {
            f.slow_settle_extra
        } else {
            Duration::ZERO
        };
        if take(&mut f.estop_during_move) {
            let delay = f.estop_delay;
            let faults = self.faults.clone();
            let backend = self.backend.clone();
            tokio::spawn(async move {
                tokio::time::sleep(delay).await;
                backend.stop();
                lock_faults(&faults).estop_latched = true;
                info!("fault: E-stop injected");
            });
        }
        Answer::Ok(vec![])
    }

    async fn wait(&mut self, timeout_ms: u64) -> Answer {
        let deadline = Instant::now() + Duration::from_millis(timeout_ms);
        let mut settled_since: Option<Instant> = None;
        loop {
            if self.estop() {
                return Answer::Err(ErrorCode::EStop, "emergency stop during motion".into());
            }
            if !self.backend.power() {
                return Answer::Err(ErrorCode::Power, "arm power lost during motion".into());
            }
            let settled =
                !self.never_settle && self.backend.is_settled() && !self.backend.is_moving();
            if settled {
                let since = *settled_since.get_or_insert_with(Instant::now);
                if since.elapsed() >= self.extra_settle {
                    return Answer::Ok(codec::format_joints(&self.readback()));
                }
            } else {
                settled_since = None;
            }
            if Instant::now() >= deadline {
                return Answer::Err(
                    ErrorCode::Timeout,
                    format!("not settled after {timeout_ms} ms"),
                );
            }
            tokio::time::sleep(POLL).await;
        }
    }

    async fn send_err(&mut self, seq: u32, code: ErrorCode, text: &str) -> std::io::Result<()> {
        self.send(
            seq,
            ReplyBody::Err {
                code,
                text: text.to_string(),
            },
            false,
        )
        .await
    }

    async fn send(&mut self, seq: u32, body: ReplyBody, numeric: bool) -> std::io::Result<()> {
        let (delay, split, extra, wrong, nonnum) = {
            let mut f = lock_faults(&self.faults);
            let delay = take(&mut f.delay_reply).then_some(f.reply_delay);
            let split = take(&mut f.split_reply);
            let extra = take(&mut f.extra_line).then(|| f.extra_line_text.clone());
            let wrong = take(&mut f.wrong_seq);
            let has_data = matches!(&body, ReplyBody::Ok(d) if d.len() >= 2);
            let nonnum = numeric && has_data && take(&mut f.non_numeric);
            (delay, split, extra, wrong, nonnum)
        };
        if let Some(d) = delay {
            tokio::time::sleep(d).await;
        }
        let mut body = body;
        if nonnum {
            if let ReplyBody::Ok(d) = &mut body {
                d[1] = "abc".into();
            }
        }
        let seq = if wrong { (seq + 1000) % 1_000_000 } else { seq };
        let mut out = String::new();
        if let Some(x) = extra {
            out.push_str(&x);
            out.push('\n');
        }
        out.push_str(&format_reply(&Reply { seq, body }));
        let mut w = self.writer.lock().await;
        let write = async {
            if split {
                for chunk in out.as_bytes().chunks(3) {
                    w.write_all(chunk).await?;
                    w.flush().await?;
                    tokio::time::sleep(Duration::from_millis(1)).await;
                }
            } else {
                w.write_all(out.as_bytes()).await?;
            }
            w.flush().await
        };
        tokio::time::timeout(WRITE_TIMEOUT, write)
            .await
            .unwrap_or_else(|_| Err(std::io::ErrorKind::TimedOut.into()))
    }
}
