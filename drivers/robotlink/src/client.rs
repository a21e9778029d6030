//! Async client: one connection, one outstanding normal request plus an out-of-band `STOP`
//! (protocol v2), replies matched by sequence number.
//!
//! Cancel-safety model: request lines go to a writer task whole, so a dropped request future
//! never leaves half a line on the wire. A request whose future was dropped (or that timed
//! out) keeps the normal slot until its late reply arrives and is dropped; the next normal
//! request waits for that reply for up to `request_timeout`, then gives the old sequence
//! number up (its reply is dropped whenever it comes) and goes ahead.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex as StdMutex};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::net::{TcpStream, ToSocketAddrs};
use tokio::sync::{broadcast, mpsc, oneshot, Mutex, Notify};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tracing::{debug, trace, warn};

use crate::auth::{Nonce, SharedSecret};
use crate::codec::{
    self, format_request, parse_server_line, CodecError, ErrorCode, Event, EventName, Identity,
    Pose, Reply, ReplyBody, Request, RobotState, ServerLine, MAX_LINE, MAX_SEQ, PROTO_VERSION,
};
use lineio::{LineRead, LineReader};

/// Typed error of the robot client.
#[derive(Debug, thiserror::Error)]
pub enum RobotError {
    /// The server rejected the request with an error code other than E_ESTOP/E_POWER/E_TIMEOUT.
    #[error("rejected by robot: {code} {text}")]
    Rejected {
        /// Parsed error code.
        code: ErrorCode,
        /// Server's text.
        text: String,
    },
    /// `WAIT` returned `E_TIMEOUT`: the arm did not settle within the server-side timeout.
    #[error("robot did not settle: {0}")]
    NotSettled(String),
    /// `E_STOPPED` (v2): the request was ended by a `STOP` (this client's or a [`StopHandle`]'s).
    #[error("motion stopped: {0}")]
    Stopped(String),
    /// No reply within the client-side timeout.
    #[error("timeout waiting for reply to {0}")]
    Timeout(&'static str),
    /// Emergency stop: `E_ESTOP` reply or `* EVT ESTOP` during a motion request.
    #[error("emergency stop: {0}")]
    EStop(String),
    /// Arm power off: `E_POWER` reply or `* EVT POWER_LOST` during a motion request.
    #[error("arm power off: {0}")]
    PowerOff(String),
    /// The server violated the protocol (bad line, wrong sequence number, bad data field).
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The connection is closed; reconnect to continue.
    #[error("disconnected")]
    Disconnected,
    /// Authentication failed (`E_AUTH`, a wrong server proof, or no secret configured): the
    /// text says which side lacks the shared secret.
    #[error("robotlink authentication: {0}")]
    Auth(String),
    /// The server speaks an older protocol (no authentication); cellcal does not drive it.
    #[error(
        "the robot controller speaks an older robotlink protocol without authentication (it \
         answered HELLO {PROTO_VERSION} with: {0}); cellcal refuses to drive it: install the \
         controller application of this cellcal version (deploy/staubli) with the cell's shared \
         secret"
    )]
    OldServer(String),
    /// Transport error while connecting.
    #[error("i/o error: {0}")]
    Io(std::io::Error),
}

/// The message prints the I/O error, so it is not also the `source()` (printed with its
/// causes, it would appear twice).
impl From<std::io::Error> for RobotError {
    fn from(cause: std::io::Error) -> Self {
        RobotError::Io(cause)
    }
}

impl RobotError {
    fn from_reply(code: ErrorCode, text: String) -> Self {
        match code {
            ErrorCode::EStop => RobotError::EStop(text),
            ErrorCode::Power => RobotError::PowerOff(text),
            ErrorCode::Timeout => RobotError::NotSettled(text),
            ErrorCode::Stopped => RobotError::Stopped(text),
            ErrorCode::Auth => RobotError::Auth(text),
            code => RobotError::Rejected { code, text },
        }
    }

    fn from_codec(ctx: &str, e: CodecError) -> Self {
        RobotError::Protocol(format!("{ctx}: {e}"))
    }
}

