//! Async emScon client: a reader task demultiplexes replies, results and unsolicited packets;
//! callers run one command at a time with explicit timeouts.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpStream, ToSocketAddrs};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tracing::{debug, warn};

use crate::codec::{
    CodecError, Command, ErrorResponse, FrameDecoder, NivelResult, ReflectorPosResult, Reply,
    ReplyBody, ServerPacket, MAX_PACKET_SIZE,
};
use crate::error::EmsconError;
use crate::types::{
    cmd, status, status_change, Environment, MeasurementStatusInfo, ReflectorInfo, SystemSettings,
    SystemStatus, Units, COORD_SYS_RHR, MEAS_MODE_STATIONARY,
};

/// `ES_TargetType` of a 1.5" red-ring reflector, preferred by [`Client::setup_stationary`].
const TARGET_TYPE_RRR15: i32 = 5;
/// Capacity of the per-command routing channel.
const ROUTE_CAPACITY: usize = 256;
/// How many timed-out command ids are remembered so that late replies can be dropped.
const STALE_CAPACITY: usize = 16;

/// Client timeouts and beam-break policy.
#[derive(Debug, Clone)]
pub struct ClientConfig {
    /// TCP connect timeout.
    pub connect_timeout: Duration,
    /// Timeout for an ordinary command (reply wait, write, waiting for the command slot).
    pub command_timeout: Duration,
    /// Timeout for Initialize (CESAPI waits 90 s).
    pub initialize_timeout: Duration,
    /// Timeout for FindReflector and GoLastMeasuredPoint.
    pub search_timeout: Duration,
    /// Added to the measuring time to get the measurement result timeout.
    pub measure_margin: Duration,
    /// Measuring time assumed until `set_stationary_params` has been called.
    pub default_meas_time_ms: i32,
    /// Status codes meaning "beam broken" (measurement) or "target not found" (search).
    pub beam_break_codes: Vec<i32>,
    /// One extra site-specific beam-break code (e.g. a newer server's "no target").
    pub beam_break_code: Option<i32>,
    /// Any unsolicited Error packet during a measurement counts as a beam break.
    pub error_during_measurement_is_beam_break: bool,
    /// A status change `MeasStatus_NotReady` (25) during a measurement counts as a beam break.
    pub not_ready_during_measurement_is_beam_break: bool,
    /// Check the ReflectorFound bit (GetMeasurementStatusInfo) before StartMeasurement.
    pub check_reflector_before_measure: bool,
    /// Capacity of the unsolicited-event broadcast channel.
    pub event_capacity: usize,
    /// Upper bound for a packet's declared size.
    pub max_packet_size: usize,
}

impl Default for ClientConfig {
    fn default() -> Self {
        ClientConfig {
            connect_timeout: Duration::from_secs(5),
            command_timeout: Duration::from_secs(30),
            initialize_timeout: Duration::from_secs(90),
            search_timeout: Duration::from_secs(30),
            measure_margin: Duration::from_secs(5),
            default_meas_time_ms: 1000,
            beam_break_codes: vec![
                status::MEASUREMENT_STATUS_NOT_READY,
                status::NO_STATIONARY_RESULT,
                status::SYSTEM_NOT_READY_FOR_MEASUREMENT,
            ],
            beam_break_code: None,
            error_during_measurement_is_beam_break: true,
            not_ready_during_measurement_is_beam_break: true,
            check_reflector_before_measure: true,
            event_capacity: 64,
            max_packet_size: MAX_PACKET_SIZE,
        }
    }
}

impl ClientConfig {
    /// True if `status` is configured as a beam-break / target-not-found code.
    pub fn is_beam_break_code(&self, status: i32) -> bool {
        self.beam_break_codes.contains(&status) || self.beam_break_code == Some(status)
    }
}

/// Unsolicited (or broadcast) events from the server.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A SystemStatusChange packet (`ES_SystemStatusChange` code).
    StatusChange(i32),
    /// An Error packet (solicited ones are broadcast too).
    Error(ErrorResponse),
    /// A reflector position packet.
    ReflectorPos(ReflectorPosResult),
    /// A nivel result packet.
    Nivel(NivelResult),
    /// A malformed packet was received and skipped.
    ProtocolError(String),
    /// The connection is closed.
    Disconnected,
}

/// Parameters for [`Client::setup_stationary`].
#[derive(Debug, Clone)]
pub struct StationarySetup {
    /// Measuring time in ms.
    pub meas_time_ms: i32,
    /// Use the ADM.
    pub use_adm: bool,
    /// Reflector id; `None` picks the first RRR 1.5" (or the first listed) reflector.
    pub reflector_id: Option<i32>,
    /// System settings to apply (unsolicited messages are forced on).
    pub settings: SystemSettings,
}

impl Default for StationarySetup {
    fn default() -> Self {
        StationarySetup {
            meas_time_ms: 1000,
            use_adm: true,
            reflector_id: None,
            settings: SystemSettings::default(),
        }
    }
}

