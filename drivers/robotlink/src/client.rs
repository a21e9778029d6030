//! Async client: one connection, one outstanding request, replies matched by sequence number.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex as StdMutex};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::net::{TcpStream, ToSocketAddrs};
use tokio::sync::{broadcast, oneshot, Mutex};
use tokio::task::JoinHandle;
use tracing::{debug, trace, warn};

use crate::codec::{
    self, format_request, parse_server_line, CodecError, ErrorCode, Event, EventName, Identity,
    Pose, ReplyBody, Request, RobotState, ServerLine, MAX_LINE, MAX_SEQ, PROTO_VERSION,
};
use crate::lineio::{read_line_limited, LineRead};

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
    /// Transport error while connecting.
    #[error("i/o error: {0}")]
    Io(#[from] std::io::Error),
}

impl RobotError {
    fn from_reply(code: ErrorCode, text: String) -> Self {
        match code {
            ErrorCode::EStop => RobotError::EStop(text),
            ErrorCode::Power => RobotError::PowerOff(text),
            ErrorCode::Timeout => RobotError::NotSettled(text),
            code => RobotError::Rejected { code, text },
        }
    }

    fn from_codec(ctx: &str, e: CodecError) -> Self {
        RobotError::Protocol(format!("{ctx}: {e}"))
    }
}

/// Client timeouts and buffer sizes.
#[derive(Debug, Clone)]
pub struct ClientConfig {
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
            connect_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(5),
            wait_margin: Duration::from_secs(2),
            event_capacity: 32,
        }
    }
}

type BoxWriter = Box<dyn AsyncWrite + Send + Unpin>;
type ReplyTx = oneshot::Sender<Result<Vec<String>, RobotError>>;

struct Pending {
    seq: u32,
    verb: &'static str,
    tx: ReplyTx,
}

#[derive(Default)]
struct Shared {
    closed: bool,
    close_reason: Option<RobotError>,
    pending: Option<Pending>,
    /// Sequence numbers whose request was abandoned (timeout or event); a late reply is dropped.
    stale: VecDeque<u32>,
}

impl Shared {
    fn mark_stale(&mut self, seq: u32) {
        if self.stale.len() >= 16 {
            self.stale.pop_front();
        }
        self.stale.push_back(seq);
    }
}

fn lock(s: &StdMutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

/// Async robotlink client. Methods take `&self`; requests are serialised internally.
pub struct RobotClient {
    shared: Arc<StdMutex<Shared>>,
    writer: Arc<Mutex<Option<BoxWriter>>>,
    seq: StdMutex<u32>,
    events: broadcast::Sender<Event>,
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
    }
}