/// Client timeouts, buffer sizes and the shared secret.
#[derive(Debug, Clone)]
pub struct ClientConfig {
    /// The secret shared with the controller (`PROTOCOL.md` §3a); without it `hello` fails.
    pub secret: Option<SharedSecret>,
    /// TCP connect timeout.
    pub connect_timeout: Duration,
    /// Reply timeout for every request except `WAIT`.
    pub request_timeout: Duration,
    /// Extra client-side time granted to `WAIT` beyond its server-side timeout.
    pub wait_margin: Duration,
    /// Capacity of the event broadcast channel.
    pub event_capacity: usize,
}

impl Default for ClientConfig {
    fn default() -> Self {
        Self {
            secret: None,
            connect_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(5),
            wait_margin: Duration::from_secs(2),
            event_capacity: 32,
        }
    }
}

type BoxWriter = Box<dyn AsyncWrite + Send + Unpin>;
type ReplyTx = oneshot::Sender<Result<Vec<String>, RobotError>>;
type ReplyRx = oneshot::Receiver<Result<Vec<String>, RobotError>>;

/// What the writer task is asked to do.
enum Out {
    /// Write one whole line.
    Line(String),
    /// Shut the write half down (the server then stops motion) and end.
    Close,
}

/// A request on the wire whose reply has not arrived yet.
struct Pending {
    seq: u32,
    verb: &'static str,
    /// `None` once the caller has been answered early (E-stop event) or has gone away.
    tx: Option<ReplyTx>,
}

/// Which reply slot a request occupies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slot {
    /// The one outstanding normal request.
    Normal,
    /// An out-of-band `STOP` (v2).
    Stop,
}

#[derive(Default)]
struct Shared {
    closed: bool,
    close_reason: Option<RobotError>,
    seq: u32,
    /// Version of the last successful handshake; `None` before one (the server then handles
    /// requests strictly in order, v1 rules).
    version: Option<u32>,
    normal: Option<Pending>,
    stop: Option<Pending>,
    /// Sequence numbers given up on (timeout); a late reply with one of them is dropped.
    stale: VecDeque<u32>,
}

impl Shared {
    fn mark_stale(&mut self, seq: u32) {
        if self.stale.len() >= 16 {
            self.stale.pop_front();
        }
        self.stale.push_back(seq);
    }

    fn next_seq(&mut self) -> u32 {
        self.seq = if self.seq >= MAX_SEQ { 1 } else { self.seq + 1 };
        self.seq
    }

    fn slot(&mut self, slot: Slot) -> &mut Option<Pending> {
        match slot {
            Slot::Normal => &mut self.normal,
            Slot::Stop => &mut self.stop,
        }
    }

    /// The error a call on a closed connection gets (the close reason once, then Disconnected).
    fn closed_error(&mut self) -> RobotError {
        self.close_reason.take().unwrap_or(RobotError::Disconnected)
    }

    /// Mark the connection closed and answer every waiting caller; `first` goes to the first.
    fn close_with(&mut self, first: RobotError) {
        self.closed = true;
        let mut first = Some(first);
        for p in [self.normal.take(), self.stop.take()].into_iter().flatten() {
            if let Some(tx) = p.tx {
                let e = first.take().unwrap_or(RobotError::Disconnected);
                let _ = tx.send(Err(e));
            }
        }
        if let Some(e) = first.filter(|e| !matches!(e, RobotError::Disconnected)) {
            self.close_reason = Some(e);
        }
    }
}

/// State shared by the client, its [`StopHandle`]s and its reader and writer tasks.
struct Link {
    shared: StdMutex<Shared>,
    out: mpsc::UnboundedSender<Out>,
    events: broadcast::Sender<Event>,
    /// Held by a normal request future from before sending until its reply (or its drop).
    gate: Mutex<()>,
    /// Serialises `STOP`s.
    stop_gate: Mutex<()>,
    /// Woken when the normal slot empties or the connection closes.
    slot_freed: Notify,
    request_timeout: Duration,
}