/// One stationary measurement, stamped by the client.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// X in mm (tracker frame, RHR).
    pub x_mm: f64,
    /// Y in mm.
    pub y_mm: f64,
    /// Z in mm.
    pub z_mm: f64,
    /// Standard deviations of X, Y, Z in mm.
    pub std_mm: [f64; 3],
    /// Total standard deviation in mm.
    pub std_total_mm: f64,
    /// Covariances 12/13/23 when the server sent SingleMeasResult2.
    pub covariance: Option<[f64; 3]>,
    /// Air temperature in °C.
    pub temperature_c: f64,
    /// Air pressure in mbar.
    pub pressure_mbar: f64,
    /// Relative humidity in %.
    pub humidity_pct: f64,
    /// When StartMeasurement was sent.
    pub sent_at: SystemTime,
    /// When the result was received.
    pub received_at: SystemTime,
    /// Configured measuring time in ms.
    pub meas_time_ms: i32,
}

/// Why the connection closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CloseReason {
    Eof,
    Refused,
    ServerClosing,
    Framing,
    Io,
    Dropped,
}

impl CloseReason {
    fn to_error(self) -> EmsconError {
        match self {
            CloseReason::Refused => EmsconError::ConnectionRefused,
            _ => EmsconError::Disconnected,
        }
    }
}

/// Items routed from the reader task to the current operation.
#[derive(Debug)]
enum Incoming {
    Packet(ServerPacket),
    Bad(CodecError),
    Closed(CloseReason),
}

#[derive(Debug, Default)]
struct Shared {
    route: Option<mpsc::Sender<Incoming>>,
    closed: Option<CloseReason>,
}

type SharedRef = Arc<Mutex<Shared>>;

struct OpState {
    writer: Box<dyn AsyncWrite + Send + Unpin>,
    stale: VecDeque<i32>,
    meas_time_ms: Option<i32>,
}

impl OpState {
    fn mark_stale(&mut self, command: i32) {
        if self.stale.len() >= STALE_CAPACITY {
            self.stale.pop_front();
        }
        self.stale.push_back(command);
    }
    fn take_stale(&mut self, command: i32) -> bool {
        match self.stale.iter().position(|c| *c == command) {
            Some(i) => {
                self.stale.remove(i);
                true
            }
            None => false,
        }
    }
}

/// Context used to map a non-OK status to an error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ctx {
    Plain,
    Measure,
    Search,
}

/// Async emScon TPI client (one outstanding command at a time; cheap to recreate).
///
/// Every request method is cancel-safe: a dropped request never desynchronises the stream
/// (a half-written command, a measurement in flight or a GetReflectors still collecting its
/// replies closes the connection, so the next call fails `Disconnected` and the caller
/// reconnects; a sent command's late reply is dropped).
pub struct Client {
    shared: SharedRef,
    op: tokio::sync::Mutex<OpState>,
    events: broadcast::Sender<Event>,
    config: ClientConfig,
    reader: JoinHandle<()>,
    peer: Option<std::net::SocketAddr>,
}

impl std::fmt::Debug for Client {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Client")
            .field("config", &self.config)
            .field("connected", &self.is_connected())
            .finish()
    }
}

impl Drop for Client {
    fn drop(&mut self) {
        self.reader.abort();
    }
}

fn lock_shared(shared: &SharedRef) -> std::sync::MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(|p| p.into_inner())
}

fn close_shared(shared: &SharedRef, events: &broadcast::Sender<Event>, reason: CloseReason) {
    let route = {
        let mut s = lock_shared(shared);
        if s.closed.is_none() {
            s.closed = Some(reason);
        }
        s.route.clone()
    };
    if let Some(tx) = route {
        let _ = tx.try_send(Incoming::Closed(reason));
    }
    let _ = events.send(Event::Disconnected);
}

fn route(shared: &SharedRef, item: Incoming) {
    let tx = lock_shared(shared).route.clone();
    if let Some(tx) = tx {
        if tx.try_send(item).is_err() {
            warn!("emscon: routing channel full, packet dropped");
        }
    }
}

/// Runs as the client's own task and is only aborted with the client (or by `close`), which closes
/// the connection, so it has no cancel-safety contract to keep.
async fn reader_loop<R: AsyncRead + Unpin>(
    mut rd: R,
    shared: SharedRef,
    events: broadcast::Sender<Event>,
    max: usize,
) {
    let mut dec = FrameDecoder::with_max_size(max);
    let mut buf = vec![0u8; 8192];
    let reason = 'outer: loop {
        let n = match rd.read(&mut buf).await {
            Ok(0) => break CloseReason::Eof,
            Ok(n) => n,
            Err(e) => {
                warn!("emscon: read error: {e}");
                break CloseReason::Io;
            }
        };
        dec.push(buf.get(..n).unwrap_or(&[]));
        loop {
            match dec.next_packet::<ServerPacket>() {
                Ok(None) => break,
                Ok(Some(p)) => {
                    if let Some(reason) = dispatch(&shared, &events, p) {
                        break 'outer reason;
                    }
                }
                Err(e) => {
                    warn!("emscon: bad packet from server: {e}");
                    let _ = events.send(Event::ProtocolError(e.to_string()));
                    let fatal = e.is_fatal();
                    route(&shared, Incoming::Bad(e));
                    if fatal {
                        break 'outer CloseReason::Framing;
                    }
                }
            }
        }
    };
    debug!("emscon: reader finished: {reason:?}");
    close_shared(&shared, &events, reason);
}