impl RobotClient {
    /// Connect over TCP (with `connect_timeout`), disable Nagle and start the reader task.
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
        let shared = Arc::new(StdMutex::new(Shared::default()));
        let writer: Arc<Mutex<Option<BoxWriter>>> = Arc::new(Mutex::new(Some(Box::new(wr))));
        let (events, _) = broadcast::channel(config.event_capacity.max(1));
        let reader = tokio::spawn(reader_task(
            BufReader::new(rd),
            shared.clone(),
            writer.clone(),
            events.clone(),
        ));
        Self {
            shared,
            writer,
            seq: StdMutex::new(0),
            events,
            config,
            reader,
        }
    }

    /// Subscribe to asynchronous `* EVT` lines.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// True once the connection is closed (every further call returns `Disconnected`).
    pub fn is_closed(&self) -> bool {
        lock(&self.shared).closed
    }

    /// Close the connection (the server then stops any motion).
    pub async fn close(&self) {
        {
            let mut sh = lock(&self.shared);
            sh.closed = true;
            sh.close_reason = None;
        }
        let mut w = self.writer.lock().await;
        if let Some(mut wr) = w.take() {
            let _ = tokio::time::timeout(Duration::from_millis(200), wr.shutdown()).await;
        }
    }

    /// `HELLO <PROTO_VERSION>` → controller identity.
    pub async fn hello(&self) -> Result<Identity, RobotError> {
        let d = self
            .request(
                Request::Hello {
                    proto_ver: PROTO_VERSION,
                },
                self.config.request_timeout,
            )
            .await?;
        codec::parse_identity(&d).map_err(|e| RobotError::from_codec("HELLO", e))
    }

    /// `PING`.
    pub async fn ping(&self) -> Result<(), RobotError> {
        self.request(Request::Ping, self.config.request_timeout)
            .await
            .map(drop)
    }

    /// `STATE` → power / mode / estop / moving / settled.
    pub async fn state(&self) -> Result<RobotState, RobotError> {
        let d = self
            .request(Request::State, self.config.request_timeout)
            .await?;
        codec::parse_state(&d).map_err(|e| RobotError::from_codec("STATE", e))
    }

    /// `POWER ON|OFF`.
    pub async fn power(&self, on: bool) -> Result<(), RobotError> {
        self.request(Request::Power(on), self.config.request_timeout)
            .await
            .map(drop)
    }

    /// `SPEED <pct>` (monitor speed override, 0 < pct <= 100).
    pub async fn speed(&self, pct: f64) -> Result<(), RobotError> {
        self.request(Request::Speed { pct }, self.config.request_timeout)
            .await
            .map(drop)
    }

    /// `MOVEJ` to `joints_deg`; returns as soon as the controller accepted the motion.
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

    /// `JOINTS` → current joints in degrees.
    pub async fn joints(&self) -> Result<[f64; 6], RobotError> {
        let d = self
            .request(Request::Joints, self.config.request_timeout)
            .await?;
        codec::parse_joints(&d).map_err(|e| RobotError::from_codec("JOINTS", e))
    }

    /// `POSE` → flange/tool pose (mm, degrees) in the world frame.
    pub async fn pose(&self) -> Result<Pose, RobotError> {
        let d = self
            .request(Request::Pose, self.config.request_timeout)
            .await?;
        codec::parse_pose(&d).map_err(|e| RobotError::from_codec("POSE", e))
    }

    /// `STOP`: abort the current motion.
    pub async fn stop(&self) -> Result<(), RobotError> {
        self.request(Request::Stop, self.config.request_timeout)
            .await
            .map(drop)
    }

    fn next_seq(&self) -> u32 {
        let mut s = self.seq.lock().unwrap_or_else(|e| e.into_inner());
        *s = if *s >= MAX_SEQ { 1 } else { *s + 1 };
        *s
    }

    async fn request(&self, req: Request, timeout: Duration) -> Result<Vec<String>, RobotError> {
        let verb = req.verb();
        // Holding the writer lock for the whole exchange enforces one outstanding request.
        let mut wguard = self.writer.lock().await;
        let seq = self.next_seq();
        let (tx, rx) = oneshot::channel();
        {
            let mut sh = lock(&self.shared);
            if sh.closed {
                return Err(sh.close_reason.take().unwrap_or(RobotError::Disconnected));
            }
            sh.pending = Some(Pending { seq, verb, tx });
        }
        let line = format_request(seq, &req);
        trace!(line = line.trim_end(), "robotlink send");
        let Some(w) = wguard.as_mut() else {
            lock(&self.shared).pending = None;
            return Err(RobotError::Disconnected);
        };
        let write = async {
            w.write_all(line.as_bytes()).await?;
            w.flush().await
        };
        match tokio::time::timeout(self.config.request_timeout, write).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                debug!(error = %e, "robotlink write failed");
                *wguard = None;
                let mut sh = lock(&self.shared);
                sh.closed = true;
                sh.pending = None;
                return Err(RobotError::Disconnected);
            }
            Err(_) => {
                *wguard = None;
                let mut sh = lock(&self.shared);
                sh.closed = true;
                sh.pending = None;
                return Err(RobotError::Timeout(verb));
            }
        }
        let res = match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(RobotError::Disconnected),
            Err(_) => {
                let mut sh = lock(&self.shared);
                if sh.pending.as_ref().map(|p| p.seq) == Some(seq) {
                    sh.pending = None;
                    sh.mark_stale(seq);
                }
                warn!(verb, seq, "robotlink reply timeout");
                Err(RobotError::Timeout(verb))
            }
        };
        // A fatal reader error closes the connection: drop our half too so the server notices.
        if lock(&self.shared).closed {
            *wguard = None;
        }
        res
    }
}