impl Link {
    fn lock(&self) -> std::sync::MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Mark closed, answer waiting callers and ask the writer to shut the socket down.
    fn close(&self, reason: RobotError) {
        self.lock().close_with(reason);
        self.slot_freed.notify_waiters();
        let _ = self.out.send(Out::Close);
    }

    /// Take a sequence number, occupy `slot` and queue the request line, all without an await:
    /// either the whole line goes out and the slot is taken, or neither happens.
    fn send(&self, slot: Slot, req: &Request) -> Result<(u32, ReplyRx), RobotError> {
        let mut sh = self.lock();
        if sh.closed {
            return Err(sh.closed_error());
        }
        let seq = sh.next_seq();
        let line = format_request(seq, req);
        trace!(line = line.trim_end(), "robotlink send");
        if self.out.send(Out::Line(line)).is_err() {
            sh.close_with(RobotError::Disconnected);
            return Err(RobotError::Disconnected);
        }
        let (tx, rx) = oneshot::channel();
        let verb = req.verb();
        // A request still in the slot was abandoned (its future dropped): drop its late reply.
        if let Some(old) = sh.slot(slot).take() {
            sh.mark_stale(old.seq);
        }
        *sh.slot(slot) = Some(Pending {
            seq,
            verb,
            tx: Some(tx),
        });
        Ok((seq, rx))
    }