/// Broadcasts and routes one packet; returns a close reason if the connection must end.
fn dispatch(
    shared: &SharedRef,
    events: &broadcast::Sender<Event>,
    p: ServerPacket,
) -> Option<CloseReason> {
    let mut close = None;
    match &p {
        ServerPacket::Error(e) => {
            let _ = events.send(Event::Error(*e));
            if e.status == status::MULTI_CONNECTIONS_NOT_ALLOWED {
                warn!("emscon: server refused connection (10011)");
                close = Some(CloseReason::Refused);
            }
        }
        ServerPacket::StatusChange(code) => {
            let _ = events.send(Event::StatusChange(*code));
            if *code == status_change::TP_CONNECTION_CLOSING
                || *code == status_change::SERVER_CLOSING
            {
                warn!("emscon: server announced closing ({code})");
                close = Some(CloseReason::ServerClosing);
            }
        }
        ServerPacket::ReflectorPos(r) => {
            let _ = events.send(Event::ReflectorPos(*r));
        }
        ServerPacket::NivelResult(n) => {
            let _ = events.send(Event::Nivel(*n));
        }
        _ => {}
    }
    if close.is_none() {
        route(shared, Incoming::Packet(p));
    }
    close
}

/// Exclusive access to the connection for one operation; routes incoming packets to `rx`.
struct Op<'a> {
    st: tokio::sync::MutexGuard<'a, OpState>,
    rx: mpsc::Receiver<Incoming>,
    shared: &'a SharedRef,
    events: &'a broadcast::Sender<Event>,
    cfg: &'a ClientConfig,
    /// What a drop right now would leave behind on the wire.
    wire: Wire,
}

/// The wire state of an [`Op`]: what dropping it mid-request must repair.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Wire {
    /// Nothing in flight.
    Idle,
    /// Part of a command may have been written: the stream can no longer be framed.
    Writing,
    /// Command `id` was sent and its reply has not arrived: drop that reply when it does.
    Awaiting(i32),
    /// A measurement is under way: its result could later pass for another one's, so the
    /// connection is closed.
    Measuring,
    /// A multi-reply command (GetReflectors) is under way: how many of its replies are still
    /// to come is unknown, so the connection is closed.
    Collecting,
}

impl Drop for Op<'_> {
    /// A dropped request never desynchronises the stream: a half-written command, a
    /// measurement or a multi-reply command in flight closes the connection, a sent one has
    /// its late reply marked to be dropped.
    fn drop(&mut self) {
        match self.wire {
            Wire::Idle => {}
            Wire::Writing | Wire::Measuring | Wire::Collecting => {
                close_shared(self.shared, self.events, CloseReason::Io)
            }
            Wire::Awaiting(id) => self.st.mark_stale(id),
        }
        lock_shared(self.shared).route = None;
    }
}