async fn reader_task<R>(
    mut rd: BufReader<R>,
    shared: Arc<StdMutex<Shared>>,
    writer: Arc<Mutex<Option<BoxWriter>>>,
    events: broadcast::Sender<Event>,
) where
    R: AsyncRead + Send + Unpin,
{
    let fatal = loop {
        let line = match read_line_limited(&mut rd, MAX_LINE).await {
            Ok(LineRead::Line(l)) => l,
            Ok(LineRead::Eof) => break RobotError::Disconnected,
            Ok(LineRead::Bad(why)) => break RobotError::Protocol(why),
            Err(e) => {
                debug!(error = %e, "robotlink read failed");
                break RobotError::Disconnected;
            }
        };
        trace!(line = line.as_str(), "robotlink recv");
        match parse_server_line(&line) {
            Err(e) => break RobotError::Protocol(format!("bad line {line:?}: {e}")),
            Ok(ServerLine::Event(ev)) => {
                let _ = events.send(ev.clone());
                let err = match &ev.name {
                    EventName::EStop => Some(RobotError::EStop(ev.data.clone())),
                    EventName::PowerLost => Some(RobotError::PowerOff(ev.data.clone())),
                    EventName::Refused => {
                        break RobotError::Rejected {
                            code: ErrorCode::Busy,
                            text: ev.data.clone(),
                        }
                    }
                    EventName::Other(_) => None,
                };
                if let Some(err) = err {
                    let mut sh = lock(&shared);
                    let relevant = matches!(sh.pending.as_ref(), Some(p) if p.verb == "WAIT" || p.verb == "MOVEJ");
                    if relevant {
                        if let Some(p) = sh.pending.take() {
                            sh.mark_stale(p.seq);
                            let _ = p.tx.send(Err(err));
                        }
                    }
                }
            }
            Ok(ServerLine::Reply(reply)) => {
                let mut sh = lock(&shared);
                match sh.pending.take() {
                    Some(p) if p.seq == reply.seq => {
                        let r = match reply.body {
                            ReplyBody::Ok(d) => Ok(d),
                            ReplyBody::Err { code, text } => {
                                Err(RobotError::from_reply(code, text))
                            }
                        };
                        let _ = p.tx.send(r);
                    }
                    other => {
                        if let Some(pos) = sh.stale.iter().position(|s| *s == reply.seq) {
                            sh.stale.remove(pos);
                            sh.pending = other;
                            debug!(seq = reply.seq, "dropping late reply to abandoned request");
                            continue;
                        }
                        sh.pending = other;
                        let expected = sh.pending.as_ref().map(|p| p.seq);
                        break RobotError::Protocol(format!(
                            "reply with unexpected sequence number {} (expected {:?})",
                            reply.seq, expected
                        ));
                    }
                }
            }
        }
    };
    debug!(error = %fatal, "robotlink connection closed");
    {
        let mut sh = lock(&shared);
        sh.closed = true;
        match sh.pending.take() {
            Some(p) => {
                let _ = p.tx.send(Err(fatal));
            }
            None => {
                if !matches!(fatal, RobotError::Disconnected) {
                    sh.close_reason = Some(fatal);
                }
            }
        }
    }
    // Close our write half as well so that the peer sees the disconnect (and stops motion).
    // try_lock: if a request holds the writer it will drop it itself after seeing `closed`.
    if let Ok(mut w) = writer.try_lock() {
        if let Some(mut wr) = w.take() {
            let _ = tokio::time::timeout(Duration::from_millis(200), wr.shutdown()).await;
        }
    }
}