    /// Await the reply to `seq`. Cancel-safe: dropping it leaves the request in its slot, so
    /// the late reply is recognised and dropped.
    async fn reply(
        &self,
        slot: Slot,
        seq: u32,
        rx: ReplyRx,
        timeout: Duration,
        verb: &'static str,
    ) -> Result<Vec<String>, RobotError> {
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(RobotError::Disconnected),
            Err(_) => {
                warn!(verb, seq, "robotlink reply timeout");
                if slot == Slot::Stop {
                    self.give_up(slot, seq);
                }
                Err(RobotError::Timeout(verb))
            }
        }
    }

    /// Stop waiting for `seq` in `slot`: its reply will be dropped whenever it comes.
    fn give_up(&self, slot: Slot, seq: u32) {
        let mut sh = self.lock();
        if sh.slot(slot).as_ref().map(|p| p.seq) == Some(seq) {
            *sh.slot(slot) = None;
            sh.mark_stale(seq);
        }
        drop(sh);
        self.slot_freed.notify_waiters();
    }

    /// Wait until no normal request is on the wire, for at most `budget`; then give the old
    /// one up. Cancel-safe (it only waits).
    async fn wait_normal_slot(&self, budget: Duration) -> Result<(), RobotError> {
        let deadline = Instant::now() + budget;
        loop {
            let freed = self.slot_freed.notified();
            tokio::pin!(freed);
            freed.as_mut().enable();
            let old = {
                let mut sh = self.lock();
                if sh.closed {
                    return Err(sh.closed_error());
                }
                match &sh.normal {
                    None => return Ok(()),
                    Some(p) => (p.seq, p.verb),
                }
            };
            if Instant::now() >= deadline {
                warn!(
                    seq = old.0,
                    verb = old.1,
                    "robotlink: no reply to abandoned request; giving it up"
                );
                self.give_up(Slot::Normal, old.0);
                return Ok(());
            }
            let _ = tokio::time::timeout_at(deadline, freed).await;
        }
    }

    /// One normal request: wait for the gate and the slot, send, await the reply.
    /// Cancel-safe (see the module doc): the line is queued whole without an await, and a dropped
    /// wait leaves the request in its slot so its late reply is dropped.
    async fn request(&self, req: Request, timeout: Duration) -> Result<Vec<String>, RobotError> {
        let _gate = self.gate.lock().await;
        self.wait_normal_slot(self.request_timeout).await?;
        let (seq, rx) = self.send(Slot::Normal, &req)?;
        self.reply(Slot::Normal, seq, rx, timeout, req.verb()).await
    }

    /// `STOP` by the negotiated version (see [`StopHandle::stop`]).
    /// Cancel-safe: a drop either sent nothing or sent the whole `STOP`, whose late reply is
    /// dropped.
    async fn stop(&self) -> Result<(), RobotError> {
        let _stop_gate = self.stop_gate.lock().await;
        let version = self.lock().version;
        if version.is_some_and(|v| v >= 2) {
            let (seq, rx) = self.send(Slot::Stop, &Request::Stop)?;
            return self
                .reply(Slot::Stop, seq, rx, self.request_timeout, "STOP")
                .await
                .map(drop);
        }
        // Not authenticated (in-order server): STOP waits its turn, so it is only sent when
        // nothing is outstanding.
        let idle = match self.gate.try_lock() {
            Ok(gate) => {
                let free = self.lock().normal.is_none();
                free.then_some(gate)
            }
            Err(_) => None,
        };
        match idle {
            Some(_gate) => {
                let (seq, rx) = self.send(Slot::Normal, &Request::Stop)?;
                self.reply(Slot::Normal, seq, rx, self.request_timeout, "STOP")
                    .await
                    .map(drop)
            }
            None => {
                warn!("robotlink: not authenticated and a request outstanding; stopping by closing the connection");
                self.close(RobotError::Disconnected);
                Ok(())
            }
        }
    }

    /// Route one reply to its slot; a reply nobody waits for is a protocol error.
    fn on_reply(&self, reply: Reply) -> Result<(), RobotError> {
        let mut sh = self.lock();
        let slot = [Slot::Normal, Slot::Stop]
            .into_iter()
            .find(|s| sh.slot(*s).as_ref().map(|p| p.seq) == Some(reply.seq));
        let Some(slot) = slot else {
            if let Some(pos) = sh.stale.iter().position(|s| *s == reply.seq) {
                sh.stale.remove(pos);
                debug!(seq = reply.seq, "dropping late reply to abandoned request");
                return Ok(());
            }
            let expected = sh.normal.as_ref().map(|p| p.seq);
            return Err(RobotError::Protocol(format!(
                "reply with unexpected sequence number {} (expected {:?})",
                reply.seq, expected
            )));
        };
        let p = sh.slot(slot).take().expect("slot found above");
        drop(sh);
        if slot == Slot::Normal {
            self.slot_freed.notify_waiters();
        }
        let r = match reply.body {
            ReplyBody::Ok(d) => Ok(d),
            ReplyBody::Err { code, text } => Err(RobotError::from_reply(code, text)),
        };
        match p.tx {
            Some(tx) if !tx.is_closed() => {
                let _ = tx.send(r);
            }
            _ => debug!(
                seq = p.seq,
                verb = p.verb,
                "dropping reply to abandoned request"
            ),
        }
        Ok(())
    }

    /// An E-stop or power-loss event fails an outstanding MOVEJ/WAIT at once; the request
    /// keeps its slot so that the server's own late reply is recognised.
    fn on_motion_event(&self, err: RobotError) {
        let mut sh = self.lock();
        if let Some(p) = sh.normal.as_mut() {
            if p.verb == "WAIT" || p.verb == "MOVEJ" {
                if let Some(tx) = p.tx.take() {
                    let _ = tx.send(Err(err));
                }
            }
        }
    }
}

/// Sends `STOP` from any task without borrowing the [`RobotClient`]; cheap to clone.
#[derive(Clone)]
pub struct StopHandle {
    link: Arc<Link>,
}

impl std::fmt::Debug for StopHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StopHandle").finish_non_exhaustive()
    }
}

impl StopHandle {
    /// Stop the arm now. v2: `STOP` goes out at once, even while a `WAIT` is outstanding (which
    /// then fails with [`RobotError::Stopped`]). No handshake yet: an in-order `STOP` when
    /// nothing is outstanding, else the connection is closed (the server stops motion on
    /// disconnect) and `Ok` is returned. Cancel-safe: a dropped call either sent nothing or
    /// sent the whole `STOP`, whose late reply is dropped.
    pub async fn stop(&self) -> Result<(), RobotError> {
        self.link.stop().await
    }
}