impl Op<'_> {
    /// Not cancel-safe on its own: a drop mid-write leaves a partial command, which is why it marks
    /// the op `Writing` first so that dropping the [`Op`] closes the connection.
    async fn send(&mut self, command: &Command) -> Result<(), EmsconError> {
        let bytes = command.to_bytes();
        self.wire = Wire::Writing;
        let res = tokio::time::timeout(self.cfg.command_timeout, async {
            self.st.writer.write_all(&bytes).await?;
            self.st.writer.flush().await
        })
        .await;
        self.wire = Wire::Awaiting(command.id());
        match res {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => {
                close_shared(self.shared, self.events, CloseReason::Io);
                Err(EmsconError::Io(e))
            }
            Err(_) => {
                close_shared(self.shared, self.events, CloseReason::Io);
                Err(EmsconError::Timeout {
                    what: "writing a command",
                })
            }
        }
    }

    /// Cancel-safe: it only receives from the routing channel, which keeps unread items.
    async fn recv(
        &mut self,
        deadline: Instant,
        what: &'static str,
    ) -> Result<Incoming, EmsconError> {
        match tokio::time::timeout_at(deadline, self.rx.recv()).await {
            Err(_) => Err(EmsconError::Timeout { what }),
            Ok(None) => Err(EmsconError::Disconnected),
            Ok(Some(item)) => Ok(item),
        }
    }

    /// A reply for another command is tolerated if that command timed out or failed earlier,
    /// or if it is an OK StartMeasurement RT (servers may send it after the result).
    fn is_ignorable_late_reply(&mut self, rep: &Reply) -> bool {
        let late_rt = rep.command == cmd::START_MEASUREMENT && rep.status == status::ALL_OK;
        if self.st.take_stale(rep.command) || late_rt {
            debug!("emscon: dropping late reply for command {}", rep.command);
            true
        } else {
            false
        }
    }

    fn map_status(&self, command: i32, st: i32, ctx: Ctx) -> EmsconError {
        match st {
            status::SERVER_BUSY => EmsconError::Busy,
            status::TRACKER_NOT_INITIALIZED => EmsconError::NotInitialized,
            status::SENSOR_NOT_WARMED_UP => EmsconError::NotWarmedUp,
            status::MULTI_CONNECTIONS_NOT_ALLOWED => EmsconError::ConnectionRefused,
            s if self.cfg.is_beam_break_code(s) && ctx == Ctx::Measure => EmsconError::BeamBroken,
            s if self.cfg.is_beam_break_code(s) && ctx == Ctx::Search => {
                EmsconError::TargetNotFound
            }
            _ => EmsconError::Device {
                command,
                status: st,
            },
        }
    }

    /// Sends `command` and waits for its reply (non-OK status is final).
    /// Cancel-safe through the [`Op`] guard: a drop mid-write closes the connection, a drop while
    /// awaiting the reply marks the command's late reply stale.
    async fn transact(
        &mut self,
        command: &Command,
        timeout: Duration,
        ctx: Ctx,
        what: &'static str,
    ) -> Result<Reply, EmsconError> {
        let id = command.id();
        self.send(command).await?;
        let deadline = Instant::now() + timeout;
        let res = self.await_reply(id, deadline, ctx, what).await;
        self.wire = Wire::Idle;
        if res.is_err() {
            self.st.mark_stale(id);
        }
        res
    }

    /// Cancel-safe: it only reads routed packets; the caller's wire state says what a drop must
    /// repair.
    async fn await_reply(
        &mut self,
        id: i32,
        deadline: Instant,
        ctx: Ctx,
        what: &'static str,
    ) -> Result<Reply, EmsconError> {
        loop {
            match self.recv(deadline, what).await? {
                Incoming::Closed(r) => return Err(r.to_error()),
                Incoming::Bad(e) => return Err(EmsconError::Protocol(e.to_string())),
                Incoming::Packet(ServerPacket::Reply(rep)) => {
                    if rep.command == id {
                        if rep.status != status::ALL_OK {
                            return Err(self.map_status(id, rep.status, ctx));
                        }
                        return Ok(rep);
                    }
                    if self.is_ignorable_late_reply(&rep) {
                        continue;
                    }
                    return Err(EmsconError::Protocol(format!(
                        "reply for command {} while waiting for command {id}",
                        rep.command
                    )));
                }
                Incoming::Packet(ServerPacket::Error(e)) if e.command == id => {
                    return Err(self.map_status(id, e.status, ctx));
                }
                Incoming::Packet(other) => {
                    debug!("emscon: ignoring packet while waiting for {id}: {other:?}");
                }
            }
        }
    }
}

fn expect_body<T>(rep: Reply, f: impl FnOnce(ReplyBody) -> Option<T>) -> Result<T, EmsconError> {
    let (command, status) = (rep.command, rep.status);
    f(rep.body).ok_or_else(|| {
        EmsconError::Protocol(format!(
            "reply to command {command} (status {status}) lacks its payload"
        ))
    })
}

