//! Protocol server over a [`RobotBackend`], with deterministic fault injection.
//!
//! The server owns the protocol (framing, sequencing, access, the one-client rule, `WAIT`
//! polling, events); the backend owns the physics. A client whose address is not on the
//! [`ServerAccess`] allow-list, or a second client, receives `* EVT REFUSED …` and is closed at
//! once.
//!
//! Access (protocol v3, `PROTOCOL.md` §3a): until the client has proved with `HELLO 3` + `AUTH`
//! that it holds the shared secret, only `HELLO`, `AUTH` and `STOP` are answered; any other
//! request gets `E_AUTH` and the connection is closed, as after a wrong proof or
//! [`ServerAccess::auth_timeout`] without one. So nothing is powered or moved for a stranger.
//!
//! A session reads its socket all the time; the executing request runs in its own task. Once
//! authenticated, a `STOP` is handled at once (the backend stops, a running `WAIT` answers
//! `E_STOPPED`, then the `STOP` answers `OK`) and any other request meanwhile gets `E_BUSY`.
//! Before that, lines are handled strictly in order.

use std::collections::VecDeque;
use std::future::Future;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex as StdMutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::net::TcpListener;
use tokio::sync::{oneshot, watch, Mutex};
use tokio::task::JoinHandle;
use tracing::{debug, info, warn};

use crate::auth::{Nonce, Proof, SharedSecret};
use crate::codec::{
    self, format_event, format_reply, parse_request, request_seq, ErrorCode, Event, EventName,
    Identity, Pose, Reply, ReplyBody, Request, RobotState, MAX_LINE, PROTO_VERSION,
};
use lineio::{LineRead, LineReader};

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
    /// Highest protocol version `HELLO` accepts; below 3 the server answers `HELLO 3` as an
    /// older server would (`E_ARGS`). It never serves v1/v2 without authentication.
    pub max_proto_version: u32,
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
            max_proto_version: PROTO_VERSION,
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
            .field("max_proto_version", &self.max_proto_version)
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
/// Lines a peer may queue behind the executing request before the server closes (in-order
/// mode, before authentication).
const V1_BACKLOG_MAX: usize = 16;
/// The session's mode before authentication: requests strictly in order (v1 rules).
const IN_ORDER: u32 = 1;

/// Who may use a server: the shared secret every client must prove it holds, the client
/// addresses it accepts connections from, and how long a client has to authenticate.
#[derive(Debug, Clone)]
pub struct ServerAccess {
    /// The secret of `PROTOCOL.md` §3a.
    pub secret: SharedSecret,
    /// Client addresses accepted (IPv4-mapped IPv6 addresses count as IPv4); any other peer is
    /// refused before it can send a line.
    pub allow: Vec<IpAddr>,
    /// A connection that has not authenticated within this time is closed (it would otherwise
    /// hold the one-client slot).
    pub auth_timeout: Duration,
}

impl ServerAccess {
    /// Access for `secret` from the loopback addresses only, 5 s to authenticate.
    pub fn loopback(secret: SharedSecret) -> ServerAccess {
        ServerAccess {
            secret,
            allow: vec![
                IpAddr::V4(Ipv4Addr::LOCALHOST),
                IpAddr::V6(Ipv6Addr::LOCALHOST),
            ],
            auth_timeout: Duration::from_secs(5),
        }
    }

    /// Whether a client at `ip` may connect.
    pub fn allows(&self, ip: IpAddr) -> bool {
        let ip = ip.to_canonical();
        self.allow.iter().any(|a| a.to_canonical() == ip)
    }
}