/// Async robotlink client. Methods take `&self`; normal requests are serialised internally and
/// `STOP` may overtake them (v2).
pub struct RobotClient {
    link: Arc<Link>,
    config: ClientConfig,
    reader: JoinHandle<()>,
}

impl std::fmt::Debug for RobotClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotClient")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Drop for RobotClient {
    fn drop(&mut self) {
        self.reader.abort();
        self.link.close(RobotError::Disconnected);
    }
}

impl RobotClient {
    /// Connect over TCP (with `connect_timeout`), disable Nagle and start the reader and
    /// writer tasks. Cancel-safe: dropping it before it returns leaves no connection behind.
    pub async fn connect<A: ToSocketAddrs>(
        addr: A,
        config: ClientConfig,
    ) -> Result<Self, RobotError> {
        let stream = tokio::time::timeout(config.connect_timeout, TcpStream::connect(addr))
            .await
            .map_err(|_| RobotError::Timeout("connect"))??;
        stream.set_nodelay(true)?;
        Ok(Self::from_stream(stream, config))
    }

    /// Wrap an already-connected stream (TCP, duplex pipe, ...). Must be called inside a runtime.
    pub fn from_stream<S>(stream: S, config: ClientConfig) -> Self
    where
        S: AsyncRead + AsyncWrite + Send + 'static,
    {
        let (rd, wr) = tokio::io::split(stream);
        let (out, out_rx) = mpsc::unbounded_channel();
        let (events, _) = broadcast::channel(config.event_capacity.max(1));
        let link = Arc::new(Link {
            shared: StdMutex::new(Shared::default()),
            out,
            events,
            gate: Mutex::new(()),
            stop_gate: Mutex::new(()),
            slot_freed: Notify::new(),
            request_timeout: config.request_timeout,
        });
        tokio::spawn(writer_task(Box::new(wr), out_rx, link.clone()));
        let reader = tokio::spawn(reader_task(
            LineReader::new(BufReader::new(rd), MAX_LINE),
            link.clone(),
        ));
        Self {
            link,
            config,
            reader,
        }
    }

