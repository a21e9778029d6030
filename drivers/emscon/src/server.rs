//! Simulator-side emScon server: accepts one client at a time on a bound listener, keeps
//! per-connection settings, asks a [`TrackerBackend`] for the physics and injects faults
//! from a shared [`FaultConfig`].
//!
//! Units: lengths in m, mm and µm are converted from the backend's mm; any other length,
//! temperature, pressure (except mbar/hPa) or humidity unit is answered with WrongParameter (3).

use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::OwnedWriteHalf;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinSet;
use tokio::time::Instant;
use tracing::{debug, info, warn};

use crate::backend::{BackendMeasurement, BackendPoint, TrackerBackend};
use crate::codec::{
    CodecError, Command, ErrorResponse, FrameDecoder, ReflectorPosResult, Reply, ReplyBody,
    ServerPacket, SingleMeasResult, SingleMeasResult2,
};
use crate::fault::{take, FaultConfig, Malformed, SharedFaults};
use crate::types::{
    cmd, data_type, status, status_change, Environment, MeasurementStatusInfo, SystemSettings,
    SystemStatus, Units, COORD_SYS_RHR, MEAS_MODE_STATIONARY, TPS_COMPENSATION_SET,
    TPS_INITIALIZED,
};

/// Server options that are not faults.
#[derive(Debug, Clone)]
pub struct ServerOptions {
    /// How long a new connection waits for the previous one to end before being refused.
    pub busy_grace: Duration,
    /// Timeout for each socket write.
    pub write_timeout: Duration,
    /// How long shutdown waits for connection tasks.
    pub shutdown_timeout: Duration,
    /// Reported emScon version.
    pub version: [i32; 3],
    /// Simulated measuring time = the client's measuring time × this factor (1 = real time;
    /// 0 = instant, for benchmarks of the orchestration around the tracker).
    pub measuring_time_scale: f64,
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions {
            busy_grace: Duration::from_millis(250),
            write_timeout: Duration::from_secs(10),
            shutdown_timeout: Duration::from_secs(2),
            version: [3, 6, 0],
            measuring_time_scale: 1.0,
        }
    }
}

/// Physical tracker state shared by all connections.
#[derive(Debug)]
struct Tracker {
    initialized: bool,
    /// `None`: locked; `Some(None)`: broken until a search; `Some(Some(t))`: re-locks at `t`.
    broken: Option<Option<Instant>>,
    /// Where the last measured point was (mm), the target of GoLastMeasuredPoint.
    last_point_mm: Option<[f64; 3]>,
}

impl Tracker {
    fn locked(&mut self) -> bool {
        match self.broken {
            None => true,
            Some(Some(t)) if Instant::now() >= t => {
                self.broken = None;
                true
            }
            _ => false,
        }
    }
    fn break_beam(&mut self, relock_after_ms: Option<u64>) {
        self.broken = Some(relock_after_ms.map(|ms| Instant::now() + Duration::from_millis(ms)));
    }
}

struct Ctx {
    backend: Arc<dyn TrackerBackend>,
    faults: SharedFaults,
    tracker: Mutex<Tracker>,
    options: ServerOptions,
}

impl Ctx {
    fn faults(&self) -> MutexGuard<'_, FaultConfig> {
        self.faults.lock().unwrap_or_else(|p| p.into_inner())
    }
    fn tracker(&self) -> MutexGuard<'_, Tracker> {
        self.tracker.lock().unwrap_or_else(|p| p.into_inner())
    }
    fn reflector_found(&self) -> bool {
        let visible = self.backend.reflector_found();
        visible && self.tracker().locked()
    }
}

/// Runs the server until `shutdown` completes, with default [`ServerOptions`].
/// Cancel-safe like [`serve_with_options`].
pub async fn serve(
    listener: TcpListener,
    backend: Arc<dyn TrackerBackend>,
    faults: SharedFaults,
    shutdown: impl Future,
) -> std::io::Result<()> {
    serve_with_options(
        listener,
        backend,
        faults,
        ServerOptions::default(),
        shutdown,
    )
    .await
}