/// Accept clients on `listener` until `shutdown` completes; one client at a time, and only
/// from the addresses `access` allows, each of which must authenticate (`PROTOCOL.md` §3a).
///
/// Cancel-safe in the sense that dropping it drops the listener and aborts the session tasks,
/// whose connections close (and whose sessions stop motion) when the tasks are dropped.
pub async fn serve(
    listener: TcpListener,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    access: ServerAccess,
    shutdown: impl Future<Output = ()>,
) -> std::io::Result<()> {
    let access = Arc::new(access);
    let (stop_tx, stop_rx) = watch::channel(false);
    let busy = Arc::new(AtomicBool::new(false));
    let mut tasks = tokio::task::JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            acc = listener.accept() => {
                let (stream, peer) = match acc {
                    Ok(x) => x,
                    Err(e) => {
                        warn!(error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let _ = stream.set_nodelay(true);
                if !access.allows(peer.ip()) {
                    warn!(%peer, "refusing a client whose address is not allowed");
                    tasks.spawn(refuse(stream, "address not allowed"));
                    continue;
                }
                tasks.spawn(session_or_refusal(
                    stream,
                    peer,
                    backend.clone(),
                    faults.clone(),
                    access.clone(),
                    busy.clone(),
                    stop_rx.clone(),
                ));
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

/// Serve `stream` if the one-client slot frees up within the grace period, else refuse it.
/// Cancel-safe: a drop ends the session as [`serve_connection`] does; the one-client flag stays
/// set, but it belongs to the [`serve`] call that dropped it.
async fn session_or_refusal(
    stream: tokio::net::TcpStream,
    peer: std::net::SocketAddr,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    access: Arc<ServerAccess>,
    busy: Arc<AtomicBool>,
    stop_rx: watch::Receiver<bool>,
) {
    if !claim_client_slot(&busy).await {
        info!(%peer, "refusing second client");
        refuse(stream, "another client is connected").await;
        return;
    }
    info!(%peer, "client connected");
    serve_connection(stream, backend, faults, access, stop_rx).await;
    busy.store(false, Ordering::SeqCst);
    info!(%peer, "client disconnected");
}

/// Send `* EVT REFUSED <why>` and close. Cancel-safe: a drop closes the connection anyway.
async fn refuse(mut stream: tokio::net::TcpStream, why: &str) {
    let line = format_event(&Event {
        name: EventName::Refused,
        data: why.into(),
    });
    let _ = tokio::time::timeout(WRITE_TIMEOUT, async {
        stream.write_all(line.as_bytes()).await?;
        stream.shutdown().await
    })
    .await;
}

/// Take the one-client slot, polling for up to [`REFUSE_GRACE`] while the previous session ends.
/// Not cancel-safe: a drop right after the swap leaves the one-client flag set; only dropped with
/// the whole [`serve`].
async fn claim_client_slot(busy: &AtomicBool) -> bool {
    for _ in 0..(REFUSE_GRACE.as_millis() / 10) {
        if !busy.swap(true, Ordering::SeqCst) {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    false
}

type SharedWriter<W> = Arc<Mutex<W>>;

/// The arm as the protocol sees it: backend plus injected faults.
#[derive(Clone)]
struct Arm {
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
}

impl Arm {
    /// E-stop from the hardware or the injected latch.
    fn estop(&self) -> bool {
        self.backend.estop() || lock_faults(&self.faults).estop_latched
    }

    /// Joints as reported on the wire: true joints plus injected offset and hook (degrees).
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
}

/// Writes whole reply lines (with reply faults applied) under the connection's writer lock.
struct Replier<W> {
    writer: SharedWriter<W>,
    faults: FaultHandle,
}

impl<W> Clone for Replier<W> {
    fn clone(&self) -> Self {
        Self {
            writer: self.writer.clone(),
            faults: self.faults.clone(),
        }
    }
}

/// Per-session protocol state (everything a request may change).
struct Conn<W> {
    out: Replier<W>,
    arm: Arm,
    /// 1 (requests strictly in order) until the client authenticated, then 3.
    version: u32,
    /// Who may use the server (the secret).
    access: Arc<ServerAccess>,
    /// The nonce of the last `HELLO 3`, until an `AUTH` spends it.
    challenge: Option<Nonce>,
    /// The client proved it holds the secret.
    authenticated: bool,
    speed_pct: f64,
    /// Set by the never_settle fault for the current move.
    never_settle: bool,
    /// Extra settle time for the current move (slow_settle fault).
    extra_settle: Duration,
    /// Power switched off on purpose (suppresses POWER_LOST).
    power_cmd_off: Arc<AtomicBool>,
}

/// Serve one client on any stream until it disconnects, sends a malformed line, fails to
/// authenticate (in `access.auth_timeout`), or `stop` flips. Motion is always stopped when this
/// returns. The address allow-list is [`serve`]'s: this serves whoever is on `stream`.
///
/// Cancel-safe: if the future is dropped the arm is stopped, the event monitor ends and the
/// connection closes, just as when it returns.
pub async fn serve_connection<S>(
    stream: S,
    backend: Arc<dyn RobotBackend>,
    faults: FaultHandle,
    access: Arc<ServerAccess>,
    mut stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Send + 'static,
{
    let (rd, wr) = tokio::io::split(stream);
    let mut lines = LineReader::new(BufReader::new(rd), MAX_LINE);
    let writer = Arc::new(Mutex::new(wr));
    let power_cmd_off = Arc::new(AtomicBool::new(!backend.power()));
    let monitor = tokio::spawn(monitor_task(
        writer.clone(),
        backend.clone(),
        faults.clone(),
        power_cmd_off.clone(),
    ));
    let mut ending = SessionEnd {
        backend: Some(backend.clone()),
        monitor,
    };
    let mut session = Session {
        conn: Conn {
            out: Replier {
                writer: writer.clone(),
                faults: faults.clone(),
            },
            arm: Arm {
                backend: backend.clone(),
                faults,
            },
            version: IN_ORDER,
            access,
            challenge: None,
            authenticated: false,
            speed_pct: 100.0,
            never_settle: false,
            extra_settle: Duration::ZERO,
            power_cmd_off,
        },
        inflight: None,
        backlog: VecDeque::new(),
    };
    session.run(&mut lines, &mut stop).await;
    drop(session);
    ending.now();
    let mut w = writer.lock().await;
    let _ = tokio::time::timeout(Duration::from_millis(200), w.shutdown()).await;
}

/// What ends a session however it ends, returned or dropped: the arm stops and the event
/// monitor (which shares the write half, so would keep the connection open) is aborted.
struct SessionEnd {
    /// `None` once the arm has been stopped.
    backend: Option<Arc<dyn RobotBackend>>,
    monitor: JoinHandle<()>,
}

impl SessionEnd {
    /// Stop the arm and the monitor now, once (dropping it later does nothing more).
    fn now(&mut self) {
        if let Some(backend) = self.backend.take() {
            backend.stop();
        }
        self.monitor.abort();
    }
}

impl Drop for SessionEnd {
    fn drop(&mut self) {
        self.now();
    }
}

/// Resolves once `stop` holds `true`; never resolves if its sender is gone. Cancel-safe.
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

/// Cancel-safe: it is aborted by the session's end; an event line is written whole under the writer
/// lock, and an abort mid-line closes that connection anyway.
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

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
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

/// What executing a request yields: an answer now, or a `WAIT` still to run.
enum Step {
    Done(Answer),
    Wait(WaitJob),
}

/// A running request: the future executes what is left of it and writes its reply.
struct InFlight {
    /// Ends a running `WAIT` with `E_STOPPED` (v2 out-of-band `STOP`).
    cancel: Option<oneshot::Sender<()>>,
    /// Set just before the reply is written: from then on the peer may send its next request,
    /// which must wait for this one to finish rather than get `E_BUSY`.
    replying: Arc<AtomicBool>,
    /// Its own task, so that it progresses (and releases the writer lock) while the session
    /// loop awaits something else.
    task: JoinHandle<Outcome>,
}

impl InFlight {
    /// Wait for the request to finish. Cancel-safe.
    async fn finished(&mut self) -> Outcome {
        (&mut self.task).await.unwrap_or(Outcome::Close)
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Resolves when the in-flight request has replied; pending when none runs. Cancel-safe.
async fn in_flight_done(inflight: &mut Option<InFlight>) -> Outcome {
    match inflight {
        Some(f) => f.finished().await,
        None => std::future::pending().await,
    }
}

/// One client session: reads the socket all the time, one request executing at a time.
struct Session<W> {
    conn: Conn<W>,
    inflight: Option<InFlight>,
    /// v1: lines that arrived while a request executed, handled in order afterwards.
    backlog: VecDeque<String>,
}

enum Input {
    Read(std::io::Result<LineRead>),
    Done(Outcome),
    Shutdown,
    AuthTimeout,
}

impl<W: AsyncWrite + Send + Unpin + 'static> Session<W> {
    /// Run until the peer leaves, sends a malformed line, a write fails or `stop` flips.
    /// Cancel-safe as part of [`serve_connection`]: dropping it drops the in-flight request task
    /// (aborted) and the session ends.
    async fn run<R>(&mut self, lines: &mut LineReader<R>, stop: &mut watch::Receiver<bool>)
    where
        R: tokio::io::AsyncBufRead + Unpin,
    {
        let auth_deadline = tokio::time::Instant::now() + self.conn.access.auth_timeout;
        loop {
            if self.inflight.is_none() {
                if let Some(line) = self.backlog.pop_front() {
                    if self.on_line(line).await == Outcome::Close {
                        return;
                    }
                    continue;
                }
            }
            // The socket is read while a request executes: a v2 STOP or a vanished peer is
            // seen at once (all three futures are cancel-safe).
            let input = tokio::select! {
                r = lines.next_line() => Input::Read(r),
                o = in_flight_done(&mut self.inflight) => Input::Done(o),
                _ = stopped(stop) => Input::Shutdown,
                _ = tokio::time::sleep_until(auth_deadline), if !self.conn.authenticated => {
                    Input::AuthTimeout
                }
            };
            let outcome = match input {
                Input::Read(Ok(LineRead::Line(l))) => self.on_line(l).await,
                Input::Read(Ok(LineRead::Bad(why))) => {
                    let _ = self.conn.out.error(0, ErrorCode::Syntax, &why).await;
                    Outcome::Close
                }
                Input::Read(Ok(LineRead::Eof)) | Input::Shutdown => Outcome::Close,
                Input::Read(Err(e)) => {
                    debug!(error = %e, "read failed");
                    Outcome::Close
                }
                Input::Done(o) => {
                    self.inflight = None;
                    o
                }
                Input::AuthTimeout => {
                    warn!("robotlink: client did not authenticate in time; closing");
                    self.conn
                        .out
                        .event(EventName::Refused, "authentication timeout")
                        .await;
                    Outcome::Close
                }
            };
            if outcome == Outcome::Close {
                return;
            }
        }
    }

    /// Handle one received line according to the negotiated version.
    /// Not cancel-safe: a drop mid-reply leaves half a line; only dropped with the session, which
    /// closes the connection.
    async fn on_line(&mut self, line: String) -> Outcome {
        if self.inflight.is_some() && self.conn.version < 2 {
            // v1: strictly in order; the line waits for the executing request.
            if self.backlog.len() >= V1_BACKLOG_MAX {
                warn!("v1 peer queued too many requests; closing");
                return Outcome::Close;
            }
            self.backlog.push_back(line);
            return Outcome::Continue;
        }
        let req = match parse_request(&line) {
            Ok(r) => r,
            Err(e) => return self.reject_line(&line, e).await,
        };
        if !self.conn.authenticated
            && !matches!(
                req.request,
                Request::Hello { .. } | Request::Auth { .. } | Request::Stop
            )
        {
            warn!(
                verb = req.request.verb(),
                "robotlink: request before authentication; closing"
            );
            let text = format!(
                "{} refused: not authenticated; a robotlink v3 client sends HELLO 3 and AUTH \
                 with a proof of the shared secret first",
                req.request.verb()
            );
            let _ = self.conn.out.error(req.seq, ErrorCode::Auth, &text).await;
            return Outcome::Close;
        }
        if self.finish_replying().await == Outcome::Close {
            return Outcome::Close;
        }
        if self.inflight.is_none() {
            self.inflight = Some(self.conn.start(req.seq, req.request));
            return Outcome::Continue;
        }
        if matches!(req.request, Request::Stop) {
            return self.stop_out_of_band(req.seq).await;
        }
        let text = format!(
            "{} not accepted: another request is executing",
            req.request.verb()
        );
        self.conn
            .out
            .reply(req.seq, Answer::Err(ErrorCode::Busy, text), false)
            .await
    }

    /// If the executing request has started writing its reply, let it finish (the peer may
    /// legitimately send its next request as soon as it has read that reply).
    /// Cancel-safe: it only awaits the in-flight task, which a drop aborts with the session.
    async fn finish_replying(&mut self) -> Outcome {
        match self.inflight.take_if(|f| f.replying.load(Ordering::SeqCst)) {
            Some(mut f) => f.finished().await,
            None => Outcome::Continue,
        }
    }

    /// `E_ARGS` (connection stays) or `E_SYNTAX` (connection closes) for an unparseable line.
    /// Not cancel-safe: a drop mid-reply leaves half a line; only dropped with the session, which
    /// closes the connection.
    async fn reject_line(&mut self, line: &str, e: codec::CodecError) -> Outcome {
        let seq = request_seq(line).unwrap_or(0);
        if e.is_args_error() {
            self.conn
                .out
                .reply(seq, Answer::Err(ErrorCode::Args, e.to_string()), false)
                .await
        } else {
            let _ = self
                .conn
                .out
                .error(seq, ErrorCode::Syntax, &e.to_string())
                .await;
            Outcome::Close
        }
    }

    /// v2 `STOP` while a request executes: halt the arm now, let the executing request answer
    /// (a `WAIT` with `E_STOPPED`), then answer the `STOP`.
    /// Not cancel-safe: a drop after the halt leaves the `STOP` unanswered; only dropped with the
    /// session, which closes the connection (and stops the arm).
    async fn stop_out_of_band(&mut self, seq: u32) -> Outcome {
        self.conn.halt();
        if let Some(mut f) = self.inflight.take() {
            if let Some(c) = f.cancel.take() {
                let _ = c.send(());
            }
            if f.finished().await == Outcome::Close {
                return Outcome::Close;
            }
        }
        self.conn.out.reply(seq, Answer::Ok(vec![]), false).await
    }
}

impl<W: AsyncWrite + Send + Unpin + 'static> Conn<W> {
    /// Stop motion and clear the per-move settle faults.
    fn halt(&mut self) {
        self.arm.backend.stop();
        self.never_settle = false;
        self.extra_settle = Duration::ZERO;
    }

    /// Execute `req` and return the future that finishes it and writes its reply.
    fn start(&mut self, seq: u32, req: Request) -> InFlight {
        let numeric = matches!(req, Request::Joints | Request::Pose | Request::Wait { .. });
        let is_move = matches!(req, Request::MoveJ { .. });
        let step = self.execute(req);
        // A failed authentication ends the session right after its reply.
        let fatal = matches!(&step, Step::Done(Answer::Err(ErrorCode::Auth, _)));
        let (cancel_tx, cancel_rx) = oneshot::channel();
        let replying = Arc::new(AtomicBool::new(false));
        let out = self.out.clone();
        let faults = self.arm.faults.clone();
        let flag = replying.clone();
        let fut = async move {
            let answer = match step {
                Step::Done(a) => a,
                Step::Wait(job) => job.run(cancel_rx).await,
            };
            let accepted_move = is_move && matches!(answer, Answer::Ok(_));
            if out.reply_marking(seq, answer, numeric, &flag).await == Outcome::Close || fatal {
                return Outcome::Close;
            }
            if accepted_move && take(&mut lock_faults(&faults).disconnect_during_move) {
                info!("fault: dropping connection during move");
                return Outcome::Close;
            }
            Outcome::Continue
        };
        InFlight {
            cancel: Some(cancel_tx),
            replying,
            task: tokio::spawn(fut),
        }
    }

    fn execute(&mut self, req: Request) -> Step {
        Step::Done(match req {
            Request::Hello { proto_ver } => self.hello(proto_ver),
            Request::Auth {
                client_nonce,
                proof,
            } => self.auth(client_nonce, proof),
            Request::Ping => Answer::Ok(vec![]),
            Request::State => self.state(),
            Request::Power(on) => self.power(on),
            Request::Speed { pct } => self.speed(pct),
            Request::MoveJ {
                joints_deg,
                vel_pct,
            } => self.movej(joints_deg, vel_pct),
            Request::Wait { timeout_ms } => {
                return Step::Wait(WaitJob {
                    arm: self.arm.clone(),
                    never_settle: self.never_settle,
                    extra_settle: self.extra_settle,
                    timeout_ms: timeout_ms.min(MAX_WAIT_MS),
                })
            }
            Request::Joints => Answer::Ok(codec::format_joints(&self.arm.readback())),
            Request::Pose => match self.arm.backend.pose() {
                Ok(p) => Answer::Ok(codec::format_pose(&p)),
                Err(e) => e.into(),
            },
            Request::Stop => {
                self.halt();
                Answer::Ok(vec![])
            }
        })
    }

    /// `HELLO 3`: a fresh server nonce (the challenge of `AUTH`). Older versions are refused
    /// with a text that tells the operator what to do; so is a second `HELLO` once authenticated.
    fn hello(&mut self, proto_ver: u32) -> Answer {
        let max = lock_faults(&self.arm.faults).max_proto_version;
        if proto_ver == PROTO_VERSION && max < PROTO_VERSION {
            // fault: answer as a server of an older protocol version would
            let text = format!("unsupported protocol version {proto_ver}, server speaks 1..{max}");
            return Answer::Err(ErrorCode::Args, text);
        }
        if proto_ver != PROTO_VERSION {
            return Answer::Err(
                ErrorCode::Args,
                format!(
                    "unsupported protocol version {proto_ver}: this server speaks only robotlink \
                     v{PROTO_VERSION} (authenticated); v1 and v2 let anyone who reaches the port \
                     move the arm. Update cellcal on the host and give it this controller's \
                     shared secret ([robot_controller] secret_file)"
                ),
            );
        }
        if self.authenticated {
            return Answer::Err(ErrorCode::Args, "already authenticated".into());
        }
        match Nonce::generate() {
            Ok(n) => {
                self.challenge = Some(n);
                Answer::Ok(vec![n.to_hex()])
            }
            Err(e) => Answer::Err(ErrorCode::Auth, e.to_string()),
        }
    }

    /// `AUTH`: check the client's proof against the nonce of the last `HELLO 3` (spent either
    /// way); on success the session is authenticated (v3 rules) and the reply carries the
    /// identity and the server's own proof. Any failure is `E_AUTH` (the session then closes).
    fn auth(&mut self, client_nonce: Nonce, proof: Proof) -> Answer {
        if self.authenticated {
            return Answer::Err(ErrorCode::Args, "already authenticated".into());
        }
        let Some(server_nonce) = self.challenge.take() else {
            return Answer::Err(ErrorCode::Auth, "AUTH without a HELLO 3 challenge".into());
        };
        let secret = &self.access.secret;
        if !secret.verify_client(&server_nonce, &client_nonce, &proof) {
            warn!("robotlink: authentication failed (wrong proof); closing");
            return Answer::Err(
                ErrorCode::Auth,
                "authentication failed: the client does not hold this controller's shared secret"
                    .into(),
            );
        }
        self.authenticated = true;
        self.version = PROTO_VERSION;
        info!("robotlink: client authenticated");
        let mut data = codec::format_identity(&self.arm.backend.identity());
        data.push(secret.server_proof(&server_nonce, &client_nonce).to_hex());
        Answer::Ok(data)
    }

    fn state(&self) -> Answer {
        let b = &self.arm.backend;
        Answer::Ok(codec::format_state(&RobotState {
            power: b.power(),
            mode: b.mode(),
            estop: self.arm.estop(),
            moving: b.is_moving(),
            settled: b.is_settled() && !self.never_settle,
        }))
    }

    fn power(&mut self, on: bool) -> Answer {
        if on && self.arm.estop() {
            return Answer::Err(ErrorCode::EStop, "emergency stop active".into());
        }
        if !on {
            self.power_cmd_off.store(true, Ordering::SeqCst);
            self.arm.backend.stop();
        }
        match self.arm.backend.set_power(on) {
            Ok(()) => {
                if on {
                    self.power_cmd_off.store(false, Ordering::SeqCst);
                }
                Answer::Ok(vec![])
            }
            Err(e) => e.into(),
        }
    }

    fn speed(&mut self, pct: f64) -> Answer {
        if !(pct > 0.0 && pct <= 100.0) {
            return Answer::Err(ErrorCode::Args, format!("speed {pct} not in (0, 100]"));
        }
        self.speed_pct = pct;
        Answer::Ok(vec![])
    }

    /// `MOVEJ` checks in the order PROTOCOL.md §3 gives, then starts the move.
    fn movej(&mut self, joints_deg: [f64; 6], vel_pct: Option<f64>) -> Answer {
        let vel = vel_pct.unwrap_or(100.0);
        if let Err(a) = self.movej_refusal(&joints_deg, vel) {
            return a;
        }
        let backend = &self.arm.backend;
        if let Err(e) = backend.start_move(joints_deg, vel * self.speed_pct / 100.0) {
            return e.into();
        }
        self.arm_move_faults();
        Answer::Ok(vec![])
    }

    /// The first reason to refuse a `MOVEJ`, if any.
    fn movej_refusal(&self, joints_deg: &[f64; 6], vel: f64) -> Result<(), Answer> {
        let b = &self.arm.backend;
        let refuse = |code, text: &str| Err(Answer::Err(code, text.to_string()));
        if !(vel > 0.0 && vel <= 100.0) {
            return refuse(ErrorCode::Args, &format!("velocity {vel} not in (0, 100]"));
        }
        if self.arm.estop() {
            return refuse(ErrorCode::EStop, "emergency stop active");
        }
        if !b.remote_ok() {
            return refuse(ErrorCode::Mode, "controller not in remote mode");
        }
        if !b.power() {
            return refuse(ErrorCode::Power, "arm power is off");
        }
        if b.is_moving() {
            return refuse(ErrorCode::Busy, "a motion is in progress");
        }
        {
            let mut f = lock_faults(&self.arm.faults);
            if take(&mut f.reject_movej) {
                let code = f.reject_code.clone();
                return refuse(code, "injected fault");
            }
        }
        b.check_target(joints_deg).map_err(Answer::from)
    }

    /// Apply the per-move faults (never/slow settle, delayed E-stop) to the move just started.
    fn arm_move_faults(&mut self) {
        let mut f = lock_faults(&self.arm.faults);
        self.never_settle = take(&mut f.never_settle);
        self.extra_settle = if take(&mut f.slow_settle) {
            f.slow_settle_extra
        } else {
            Duration::ZERO
        };
        if take(&mut f.estop_during_move) {
            let delay = f.estop_delay;
            let arm = self.arm.clone();
            tokio::spawn(async move {
                tokio::time::sleep(delay).await;
                arm.backend.stop();
                lock_faults(&arm.faults).estop_latched = true;
                info!("fault: E-stop injected");
            });
        }
    }
}

/// A `WAIT` being executed: polls the arm until settled, E-stop, power loss, timeout or STOP.
struct WaitJob {
    arm: Arm,
    never_settle: bool,
    extra_settle: Duration,
    timeout_ms: u64,
}

impl WaitJob {
    /// Poll every [`POLL`]; `cancel` firing (or its sender going away) ends it with `E_STOPPED`.
    /// Cancel-safe: it only polls the arm, so a drop just stops watching it.
    async fn run(self, mut cancel: oneshot::Receiver<()>) -> Answer {
        let deadline = Instant::now() + Duration::from_millis(self.timeout_ms);
        let mut settled_since: Option<Instant> = None;
        loop {
            if let Some(a) = self.fault_answer() {
                return a;
            }
            if self.settled(&mut settled_since) {
                return Answer::Ok(codec::format_joints(&self.arm.readback()));
            }
            if Instant::now() >= deadline {
                let text = format!("not settled after {} ms", self.timeout_ms);
                return Answer::Err(ErrorCode::Timeout, text);
            }
            tokio::select! {
                _ = tokio::time::sleep(POLL) => {}
                _ = &mut cancel => {
                    return Answer::Err(ErrorCode::Stopped, "motion stopped by STOP".into());
                }
            }
        }
    }

    /// `E_ESTOP` / `E_POWER` when the arm lost its E-stop chain or power during the wait.
    fn fault_answer(&self) -> Option<Answer> {
        if self.arm.estop() {
            return Some(Answer::Err(
                ErrorCode::EStop,
                "emergency stop during motion".into(),
            ));
        }
        if !self.arm.backend.power() {
            return Some(Answer::Err(
                ErrorCode::Power,
                "arm power lost during motion".into(),
            ));
        }
        None
    }

    /// True once the arm has been settled for the extra settle time (slow_settle fault).
    fn settled(&self, since: &mut Option<Instant>) -> bool {
        let b = &self.arm.backend;
        if self.never_settle || !b.is_settled() || b.is_moving() {
            *since = None;
            return false;
        }
        since.get_or_insert_with(Instant::now).elapsed() >= self.extra_settle
    }
}

impl<W: AsyncWrite + Send + Unpin> Replier<W> {
    /// Write the reply to `seq`; [`Outcome::Close`] when the write failed.
    /// Not cancel-safe: a drop mid-write leaves half a line; only dropped with the session, which
    /// closes the connection.
    async fn reply(&self, seq: u32, answer: Answer, numeric: bool) -> Outcome {
        self.reply_marking(seq, answer, numeric, &AtomicBool::new(false))
            .await
    }

    /// [`Self::reply`], setting `replying` right before the first byte is written.
    /// Not cancel-safe: a drop mid-write leaves half a line; only dropped with the session, which
    /// closes the connection.
    async fn reply_marking(
        &self,
        seq: u32,
        answer: Answer,
        numeric: bool,
        replying: &AtomicBool,
    ) -> Outcome {
        let body = match answer {
            Answer::Ok(data) => ReplyBody::Ok(data),
            Answer::Err(code, text) => ReplyBody::Err { code, text },
        };
        match self.send(seq, body, numeric, replying).await {
            Ok(()) => Outcome::Continue,
            Err(_) => Outcome::Close,
        }
    }

    /// Write an event line (used right before closing). Not cancel-safe: a drop mid-write leaves
    /// half a line; it is only written right before closing.
    async fn event(&self, name: EventName, data: &str) {
        let line = format_event(&Event {
            name,
            data: data.into(),
        });
        let mut w = self.writer.lock().await;
        let _ = tokio::time::timeout(WRITE_TIMEOUT, async {
            w.write_all(line.as_bytes()).await?;
            w.flush().await
        })
        .await;
    }

    /// Write an error reply (used right before closing).
    /// Not cancel-safe: a drop mid-write leaves half a line; it is only written right before
    /// closing.
    async fn error(&self, seq: u32, code: ErrorCode, text: &str) -> std::io::Result<()> {
        let body = ReplyBody::Err {
            code,
            text: text.to_string(),
        };
        self.send(seq, body, false, &AtomicBool::new(false)).await
    }

    /// Write one reply line, applying the armed reply faults; the line is written whole under
    /// the writer lock so replies and events never interleave.
    /// Not cancel-safe: the one-shot reply faults are spent before the write and a drop mid-write
    /// leaves half a line; only dropped with the session, which closes the connection.
    async fn send(
        &self,
        seq: u32,
        body: ReplyBody,
        numeric: bool,
        replying: &AtomicBool,
    ) -> std::io::Result<()> {
        let faults = ReplyFaults::take(&self.faults, &body, numeric);
        if let Some(d) = faults.delay {
            tokio::time::sleep(d).await;
        }
        let out = faults.render(seq, body);
        let mut w = self.writer.lock().await;
        replying.store(true, Ordering::SeqCst);
        let write = async {
            if faults.split {
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

/// Reply faults taken (one-shot) for one reply.
struct ReplyFaults {
    delay: Option<Duration>,
    split: bool,
    extra: Option<String>,
    wrong_seq: bool,
    non_numeric: bool,
}

impl ReplyFaults {
    fn take(faults: &FaultHandle, body: &ReplyBody, numeric: bool) -> Self {
        let mut f = lock_faults(faults);
        let has_data = matches!(body, ReplyBody::Ok(d) if d.len() >= 2);
        Self {
            delay: take(&mut f.delay_reply).then_some(f.reply_delay),
            split: take(&mut f.split_reply),
            extra: take(&mut f.extra_line).then(|| f.extra_line_text.clone()),
            wrong_seq: take(&mut f.wrong_seq),
            non_numeric: numeric && has_data && take(&mut f.non_numeric),
        }
    }

    /// The bytes to send: optional extra line, then the (possibly corrupted) reply.
    fn render(&self, seq: u32, mut body: ReplyBody) -> String {
        if self.non_numeric {
            if let ReplyBody::Ok(d) = &mut body {
                d[1] = "abc".into();
            }
        }
        let seq = if self.wrong_seq {
            (seq + 1000) % 1_000_000
        } else {
            seq
        };
        let mut out = String::new();
        if let Some(x) = &self.extra {
            out.push_str(x);
            out.push('\n');
        }
        out.push_str(&format_reply(&Reply { seq, body }));
        out
    }
}