    /// Subscribe to asynchronous `* EVT` lines.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.link.events.subscribe()
    }

    /// A handle that sends `STOP` from another task (see [`StopHandle::stop`]).
    pub fn stop_handle(&self) -> StopHandle {
        StopHandle {
            link: self.link.clone(),
        }
    }

    /// True once the connection is closed (every further call returns `Disconnected`).
    pub fn is_closed(&self) -> bool {
        self.link.lock().closed
    }

    /// Protocol version of the last successful [`Self::hello`] (always [`PROTO_VERSION`]);
    /// `None` before one.
    pub fn protocol_version(&self) -> Option<u32> {
        self.link.lock().version
    }

    /// Close the connection (the server then stops any motion). Not async work beyond queueing
    /// the shutdown for the writer task; cancel-safe.
    pub async fn close(&self) {
        self.link.close(RobotError::Disconnected);
        tokio::task::yield_now().await;
    }

    /// The v3 handshake: `HELLO 3` (the server's nonce), `AUTH` with this client's nonce and
    /// proof of the shared secret, then the server's proof checked (mutual authentication;
    /// `PROTOCOL.md` §3a). A server that does not prove it holds the secret is disconnected;
    /// an older server ([`RobotError::OldServer`]) is refused. Records the version
    /// ([`Self::protocol_version`]).
    /// Cancel-safe like every request (see the module doc); a call dropped midway leaves the
    /// connection unauthenticated (the server closes it after its authentication timeout).
    pub async fn hello(&self) -> Result<Identity, RobotError> {
        let secret = self.config.secret.as_ref().ok_or_else(|| {
            RobotError::Auth(
                "no shared secret configured: a robotlink v3 controller accepts only a client \
                 that proves it holds the controller's secret ([robot_controller] secret_file)"
                    .into(),
            )
        })?;
        let timeout = self.config.request_timeout;
        let hello = self
            .request(
                Request::Hello {
                    proto_ver: PROTO_VERSION,
                },
                timeout,
            )
            .await;
        let d = match hello {
            Err(RobotError::Rejected {
                code: ErrorCode::Args,
                text,
            }) => return Err(RobotError::OldServer(text)),
            r => r?,
        };
        let server_nonce =
            codec::parse_challenge(&d).map_err(|e| RobotError::from_codec("HELLO", e))?;
        let client_nonce = Nonce::generate().map_err(|e| RobotError::Auth(e.to_string()))?;
        let proof = secret.client_proof(&server_nonce, &client_nonce);
        let auth = self
            .request(
                Request::Auth {
                    client_nonce,
                    proof,
                },
                timeout,
            )
            .await;
        let d = match auth {
            Err(RobotError::Auth(text)) => {
                return Err(RobotError::Auth(format!(
                    "the robot controller refused cellcal's proof ({text}): the configured \
                     secret ([robot_controller] secret_file) is not the controller's"
                )))
            }
            r => r?,
        };
        let (id, server_proof) =
            codec::parse_auth_reply(&d).map_err(|e| RobotError::from_codec("AUTH", e))?;
        if !secret.verify_server(&server_nonce, &client_nonce, &server_proof) {
            self.link.close(RobotError::Disconnected);
            return Err(RobotError::Auth(
                "the robot controller did not prove it holds the shared secret: it is not the \
                 configured controller, or its secret differs; disconnected"
                    .into(),
            ));
        }
        self.link.lock().version = Some(PROTO_VERSION);
        Ok(id)
    }

    /// `PING`. Cancel-safe (see the module doc).
    pub async fn ping(&self) -> Result<(), RobotError> {
        self.request(Request::Ping, self.config.request_timeout)
            .await
            .map(drop)
    }

    /// `STATE` → power / mode / estop / moving / settled. Cancel-safe (see the module doc).
    pub async fn state(&self) -> Result<RobotState, RobotError> {
        let d = self
            .request(Request::State, self.config.request_timeout)
            .await?;
        codec::parse_state(&d).map_err(|e| RobotError::from_codec("STATE", e))
    }

    /// `POWER ON|OFF`. Cancel-safe (see the module doc); a dropped call may still switch power.
    pub async fn power(&self, on: bool) -> Result<(), RobotError> {
        self.request(Request::Power(on), self.config.request_timeout)
            .await
            .map(drop)
    }

    /// `SPEED <pct>` (monitor speed override, 0 < pct <= 100). Cancel-safe (see the module doc).
    pub async fn speed(&self, pct: f64) -> Result<(), RobotError> {
        self.request(Request::Speed { pct }, self.config.request_timeout)
            .await
            .map(drop)
    }

    /// `MOVEJ` to `joints_deg`; returns as soon as the controller accepted the motion.
    /// Cancel-safe (see the module doc); a dropped call may still have started the move.
    pub async fn move_joints(
        &self,
        joints_deg: [f64; 6],
        vel_pct: Option<f64>,
    ) -> Result<(), RobotError> {
        self.request(
            Request::MoveJ {
                joints_deg,
                vel_pct,
            },
            self.config.request_timeout,
        )
        .await
        .map(drop)
    }

    /// `WAIT <timeout>`: wait until settled and return the settled joints (degrees).
    /// Cancel-safe (see the module doc): dropping it does not stop the arm; call [`Self::stop`].
    pub async fn wait_settled(&self, timeout: Duration) -> Result<[f64; 6], RobotError> {
        let ms = u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX);
        let d = self
            .request(
                Request::Wait { timeout_ms: ms },
                timeout.saturating_add(self.config.wait_margin),
            )
            .await?;
        codec::parse_joints(&d).map_err(|e| RobotError::from_codec("WAIT", e))
    }

    /// `JOINTS` → current joints in degrees. Cancel-safe (see the module doc).
    pub async fn joints(&self) -> Result<[f64; 6], RobotError> {
        let d = self
            .request(Request::Joints, self.config.request_timeout)
            .await?;
        codec::parse_joints(&d).map_err(|e| RobotError::from_codec("JOINTS", e))
    }

    /// `POSE` → flange/tool pose (mm, degrees) in the world frame. Cancel-safe (module doc).
    pub async fn pose(&self) -> Result<Pose, RobotError> {
        let d = self
            .request(Request::Pose, self.config.request_timeout)
            .await?;
        codec::parse_pose(&d).map_err(|e| RobotError::from_codec("POSE", e))
    }

    /// `STOP`: abort the current motion now, overtaking an outstanding request on v2
    /// (see [`StopHandle::stop`] for v1 and cancel-safety).
    pub async fn stop(&self) -> Result<(), RobotError> {
        self.link.stop().await
    }

    /// Cancel-safe (see the module doc).
    async fn request(&self, req: Request, timeout: Duration) -> Result<Vec<String>, RobotError> {
        self.link.request(req, timeout).await
    }
}