/// Runs the server until `shutdown` completes; connected clients get status change 998.
/// Cancel-safe: dropping it drops the listener and aborts every connection task, so clients see
/// their socket close instead of status change 998.
pub async fn serve_with_options(
    listener: TcpListener,
    backend: Arc<dyn TrackerBackend>,
    faults: SharedFaults,
    options: ServerOptions,
    shutdown: impl Future,
) -> std::io::Result<()> {
    let ctx = Arc::new(Ctx {
        tracker: Mutex::new(Tracker {
            initialized: backend.initialized(),
            broken: None,
            last_point_mm: None,
        }),
        backend,
        faults,
        options,
    });
    let slot = Arc::new(Semaphore::new(1));
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut tasks = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            res = listener.accept() => {
                let (stream, peer) = match res {
                    Ok(v) => v,
                    Err(e) => {
                        warn!("emscon server: accept failed: {e}");
                        tokio::time::sleep(Duration::from_millis(10)).await;
                        continue;
                    }
                };
                debug!("emscon server: connection from {peer}");
                let ctx = ctx.clone();
                let slot = slot.clone();
                let stop = stop_rx.clone();
                tasks.spawn(async move {
                    let permit = tokio::time::timeout(
                        ctx.options.busy_grace,
                        slot.acquire_owned(),
                    )
                    .await;
                    match permit {
                        Ok(Ok(permit)) => {
                            let _ = stream.set_nodelay(true);
                            if let Err(e) = handle_connection(stream, &ctx, stop).await {
                                debug!("emscon server: connection ended: {e}");
                            }
                            drop(permit);
                        }
                        _ => refuse(stream, &ctx).await,
                    }
                });
            }
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
        }
    }
    let _ = stop_tx.send(true);
    let grace = ctx.options.shutdown_timeout;
    let drained =
        tokio::time::timeout(grace, async { while tasks.join_next().await.is_some() {} }).await;
    if drained.is_err() {
        tasks.abort_all();
    }
    info!("emscon server stopped");
    Ok(())
}

/// Refuses a second client: Error packet 10011, then close.
/// Cancel-safe: the connection is being refused anyway; a drop only closes it sooner.
async fn refuse(mut stream: TcpStream, ctx: &Ctx) {
    warn!("emscon server: refusing second client (10011)");
    let pkt = ServerPacket::Error(ErrorResponse {
        command: cmd::UNKNOWN,
        status: status::MULTI_CONNECTIONS_NOT_ALLOWED,
    })
    .to_bytes();
    let _ = tokio::time::timeout(ctx.options.write_timeout, async {
        stream.write_all(&pkt).await?;
        stream.shutdown().await
    })
    .await;
}

/// Control flow after handling a command.
#[derive(Debug, PartialEq, Eq)]
enum Flow {
    Continue,
    Close,
}

/// Packet writer applying the stream-shaping faults.
struct Out<'a> {
    wr: OwnedWriteHalf,
    batch: Vec<u8>,
    coalesce: bool,
    dribble: bool,
    ctx: &'a Ctx,
}

impl Out<'_> {
    fn shape(&mut self) {
        let f = self.ctx.faults();
        self.coalesce = f.coalesce;
        self.dribble = f.dribble;
    }

    /// Not cancel-safe: a drop mid-write leaves a partial packet; it only runs inside a connection
    /// task, which is dropped with its socket.
    async fn raw(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let timeout = self.ctx.options.write_timeout;
        let res = tokio::time::timeout(timeout, async {
            if self.dribble {
                for b in bytes {
                    self.wr.write_all(std::slice::from_ref(b)).await?;
                    self.wr.flush().await?;
                    tokio::task::yield_now().await;
                }
                Ok(())
            } else {
                self.wr.write_all(bytes).await?;
                self.wr.flush().await
            }
        })
        .await;
        match res {
            Ok(r) => r,
            Err(_) => Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "write timed out",
            )),
        }
    }

    /// Not cancel-safe: a drop mid-write leaves a partial packet (see [`Out::raw`]); only dropped
    /// with the connection.
    async fn bytes(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        if self.coalesce {
            self.batch.extend_from_slice(bytes);
            Ok(())
        } else {
            self.raw(bytes).await
        }
    }

    /// Not cancel-safe: a drop mid-write leaves a partial packet (see [`Out::raw`]); only dropped
    /// with the connection.
    async fn packet(&mut self, p: &ServerPacket) -> std::io::Result<()> {
        self.bytes(&p.to_bytes()).await
    }

    /// Not cancel-safe: the batch is taken before the write, so a drop loses it; only dropped with
    /// the connection.
    async fn flush_batch(&mut self) -> std::io::Result<()> {
        if self.batch.is_empty() {
            return Ok(());
        }
        let batch = std::mem::take(&mut self.batch);
        self.raw(&batch).await
    }
}