fn all_finite(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

impl Client {
    /// Connects over TCP (timeout `config.connect_timeout`) and starts the reader task.
    /// Cancel-safe: a drop before it returns leaves no connection and no reader task behind.
    pub async fn connect<A: ToSocketAddrs>(
        addr: A,
        config: ClientConfig,
    ) -> Result<Client, EmsconError> {
        let stream = tokio::time::timeout(config.connect_timeout, TcpStream::connect(addr))
            .await
            .map_err(|_| EmsconError::Timeout { what: "connect" })??;
        stream.set_nodelay(true)?;
        let peer = stream.peer_addr().ok();
        let mut client = Self::from_stream(stream, config);
        client.peer = peer;
        Ok(client)
    }

    /// Opens a fresh connection to the same server with the same configuration.
    /// Cancel-safe like [`Client::connect`]; the old client is untouched.
    pub async fn reconnect(&self) -> Result<Client, EmsconError> {
        let addr = self.peer.ok_or(EmsconError::Disconnected)?;
        Client::connect(addr, self.config.clone()).await
    }

    /// Wraps an established byte stream (TCP, in-memory duplex, ...); needs a Tokio runtime.
    pub fn from_stream<S>(stream: S, config: ClientConfig) -> Client
    where
        S: AsyncRead + AsyncWrite + Send + 'static,
    {
        let (rd, wr) = tokio::io::split(stream);
        let shared: SharedRef = Arc::new(Mutex::new(Shared::default()));
        let (events, _) = broadcast::channel(config.event_capacity.max(1));
        let reader = tokio::spawn(reader_loop(
            rd,
            shared.clone(),
            events.clone(),
            config.max_packet_size,
        ));
        Client {
            shared,
            op: tokio::sync::Mutex::new(OpState {
                writer: Box::new(wr),
                stale: VecDeque::new(),
                meas_time_ms: None,
            }),
            events,
            config,
            reader,
            peer: None,
        }
    }

    /// Subscribes to unsolicited events (status changes, error packets, disconnect).
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// The configuration in use.
    pub fn config(&self) -> &ClientConfig {
        &self.config
    }

    /// False once the connection is closed (then every call fails; create a new client).
    pub fn is_connected(&self) -> bool {
        lock_shared(&self.shared).closed.is_none()
    }

    /// Closes the connection; later calls return `Disconnected`.
    /// Cancel-safe: a drop while waiting for the command slot or the shutdown changes nothing (the
    /// connection is then closed by dropping the client).
    pub async fn close(&self) {
        if let Ok(mut st) = tokio::time::timeout(self.config.command_timeout, self.op.lock()).await
        {
            let _ = tokio::time::timeout(self.config.command_timeout, st.writer.shutdown()).await;
        }
        self.reader.abort();
        close_shared(&self.shared, &self.events, CloseReason::Dropped);
    }

    /// Cancel-safe: no state changes before the only await (the command slot).
    async fn begin(&self) -> Result<Op<'_>, EmsconError> {
        let st = tokio::time::timeout(self.config.command_timeout, self.op.lock())
            .await
            .map_err(|_| EmsconError::Timeout {
                what: "command slot",
            })?;
        let (tx, rx) = mpsc::channel(ROUTE_CAPACITY);
        {
            let mut s = lock_shared(&self.shared);
            if let Some(reason) = s.closed {
                return Err(reason.to_error());
            }
            s.route = Some(tx);
        }
        Ok(Op {
            st,
            rx,
            shared: &self.shared,
            events: &self.events,
            cfg: &self.config,
            wire: Wire::Idle,
        })
    }

    /// Cancel-safe (see [`Client`]): the [`Op`] guard repairs the stream whatever await it is
    /// dropped at.
    async fn simple(
        &self,
        command: Command,
        timeout: Duration,
        ctx: Ctx,
        what: &'static str,
    ) -> Result<Reply, EmsconError> {
        let mut op = self.begin().await?;
        op.transact(&command, timeout, ctx, what).await
    }

    /// Sends any command and returns its (OK) reply; errors are mapped as for plain commands.
    /// Cancel-safe (see [`Client`]).
    pub async fn command(&self, command: Command) -> Result<Reply, EmsconError> {
        self.simple(command, self.config.command_timeout, Ctx::Plain, "reply")
            .await
    }

    /// GetSystemStatus (1).
    /// Cancel-safe (see [`Client`]).
    pub async fn system_status(&self) -> Result<SystemStatus, EmsconError> {
        let rep = self
            .simple(
                Command::GetSystemStatus,
                self.config.command_timeout,
                Ctx::Plain,
                "GetSystemStatus reply",
            )
            .await?;
        expect_body(rep, |b| match b {
            ReplyBody::SystemStatus(s) => Some(s),
            _ => None,
        })
    }

    /// SetUnits (5) with arbitrary units (results are only interpreted as mm by this client).
    /// Cancel-safe (see [`Client`]); a dropped call may still have changed the units.
    pub async fn set_units(&self, units: Units) -> Result<(), EmsconError> {
        self.simple(
            Command::SetUnits(units),
            self.config.command_timeout,
            Ctx::Plain,
            "SetUnits reply",
        )
        .await
        .map(drop)
    }

    /// SetUnits (5): millimetre, degree, °C, mbar, %RH.
    /// Cancel-safe (see [`Client`]); a dropped call may still have changed the units.
    pub async fn set_units_mm_deg(&self) -> Result<(), EmsconError> {
        self.set_units(Units::MM_DEG).await
    }

    /// Initialize (7), with `config.initialize_timeout`.
    /// Cancel-safe (see [`Client`]); a dropped call does not stop the tracker initialising.
    pub async fn initialize(&self) -> Result<(), EmsconError> {
        self.simple(
            Command::Initialize,
            self.config.initialize_timeout,
            Ctx::Plain,
            "Initialize reply",
        )
        .await
        .map(drop)
    }

    /// SetEnvironmentParams (20).
    /// Cancel-safe (see [`Client`]); a dropped call may still have applied the parameters.
    pub async fn set_environment(&self, env: Environment) -> Result<(), EmsconError> {
        self.simple(
            Command::SetEnvironmentParams(env),
            self.config.command_timeout,
            Ctx::Plain,
            "SetEnvironmentParams reply",
        )
        .await
        .map(drop)
    }

    /// SetMeasurementMode (24) = stationary.
    /// Cancel-safe (see [`Client`]); a dropped call may still have switched the mode.
    pub async fn set_measurement_mode_stationary(&self) -> Result<(), EmsconError> {
        self.simple(
            Command::SetMeasurementMode(MEAS_MODE_STATIONARY),
            self.config.command_timeout,
            Ctx::Plain,
            "SetMeasurementMode reply",
        )
        .await
        .map(drop)
    }

    /// SetStationaryModeParams (28); remembers the measuring time for result timeouts.
    /// Cancel-safe for the stream (see [`Client`]); a call dropped after the command went out may
    /// leave the tracker on the new measuring time while result timeouts still use the old one, so
    /// call it again before measuring.
    pub async fn set_stationary_params(
        &self,
        meas_time_ms: i32,
        use_adm: bool,
    ) -> Result<(), EmsconError> {
        let mut op = self.begin().await?;
        op.transact(
            &Command::SetStationaryModeParams {
                meas_time_ms,
                use_adm,
            },
            self.config.command_timeout,
            Ctx::Plain,
            "SetStationaryModeParams reply",
        )
        .await?;
        op.st.meas_time_ms = Some(meas_time_ms);
        Ok(())
    }

    /// SetCoordinateSystemType (26) = RHR (Cartesian right-handed).
    /// Cancel-safe (see [`Client`]); a dropped call may still have switched the system.
    pub async fn set_coordinate_system_rhr(&self) -> Result<(), EmsconError> {
        self.simple(
            Command::SetCoordinateSystemType(COORD_SYS_RHR),
            self.config.command_timeout,
            Ctx::Plain,
            "SetCoordinateSystemType reply",
        )
        .await
        .map(drop)
    }

    /// SetReflector (40).
    /// Cancel-safe (see [`Client`]); a dropped call may still have selected the reflector.
    pub async fn set_reflector(&self, id: i32) -> Result<(), EmsconError> {
        self.simple(
            Command::SetReflector(id),
            self.config.command_timeout,
            Ctx::Plain,
            "SetReflector reply",
        )
        .await
        .map(drop)
    }

    /// GetReflectors (42): collects one reply per reflector.
    /// Cancel-safe: a drop once the command went out closes the connection, because the number of
    /// its replies still to come is unknown (see [`Client`]).
    pub async fn reflectors(&self) -> Result<Vec<ReflectorInfo>, EmsconError> {
        let mut op = self.begin().await?;
        let deadline = Instant::now() + self.config.command_timeout;
        op.send(&Command::GetReflectors).await?;
        op.wire = Wire::Collecting;
        let mut out = Vec::new();
        loop {
            let rep = match op
                .await_reply(
                    cmd::GET_REFLECTORS,
                    deadline,
                    Ctx::Plain,
                    "GetReflectors reply",
                )
                .await
            {
                Ok(r) => r,
                // more replies may still come: the op stays `Collecting`, so its drop closes
                // the connection
                Err(e @ EmsconError::Timeout { .. }) => return Err(e),
                Err(e) => {
                    op.wire = Wire::Idle;
                    op.st.mark_stale(cmd::GET_REFLECTORS);
                    return Err(e);
                }
            };
            let info = expect_body(rep, |b| match b {
                ReplyBody::Reflector(r) => Some(r),
                _ => None,
            })?;
            let total = info.total;
            if total > 0 {
                out.push(info);
            }
            if total <= 0 || out.len() >= usize::try_from(total).unwrap_or(usize::MAX) {
                op.wire = Wire::Idle;
                return Ok(out);
            }
        }
    }

    /// SetSystemSettings (47).
    /// Cancel-safe (see [`Client`]); a dropped call may still have applied the settings.
    pub async fn set_system_settings(&self, settings: SystemSettings) -> Result<(), EmsconError> {
        self.simple(
            Command::SetSystemSettings(settings),
            self.config.command_timeout,
            Ctx::Plain,
            "SetSystemSettings reply",
        )
        .await
        .map(drop)
    }

    /// SetStatisticMode (80): `extended` = SingleMeasResult2 results.
    /// Cancel-safe (see [`Client`]); a dropped call may still have switched the mode.
    pub async fn set_statistic_mode(&self, extended: bool) -> Result<(), EmsconError> {
        let mode = i32::from(extended);
        self.simple(
            Command::SetStatisticMode {
                stationary: mode,
                continuous: mode,
            },
            self.config.command_timeout,
            Ctx::Plain,
            "SetStatisticMode reply",
        )
        .await
        .map(drop)
    }

    /// GetMeasurementStatusInfo (122) bitmask.
    /// Cancel-safe (see [`Client`]).
    pub async fn measurement_status(&self) -> Result<MeasurementStatusInfo, EmsconError> {
        let mut op = self.begin().await?;
        Self::measurement_status_op(&mut op).await
    }

    /// Cancel-safe through the [`Op`] guard (see [`Op::transact`]).
    async fn measurement_status_op(op: &mut Op<'_>) -> Result<MeasurementStatusInfo, EmsconError> {
        let timeout = op.cfg.command_timeout;
        let rep = op
            .transact(
                &Command::GetMeasurementStatusInfo,
                timeout,
                Ctx::Plain,
                "GetMeasurementStatusInfo reply",
            )
            .await?;
        expect_body(rep, |b| match b {
            ReplyBody::MeasurementStatusInfo { info, .. } => Some(info),
            _ => None,
        })
    }

    /// FindReflector (63); failure codes in the beam-break set map to `TargetNotFound`.
    /// Cancel-safe (see [`Client`]); a dropped call does not stop the search.
    pub async fn find_reflector(&self, approx_distance_mm: f64) -> Result<(), EmsconError> {
        self.simple(
            Command::FindReflector {
                approx_distance: approx_distance_mm,
            },
            self.config.search_timeout,
            Ctx::Search,
            "FindReflector reply",
        )
        .await
        .map(drop)
    }

    /// GoLastMeasuredPoint (62); failure codes in the beam-break set map to `TargetNotFound`.
    /// Cancel-safe (see [`Client`]); a dropped call does not stop the beam moving.
    pub async fn go_last_measured_point(&self) -> Result<(), EmsconError> {
        self.simple(
            Command::GoLastMeasuredPoint,
            self.config.search_timeout,
            Ctx::Search,
            "GoLastMeasuredPoint reply",
        )
        .await
        .map(drop)
    }

    /// GoPosition (55): point the beam at `xyz_mm` (tracker frame, mm as set up by the client),
    /// measuring the distance with the ADM on arrival when `use_adm`. OK means the tracker
    /// pointed there, not that it locked on: check GetMeasurementStatusInfo. Cancel-safe (see
    /// [`Client`]).
    pub async fn go_position(&self, xyz_mm: [f64; 3], use_adm: bool) -> Result<(), EmsconError> {
        let [x, y, z] = xyz_mm;
        self.simple(
            Command::GoPosition { x, y, z, use_adm },
            self.config.search_timeout,
            Ctx::Search,
            "GoPosition reply",
        )
        .await
        .map(drop)
    }

    /// StopMeasurement (52).
    /// Cancel-safe (see [`Client`]).
    pub async fn stop_measurement(&self) -> Result<(), EmsconError> {
        self.simple(
            Command::StopMeasurement,
            self.config.command_timeout,
            Ctx::Plain,
            "StopMeasurement reply",
        )
        .await
        .map(drop)
    }

    /// ClearCommandQueue (130) with `ES_CCQ_ClearOwnOnly`.
    /// Cancel-safe (see [`Client`]).
    pub async fn clear_command_queue(&self) -> Result<(), EmsconError> {
        self.simple(
            Command::ClearCommandQueue(0),
            self.config.command_timeout,
            Ctx::Plain,
            "ClearCommandQueue reply",
        )
        .await
        .map(drop)
    }

    /// Stationary measurement: optional ReflectorFound check, StartMeasurement, then the RT
    /// and the result in either order (or the result alone); timeout = measuring time + margin.
    /// Cancel-safe (see [`Client`]): a drop once StartMeasurement went out closes the connection,
    /// so the abandoned result can never pass for the next one.
    pub async fn measure_stationary(&self) -> Result<Measurement, EmsconError> {
        let mut op = self.begin().await?;
        if self.config.check_reflector_before_measure {
            let info = Self::measurement_status_op(&mut op).await?;
            if !info.reflector_found() {
                debug!("emscon: ReflectorFound bit cleared before measurement");
                return Err(EmsconError::BeamBroken);
            }
        }
        let meas_time_ms = op
            .st
            .meas_time_ms
            .unwrap_or(self.config.default_meas_time_ms);
        let meas_time = Duration::from_millis(u64::try_from(meas_time_ms.max(0)).unwrap_or(0));
        let sent_at = SystemTime::now();
        op.send(&Command::StartMeasurement).await?;
        op.wire = Wire::Measuring;
        let deadline = Instant::now() + meas_time + self.config.measure_margin;
        let mut rt_seen = false;
        let res = self
            .await_measurement(&mut op, deadline, &mut rt_seen, sent_at, meas_time_ms)
            .await;
        if matches!(res, Err(EmsconError::Timeout { .. })) {
            // The measurement may still be under way: its late result could pass for the next
            // measurement's. The op stays `Measuring`, so dropping it closes the connection.
            return res;
        }
        op.wire = Wire::Idle;
        if res.is_err() || !rt_seen {
            // A late StartMeasurement reply must not confuse the next command.
            op.st.mark_stale(cmd::START_MEASUREMENT);
        }
        res
    }

    /// Cancel-safe: it only reads routed packets; `measure_stationary` marks the op `Measuring` so
    /// that a drop closes the connection.
    async fn await_measurement(
        &self,
        op: &mut Op<'_>,
        deadline: Instant,
        rt_seen: &mut bool,
        sent_at: SystemTime,
        meas_time_ms: i32,
    ) -> Result<Measurement, EmsconError> {
        let id = cmd::START_MEASUREMENT;
        let measure_error = |op: &Op<'_>, command: i32, st: i32| -> EmsconError {
            match op.map_status(command, st, Ctx::Measure) {
                EmsconError::Device { .. }
                    if self.config.error_during_measurement_is_beam_break =>
                {
                    EmsconError::BeamBroken
                }
                other => other,
            }
        };
        loop {
            let what = if *rt_seen {
                "measurement result"
            } else {
                "StartMeasurement reply"
            };
            let item = op.recv(deadline, what).await?;
            let (val, std, std_total, covariance, meteo, st) = match item {
                Incoming::Closed(r) => return Err(r.to_error()),
                Incoming::Bad(e) => return Err(EmsconError::Protocol(e.to_string())),
                Incoming::Packet(ServerPacket::Reply(rep)) => {
                    if rep.command == id {
                        if rep.status != status::ALL_OK {
                            *rt_seen = true;
                            return Err(op.map_status(id, rep.status, Ctx::Measure));
                        }
                        *rt_seen = true;
                        continue;
                    }
                    if op.is_ignorable_late_reply(&rep) {
                        continue;
                    }
                    return Err(EmsconError::Protocol(format!(
                        "reply for command {} while waiting for a measurement",
                        rep.command
                    )));
                }
                Incoming::Packet(ServerPacket::Error(e)) => {
                    warn!("emscon: error packet during measurement: {e:?}");
                    return Err(measure_error(op, e.command, e.status));
                }
                Incoming::Packet(ServerPacket::StatusChange(code)) => {
                    if code == status_change::MEAS_STATUS_NOT_READY
                        && self.config.not_ready_during_measurement_is_beam_break
                    {
                        return Err(EmsconError::BeamBroken);
                    }
                    continue;
                }
                Incoming::Packet(ServerPacket::SingleMeasResult(m)) => (
                    m.val,
                    m.std,
                    m.std_total,
                    None,
                    [m.temperature, m.pressure, m.humidity],
                    m.status,
                ),
                Incoming::Packet(ServerPacket::SingleMeasResult2(m)) => (
                    m.val,
                    m.std,
                    m.std_total,
                    Some(m.covar),
                    [m.temperature, m.pressure, m.humidity],
                    m.status,
                ),
                Incoming::Packet(_) => continue,
            };
            let received_at = SystemTime::now();
            if st != status::ALL_OK {
                return Err(op.map_status(id, st, Ctx::Measure));
            }
            let finite = all_finite(&val)
                && all_finite(&std)
                && all_finite(&[std_total])
                && all_finite(&meteo)
                && covariance.is_none_or(|c| all_finite(&c));
            if !finite {
                return Err(EmsconError::Protocol(
                    "measurement result contains NaN or infinite values".into(),
                ));
            }
            return Ok(Measurement {
                x_mm: val[0],
                y_mm: val[1],
                z_mm: val[2],
                std_mm: std,
                std_total_mm: std_total,
                covariance,
                temperature_c: meteo[0],
                pressure_mbar: meteo[1],
                humidity_pct: meteo[2],
                sent_at,
                received_at,
                meas_time_ms,
            });
        }
    }

    /// The DEVICES.md §1.4 sequence: status; units mm/deg; Initialize only if the tracker
    /// processor is not initialised; stationary mode; params; RHR; reflector; unsolicited on.
    /// Returns the system status read at the end.
    /// Cancel-safe per step (see [`Client`]); a drop leaves the tracker part-way through the setup,
    /// so run it again from the start.
    pub async fn setup_stationary(
        &self,
        setup: &StationarySetup,
    ) -> Result<SystemStatus, EmsconError> {
        let st = self.system_status().await?;
        self.set_units_mm_deg().await?;
        if !st.is_initialized() {
            debug!(
                "emscon: tracker processor status {}, initialising",
                st.tracker_processor_status
            );
            self.initialize().await?;
        }
        self.set_measurement_mode_stationary().await?;
        self.set_stationary_params(setup.meas_time_ms, setup.use_adm)
            .await?;
        self.set_coordinate_system_rhr().await?;
        let reflector = match setup.reflector_id {
            Some(id) => Some(id),
            None => {
                let list = self.reflectors().await?;
                list.iter()
                    .find(|r| r.target_type == TARGET_TYPE_RRR15)
                    .or(list.first())
                    .map(|r| r.id)
            }
        };
        if let Some(id) = reflector {
            self.set_reflector(id).await?;
        }
        let settings = SystemSettings {
            send_unsolicited_messages: true,
            ..setup.settings
        };
        self.set_system_settings(settings).await?;
        self.system_status().await
    }
}