/// Writes queued lines whole; on a write error or timeout the connection is closed.
/// Cancel-safe in effect: it is the connection's own task and is never aborted (a runtime
/// shutdown mid-line ends the connection anyway).
async fn writer_task(mut wr: BoxWriter, mut rx: mpsc::UnboundedReceiver<Out>, link: Arc<Link>) {
    let timeout = link.request_timeout;
    while let Some(Out::Line(line)) = rx.recv().await {
        let write = async {
            wr.write_all(line.as_bytes()).await?;
            wr.flush().await
        };
        match tokio::time::timeout(timeout, write).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                debug!(error = %e, "robotlink write failed");
                link.close(RobotError::Disconnected);
                break;
            }
            Err(_) => {
                warn!("robotlink write timed out");
                link.close(RobotError::Disconnected);
                break;
            }
        }
    }
    drop(link);
    let _ = tokio::time::timeout(Duration::from_millis(200), wr.shutdown()).await;
}

/// Reads server lines: replies to their slots, events to subscribers; ends the connection on
/// EOF or a protocol violation.
/// Cancel-safe in effect: it is the connection's own task, aborted only with the client, whose
/// drop closes the connection.
async fn reader_task<R>(mut rd: LineReader<BufReader<R>>, link: Arc<Link>)
where
    R: AsyncRead + Send + Unpin,
{
    let fatal = loop {
        let line = match rd.next_line().await {
            Ok(LineRead::Line(l)) => l,
            Ok(LineRead::Eof) => break RobotError::Disconnected,
            Ok(LineRead::Bad(why)) => break RobotError::Protocol(why),
            Err(e) => {
                debug!(error = %e, "robotlink read failed");
                break RobotError::Disconnected;
            }
        };
        trace!(line = line.as_str(), "robotlink recv");
        let handled = match parse_server_line(&line) {
            Err(e) => Err(RobotError::Protocol(format!("bad line {line:?}: {e}"))),
            Ok(ServerLine::Event(ev)) => on_event(&link, ev),
            Ok(ServerLine::Reply(reply)) => link.on_reply(reply),
        };
        if let Err(e) = handled {
            break e;
        }
    };
    debug!(error = %fatal, "robotlink connection closed");
    // Close our write half as well so that the peer sees the disconnect (and stops motion).
    link.close(fatal);
}

/// Publish an event; E-stop / power loss fail an outstanding motion request; REFUSED is fatal.
fn on_event(link: &Link, ev: Event) -> Result<(), RobotError> {
    let _ = link.events.send(ev.clone());
    match ev.name {
        EventName::EStop => link.on_motion_event(RobotError::EStop(ev.data)),
        EventName::PowerLost => link.on_motion_event(RobotError::PowerOff(ev.data)),
        EventName::Refused => {
            return Err(RobotError::Rejected {
                code: ErrorCode::Busy,
                text: ev.data,
            })
        }
        EventName::Other(_) => {}
    }
    Ok(())
}