/// Per-connection settings.
#[derive(Debug)]
struct Conn {
    units: Units,
    scale: f64,
    environment: Environment,
    meas_time_ms: i32,
    use_adm: bool,
    reflector_id: i32,
    settings: SystemSettings,
    extended: bool,
    last_status: i32,
}

impl Default for Conn {
    fn default() -> Self {
        Conn {
            units: Units::MM_DEG,
            scale: 1.0,
            environment: Environment {
                temperature: 20.0,
                pressure: 1013.25,
                humidity: 45.0,
            },
            meas_time_ms: 1000,
            use_adm: true,
            reflector_id: 1,
            settings: SystemSettings::default(),
            extended: false,
            last_status: status::ALL_OK,
        }
    }
}

/// Cancel-safe as a whole: it owns the socket, so a drop (server shutdown grace expired) closes the
/// connection; inside, only the read is raced against shutdown, never a command.
async fn handle_connection(
    stream: TcpStream,
    ctx: &Ctx,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<()> {
    let (mut rd, wr) = stream.into_split();
    let mut out = Out {
        wr,
        batch: Vec::new(),
        coalesce: false,
        dribble: false,
        ctx,
    };
    let mut conn = Conn::default();
    let mut dec = FrameDecoder::new();
    let mut buf = vec![0u8; 4096];
    loop {
        let n = tokio::select! {
            _ = stop.changed() => {
                out.coalesce = false;
                out.dribble = false;
                let _ = out
                    .packet(&ServerPacket::StatusChange(status_change::SERVER_CLOSING))
                    .await;
                let _ = out.wr.shutdown().await;
                return Ok(());
            }
            r = rd.read(&mut buf) => r?,
        };
        if n == 0 {
            return Ok(());
        }
        dec.push(buf.get(..n).unwrap_or(&[]));
        loop {
            let flow = match dec.next_packet::<Command>() {
                Ok(None) => break,
                Ok(Some(command)) => {
                    out.shape();
                    let flow = handle_command(ctx, &mut conn, &mut out, command).await?;
                    out.flush_batch().await?;
                    flow
                }
                Err(e) => bad_command(&mut out, e).await?,
            };
            if flow == Flow::Close {
                let _ = out.wr.shutdown().await;
                return Ok(());
            }
        }
    }
}

/// Not cancel-safe: a drop mid-write leaves a partial packet; only dropped with the connection.
async fn bad_command(out: &mut Out<'_>, e: CodecError) -> std::io::Result<Flow> {
    warn!("emscon server: bad command packet: {e}");
    out.coalesce = false;
    out.dribble = false;
    match e {
        _ if e.is_fatal() => Ok(Flow::Close),
        CodecError::UnknownCommand(c) => {
            out.packet(&ServerPacket::Reply(Reply::ok_with(
                c,
                status::NOT_IMPLEMENTED,
            )))
            .await?;
            Ok(Flow::Continue)
        }
        CodecError::SizeMismatch {
            command: Some(c), ..
        } => {
            out.packet(&ServerPacket::Reply(Reply::failed(
                c,
                status::WRONG_PARAMETER,
            )))
            .await?;
            Ok(Flow::Continue)
        }
        _ => {
            out.packet(&ServerPacket::Error(ErrorResponse {
                command: cmd::UNKNOWN,
                status: status::NOT_IMPLEMENTED,
            }))
            .await?;
            Ok(Flow::Continue)
        }
    }
}

/// Faults that apply on command entry, decided under one lock.
enum Entry {
    Normal,
    Silent,
    Closing,
    Forced(i32),
}

fn entry_fault(ctx: &Ctx, command: i32) -> Entry {
    let mut f = ctx.faults();
    if take(&mut f.closing_then_close) {
        return Entry::Closing;
    }
    if f.no_reply > 0 && f.no_reply_command.is_none_or(|c| c == command) {
        f.no_reply -= 1;
        return Entry::Silent;
    }
    if let Some(fs) = f.forced_status.as_mut() {
        if fs.count > 0 && fs.command.is_none_or(|c| c == command) {
            fs.count -= 1;
            let st = fs.status;
            if fs.count == 0 {
                f.forced_status = None;
            }
            return Entry::Forced(st);
        }
    }
    Entry::Normal
}

/// Sends a reply, applying malformed-packet and mid-packet-disconnect faults.
/// Not cancel-safe: the reply status is recorded and fault budgets are spent before the write; only
/// dropped with the connection.
async fn emit_reply(
    ctx: &Ctx,
    conn: &mut Conn,
    out: &mut Out<'_>,
    rep: Reply,
) -> std::io::Result<Flow> {
    conn.last_status = rep.status;
    let (malformed, cut) = {
        let mut f = ctx.faults();
        let m = match f.malformed.front() {
            Some(Malformed::NanResult) | None => None,
            Some(_) => f.malformed.pop_front(),
        };
        (m, take(&mut f.disconnect_mid_packet))
    };
    let mut bytes = ServerPacket::Reply(rep.clone()).to_bytes();
    if let Some(m) = malformed {
        warn!("emscon server: injecting malformed packet {m:?}");
        bytes = malformed_bytes(m, &rep);
    }
    if cut {
        warn!("emscon server: disconnecting mid-packet");
        let half = bytes.len() / 2;
        out.bytes(bytes.get(..half).unwrap_or(&[])).await?;
        out.flush_batch().await?;
        return Ok(Flow::Close);
    }
    out.bytes(&bytes).await?;
    Ok(Flow::Continue)
}

fn malformed_bytes(m: Malformed, rep: &Reply) -> Vec<u8> {
    let header = |size: i32, ty: i32| {
        let mut v = size.to_le_bytes().to_vec();
        v.extend_from_slice(&ty.to_le_bytes());
        v
    };
    match m {
        Malformed::SizeTooSmall => header(4, data_type::COMMAND),
        Malformed::SizeTooLarge => {
            let mut v = header(1 << 20, data_type::COMMAND);
            v.extend_from_slice(&rep.command.to_le_bytes());
            v.extend_from_slice(&0i32.to_le_bytes());
            v
        }
        Malformed::SizeMismatch => {
            let mut v = ServerPacket::Reply(rep.clone()).to_bytes();
            v.extend_from_slice(&[0u8; 4]);
            let size = i32::try_from(v.len()).unwrap_or(i32::MAX);
            v[..4].copy_from_slice(&size.to_le_bytes());
            v
        }
        Malformed::UnknownType => {
            let mut v = header(16, 5);
            v.extend_from_slice(&rep.command.to_le_bytes());
            v.extend_from_slice(&0i32.to_le_bytes());
            v
        }
        Malformed::WrongCommandEcho => {
            let other = if rep.command == cmd::CLEAR_COMMAND_QUEUE {
                cmd::STOP_MEASUREMENT
            } else {
                cmd::CLEAR_COMMAND_QUEUE
            };
            ServerPacket::Reply(Reply::ok(other)).to_bytes()
        }
        Malformed::NanResult => ServerPacket::Reply(rep.clone()).to_bytes(),
    }
}

/// Answer one command: an injected entry fault first, then the command's reply (or replies).
/// Not cancel-safe: a drop leaves a command half answered; only dropped with the connection.
async fn handle_command(
    ctx: &Ctx,
    conn: &mut Conn,
    out: &mut Out<'_>,
    command: Command,
) -> std::io::Result<Flow> {
    let id = command.id();
    debug!("emscon server: command {command:?}");
    if let Some(flow) = answer_entry_fault(ctx, conn, out, id).await? {
        return Ok(flow);
    }
    match command {
        Command::Initialize => initialize(ctx, conn, out, id).await,
        Command::GetReflectors => send_reflectors(ctx, conn, out, id).await,
        Command::StartMeasurement => start_measurement(ctx, conn, out).await,
        c => {
            let rep = immediate_reply(ctx, conn, c);
            emit_reply(ctx, conn, out, rep).await
        }
    }
}

/// An injected fault on entry to `command`: swallowed, connection closing, or a forced status
/// (`None`: answer normally).
/// Not cancel-safe: the fault is spent before its packet is written; only dropped with the
/// connection.
async fn answer_entry_fault(
    ctx: &Ctx,
    conn: &mut Conn,
    out: &mut Out<'_>,
    id: i32,
) -> std::io::Result<Option<Flow>> {
    match entry_fault(ctx, id) {
        Entry::Normal => Ok(None),
        Entry::Silent => {
            warn!("emscon server: swallowing command {id}");
            Ok(Some(Flow::Continue))
        }
        Entry::Closing => {
            warn!("emscon server: TPConnectionClosing, closing");
            out.packet(&ServerPacket::StatusChange(
                status_change::TP_CONNECTION_CLOSING,
            ))
            .await?;
            out.flush_batch().await?;
            Ok(Some(Flow::Close))
        }
        Entry::Forced(st) => {
            warn!("emscon server: forcing status {st} on command {id}");
            emit_reply(ctx, conn, out, Reply::failed(id, st))
                .await
                .map(Some)
        }
    }
}

/// Initialize: after the configured delay, the reply and then the initialisation status change.
/// Not cancel-safe: a drop after the delay leaves the tracker initialised without a reply; only
/// dropped with the connection.
async fn initialize(
    ctx: &Ctx,
    conn: &mut Conn,
    out: &mut Out<'_>,
    id: i32,
) -> std::io::Result<Flow> {
    let delay = ctx.faults().initialize_delay_ms;
    tokio::time::sleep(Duration::from_millis(delay)).await;
    ctx.tracker().initialized = true;
    let flow = emit_reply(ctx, conn, out, Reply::ok(id)).await?;
    if flow == Flow::Continue {
        out.packet(&ServerPacket::StatusChange(
            status_change::INITIALIZATION_STATUS_CHANGED,
        ))
        .await?;
    }
    Ok(flow)
}

/// GetReflectors: one reply per reflector (surface offset in the connection's units), each
/// carrying the total; a failed reply when there is none.
/// Not cancel-safe: a drop leaves part of the reply list written; only dropped with the connection.
async fn send_reflectors(
    ctx: &Ctx,
    conn: &mut Conn,
    out: &mut Out<'_>,
    id: i32,
) -> std::io::Result<Flow> {
    let list = ctx.backend.reflectors();
    if list.is_empty() {
        return emit_reply(ctx, conn, out, Reply::failed(id, status::ALL_OK)).await;
    }
    let total = i32::try_from(list.len()).unwrap_or(i32::MAX);
    let mut flow = Flow::Continue;
    for mut r in list {
        r.total = total;
        r.surface_offset *= conn.scale;
        let rep = Reply {
            command: id,
            status: status::ALL_OK,
            body: ReplyBody::Reflector(r),
        };
        flow = emit_reply(ctx, conn, out, rep).await?;
        if flow == Flow::Close {
            break;
        }
    }
    Ok(flow)
}

/// The single reply of a command answered at once (settings, queries, beam moves).
fn immediate_reply(ctx: &Ctx, conn: &mut Conn, command: Command) -> Reply {
    let id = command.id();
    let wrong = || Reply::failed(id, status::WRONG_PARAMETER);
    let ok_with = |body| Reply {
        command: id,
        status: status::ALL_OK,
        body,
    };
    match command {
        Command::GetSystemStatus => ok_with(ReplyBody::SystemStatus(system_status(ctx, conn))),
        Command::SetUnits(u) => {
            if set_units(conn, u) {
                Reply::ok(id)
            } else {
                wrong()
            }
        }
        Command::GetUnits => ok_with(ReplyBody::Units(conn.units)),
        Command::SetEnvironmentParams(e) => {
            conn.environment = e;
            Reply::ok(id)
        }
        Command::GetEnvironmentParams => ok_with(ReplyBody::Environment(conn.environment)),
        Command::SetMeasurementMode(m) if m == MEAS_MODE_STATIONARY => Reply::ok(id),
        Command::SetMeasurementMode(_) => wrong(),
        Command::SetCoordinateSystemType(c) if c == COORD_SYS_RHR => Reply::ok(id),
        Command::SetCoordinateSystemType(_) => wrong(),
        Command::SetStationaryModeParams {
            meas_time_ms,
            use_adm,
        } => {
            if (1..=600_000).contains(&meas_time_ms) {
                conn.meas_time_ms = meas_time_ms;
                conn.use_adm = use_adm;
                Reply::ok(id)
            } else {
                wrong()
            }
        }
        Command::GetStationaryModeParams => ok_with(ReplyBody::StationaryModeParams {
            meas_time_ms: conn.meas_time_ms,
            use_adm: conn.use_adm,
        }),
        Command::SetReflector(r) => {
            if ctx.backend.reflectors().iter().any(|x| x.id == r) {
                conn.reflector_id = r;
                Reply::ok(id)
            } else {
                wrong()
            }
        }
        Command::GetReflector => ok_with(ReplyBody::ReflectorId(conn.reflector_id)),
        Command::SetSystemSettings(s) => {
            conn.settings = s;
            Reply::ok(id)
        }
        Command::GetSystemSettings => ok_with(ReplyBody::SystemSettings(conn.settings)),
        Command::SetStatisticMode { stationary, .. } if (0..=1).contains(&stationary) => {
            conn.extended = stationary == 1;
            Reply::ok(id)
        }
        Command::SetStatisticMode { .. } => wrong(),
        Command::GetMeasurementStatusInfo => ok_with(ReplyBody::MeasurementStatusInfo {
            last_result_status: conn.last_status,
            info: measurement_status(ctx),
        }),
        Command::GetObjectTemperature => ok_with(ReplyBody::ObjectTemperature(
            ctx.backend.meteo().temperature_c,
        )),
        c @ (Command::FindReflector { .. }
        | Command::GoLastMeasuredPoint
        | Command::GoPosition { .. }) => search(ctx, conn, &c),
        Command::StopMeasurement
        | Command::ChangeFace
        | Command::GoBirdBath
        | Command::ClearCommandQueue(_) => Reply::ok(id),
        // answered by their own functions in `handle_command`
        Command::Initialize | Command::GetReflectors | Command::StartMeasurement => {
            Reply::failed(id, status::WRONG_PARAMETER)
        }
    }
}

/// The simulated tracker's system status as this connection sees it.
fn system_status(ctx: &Ctx, conn: &Conn) -> SystemStatus {
    SystemStatus {
        last_result_status: conn.last_status,
        tracker_processor_status: if ctx.tracker().initialized {
            TPS_INITIALIZED
        } else {
            TPS_COMPENSATION_SET
        },
        laser_status: 3,
        adm_status: 2,
        version: ctx.options.version,
        weather_monitor_status: conn.settings.weather_monitor_status,
        flags: 0,
        serial_number: ctx.backend.serial_number(),
    }
}

/// Take `u` as the connection's units when the simulator supports them (length mm/m/µm, any
/// angle unit, °C, mbar or hPa, % humidity); `false` leaves them as they were.
fn set_units(conn: &mut Conn, u: Units) -> bool {
    let scale = match u.length {
        0 => 0.001,
        1 => 1.0,
        2 => 1000.0,
        _ => return false,
    };
    let supported = (0..=2).contains(&u.angle)
        && u.temperature == 0
        && (0..=1).contains(&u.pressure)
        && u.humidity == 0;
    if supported {
        conn.units = u;
        conn.scale = scale;
    }
    supported
}

/// The measurement status bits: tracker, compensations, ADM, face 1 and level always; the
/// reflector when the beam is locked on one; initialised after Initialize.
fn measurement_status(ctx: &Ctx) -> MeasurementStatusInfo {
    let mut bits = MeasurementStatusInfo::TRACKER_FOUND
        | MeasurementStatusInfo::TRACKER_COMPENSATION_FOUND
        | MeasurementStatusInfo::ADM_FOUND
        | MeasurementStatusInfo::ADM_COMPENSATION_FOUND
        | MeasurementStatusInfo::IN_FACE1
        | MeasurementStatusInfo::NIVEL_IN_WORKING_RANGE;
    if ctx.reflector_found() {
        bits |= MeasurementStatusInfo::REFLECTOR_FOUND;
    }
    if ctx.tracker().initialized {
        bits |= MeasurementStatusInfo::INITIALIZED;
    }
    MeasurementStatusInfo(bits)
}

/// FindReflector, GoLastMeasuredPoint, GoPosition: the beam goes to the target and locks when
/// a reflector is there (FindReflector searches wherever a reflector is visible;
/// GoLastMeasuredPoint and GoPosition lock only within the backend's capture radius of their
/// point). A command that points but finds nothing still answers OK (`go_last_without_lock`
/// for GoLastMeasuredPoint); the lock shows in GetMeasurementStatusInfo.
fn search(ctx: &Ctx, conn: &Conn, command: &Command) -> Reply {
    let id = command.id();
    let find_fails =
        id == cmd::FIND_REFLECTOR && crate::fault::take(&mut ctx.faults().find_reflector_fails);
    let no_lock = id == cmd::GO_LAST_MEASURED_POINT
        && crate::fault::take(&mut ctx.faults().go_last_without_lock);
    let t = ctx.tracker();
    if !t.initialized {
        return Reply::failed(id, status::TRACKER_NOT_INITIALIZED);
    }
    let target = match command {
        Command::GoLastMeasuredPoint => match t.last_point_mm {
            None => return Reply::failed(id, status::NO_LAST_MEASURED_POINT),
            Some(p) => Some(p),
        },
        Command::GoPosition { x, y, z, .. } => Some([*x, *y, *z].map(|v| v / conn.scale)),
        _ => None,
    };
    drop(t);
    if find_fails || !ctx.backend.reflector_found() {
        return Reply::failed(id, ctx.faults().target_not_found_status);
    }
    let there = target.is_none_or(|p| ctx.backend.reflector_near(p));
    if there && !no_lock {
        ctx.tracker().broken = None;
    }
    Reply::ok(id)
}

/// The last part of a measuring time that is waited on a thread rather than a tokio timer.
const FINE_WAIT: Duration = Duration::from_millis(2);

/// Wait `d` of measuring time to within about 0.1 ms. Tokio timers round up to the next
/// millisecond tick (a 1 ms sleep takes about 2 ms), so the last [`FINE_WAIT`] at most is a
/// thread sleep on the blocking pool.
/// Cancel-safe: it only waits (a thread sleep already started finishes on the blocking pool).
async fn wait_measuring_time(d: Duration) {
    let deadline = Instant::now() + d;
    if d > FINE_WAIT {
        tokio::time::sleep_until(deadline - FINE_WAIT).await;
    }
    let rest = deadline.saturating_duration_since(Instant::now());
    if !rest.is_zero() {
        // A join error can only mean the runtime is shutting down: nothing left to wait for.
        let _ = tokio::task::spawn_blocking(move || std::thread::sleep(rest)).await;
    }
}

/// One measurement's fault plan, taken under one lock.
struct MeasPlan {
    beam_before: bool,
    beam_during: bool,
    rt_without_result: bool,
    result_without_rt: bool,
    result_before_rt: bool,
    interleave: bool,
    beam_status: i32,
    beam_error_status: Option<i32>,
    relock_after_ms: Option<u64>,
}

/// Not cancel-safe: a drop leaves the fault plan spent and the measurement half answered; only
/// dropped with the connection.
async fn start_measurement(ctx: &Ctx, conn: &mut Conn, out: &mut Out<'_>) -> std::io::Result<Flow> {
    let id = cmd::START_MEASUREMENT;
    let plan = {
        let mut f = ctx.faults();
        MeasPlan {
            beam_before: take(&mut f.beam_break_before_measure),
            beam_during: take(&mut f.beam_break_during_measure),
            rt_without_result: take(&mut f.rt_without_result),
            result_without_rt: take(&mut f.result_without_rt),
            result_before_rt: take(&mut f.result_before_rt),
            interleave: f.interleave_unsolicited,
            beam_status: f.beam_break_status,
            beam_error_status: f
                .beam_break_sends_error
                .then_some(f.beam_break_error_status),
            relock_after_ms: f.relock_after_ms,
        }
    };
    if !ctx.tracker().initialized {
        return emit_reply(
            ctx,
            conn,
            out,
            Reply::failed(id, status::TRACKER_NOT_INITIALIZED),
        )
        .await;
    }
    if !ctx.backend.warmed_up() {
        return emit_reply(
            ctx,
            conn,
            out,
            Reply::failed(id, status::SENSOR_NOT_WARMED_UP),
        )
        .await;
    }
    if plan.beam_before {
        warn!("emscon server: beam break before measurement");
        ctx.tracker().break_beam(plan.relock_after_ms);
    }
    if !ctx.reflector_found() {
        return emit_reply(ctx, conn, out, Reply::failed(id, plan.beam_status)).await;
    }
    let meas_time = Duration::from_millis(u64::try_from(conn.meas_time_ms.max(0)).unwrap_or(0))
        .mul_f64(match ctx.options.measuring_time_scale {
            s if s.is_finite() => s.clamp(0.0, 1.0e3),
            _ => 1.0,
        });
    let send_rt_first = !plan.result_without_rt && !plan.result_before_rt;
    if send_rt_first && emit_reply(ctx, conn, out, Reply::ok(id)).await? == Flow::Close {
        return Ok(Flow::Close);
    }
    if plan.beam_during {
        warn!("emscon server: beam break during measurement");
        wait_measuring_time(meas_time / 2).await;
        return beam_lost(ctx, out, plan.beam_error_status, plan.relock_after_ms).await;
    }
    if plan.interleave {
        out.packet(&ServerPacket::StatusChange(status_change::MEAS_STATUS_BUSY))
            .await?;
        out.packet(&ServerPacket::ReflectorPos(ReflectorPosResult {
            status: status::ALL_OK,
            val: [0.0; 3],
        }))
        .await?;
    }
    wait_measuring_time(meas_time).await;
    let point = match ctx.backend.measure(conn.meas_time_ms) {
        BackendMeasurement::Point(p) => p,
        BackendMeasurement::TargetLost => {
            return beam_lost(ctx, out, plan.beam_error_status, plan.relock_after_ms).await;
        }
    };
    if plan.rt_without_result {
        warn!("emscon server: withholding measurement result");
        return Ok(Flow::Continue);
    }
    let nan = {
        let mut f = ctx.faults();
        if f.malformed.front() == Some(&Malformed::NanResult) {
            f.malformed.pop_front();
            true
        } else {
            false
        }
    };
    let result = result_packet(&point, conn, nan);
    ctx.tracker().last_point_mm = Some(point.xyz_mm);
    out.packet(&result).await?;
    if plan.result_before_rt {
        return emit_reply(ctx, conn, out, Reply::ok(id)).await;
    }
    if plan.result_without_rt {
        conn.last_status = status::ALL_OK;
    }
    Ok(Flow::Continue)
}

/// Not cancel-safe: the beam is broken before the packets are written; only dropped with the
/// connection.
async fn beam_lost(
    ctx: &Ctx,
    out: &mut Out<'_>,
    error_status: Option<i32>,
    relock_after_ms: Option<u64>,
) -> std::io::Result<Flow> {
    ctx.tracker().break_beam(relock_after_ms);
    if let Some(status) = error_status {
        out.packet(&ServerPacket::Error(ErrorResponse {
            command: cmd::START_MEASUREMENT,
            status,
        }))
        .await?;
    }
    out.packet(&ServerPacket::StatusChange(
        status_change::MEAS_STATUS_NOT_READY,
    ))
    .await?;
    Ok(Flow::Continue)
}

fn result_packet(p: &BackendPoint, conn: &Conn, nan: bool) -> ServerPacket {
    let s = conn.scale;
    let mut val = p.xyz_mm.map(|v| v * s);
    if nan {
        val[0] = f64::NAN;
    }
    let std = p.std_mm.map(|v| v * s);
    let std_total = p.std_total_mm * s;
    if conn.extended {
        ServerPacket::SingleMeasResult2(SingleMeasResult2 {
            status: status::ALL_OK,
            meas_mode: MEAS_MODE_STATIONARY,
            is_try_mode: false,
            val,
            std,
            std_total,
            covar: [0.0; 3],
            pointing_error: [0.0; 3],
            apriori_std: std,
            apriori_std_total: std_total,
            apriori_covar: [0.0; 3],
            temperature: p.meteo.temperature_c,
            pressure: p.meteo.pressure_mbar,
            humidity: p.meteo.humidity_pct,
        })
    } else {
        ServerPacket::SingleMeasResult(SingleMeasResult {
            status: status::ALL_OK,
            meas_mode: MEAS_MODE_STATIONARY,
            is_try_mode: false,
            val,
            std,
            std_total,
            pointing_error: [0.0; 3],
            apriori_std: std,
            apriori_std_total: std_total,
            temperature: p.meteo.temperature_c,
            pressure: p.meteo.pressure_mbar,
            humidity: p.meteo.humidity_pct,
        })
    }
}
