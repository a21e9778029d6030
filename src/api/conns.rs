//! The open connections of [`super::serve`]: every accepted TCP connection is tracked from its
//! accept to its close, so that no client can take the descriptors a new request needs.
//!
//! - **A cap with headroom.** At most [`ServeLimits::max_connections`] are open, a number below
//!   the process's descriptor limit by [`RESERVED_DESCRIPTORS`] (the store, the devices, the
//!   simulated cell). A connection accepted beyond the cap closes the one idle the longest (no
//!   request in flight), else the oldest that never authenticated; only when every open
//!   connection is an authenticated request in flight is the new one refused. So a new
//!   request (an ABORT) always gets a descriptor and a turn, however many idle or anonymous
//!   connections a client opens.
//! - **Timeouts.** A connection idle longer than [`ServeLimits::idle_timeout`] is closed;
//!   HTTP/1 request heads (and the first request of a connection, the TLS handshake included)
//!   must arrive within [`ServeLimits::header_read_timeout`] (hyper's and axum-server's timers,
//!   set by [`super::serve`]).
//! - **Failed accepts** are logged (at most once per [`LOG_EVERY`], with the count since) and
//!   never spin: axum-server backs off 50 ms; on `EMFILE`/`ENFILE` the idlest connection is
//!   closed to free a descriptor.
//!
//! "In flight" means from the request's dispatch until its response body is dropped (an event
//! stream is in flight while it is open).

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};
use std::time::{Duration, Instant};

use axum::http::{Request, Response};
use axum_server::accept::Accept;
use hyper::body::{Body, Frame, SizeHint};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Default [`ServeLimits::header_read_timeout`].
pub const HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);
/// Default [`ServeLimits::idle_timeout`].
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// Most connections open at once, whatever the descriptor limit.
pub const MAX_CONNECTIONS: usize = 512;
/// Descriptors kept free of connections: the store, the devices, the simulated cell, logs.
pub const RESERVED_DESCRIPTORS: u64 = 64;
/// Fewest connections allowed, whatever the descriptor limit.
const MIN_CONNECTIONS: usize = 16;
/// Env var overriding [`ServeLimits::header_read_timeout`] in ms (tests).
pub const HEADER_READ_TIMEOUT_ENV: &str = "CELLCAL_HEADER_READ_TIMEOUT_MS";
/// Env var overriding [`ServeLimits::idle_timeout`] in ms (tests).
pub const IDLE_TIMEOUT_ENV: &str = "CELLCAL_IDLE_TIMEOUT_MS";
/// Shortest interval between two log lines about failed accepts or closed connections.
pub const LOG_EVERY: Duration = Duration::from_secs(10);

/// How long connections may wait and how many may be open (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServeLimits {
    /// Time for a request head to arrive (HTTP/1: from the moment the server waits for one,
    /// keep-alive waits included), and for the first request after the accept.
    pub header_read_timeout: Duration,
    /// A connection without a request in flight this long is closed (any protocol).
    pub idle_timeout: Duration,
    /// Most connections open at once.
    pub max_connections: usize,
}

/// A limit from the environment that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{name}: `{value}` is not a positive whole number of milliseconds")]
pub struct LimitError {
    /// The variable.
    pub name: &'static str,
    /// Its value.
    pub value: String,
}

impl ServeLimits {
    /// The defaults for a process allowed `descriptors` open files: the cap is
    /// `descriptors − RESERVED_DESCRIPTORS`, at most [`MAX_CONNECTIONS`], at least 16.
    pub fn for_descriptors(descriptors: u64) -> ServeLimits {
        let room =
            usize::try_from(descriptors.saturating_sub(RESERVED_DESCRIPTORS)).unwrap_or(usize::MAX);
        ServeLimits {
            header_read_timeout: HEADER_READ_TIMEOUT,
            idle_timeout: IDLE_TIMEOUT,
            max_connections: room.clamp(MIN_CONNECTIONS, MAX_CONNECTIONS),
        }
    }

    /// [`ServeLimits::for_descriptors`] with [`HEADER_READ_TIMEOUT_ENV`] and
    /// [`IDLE_TIMEOUT_ENV`] applied when set.
    pub fn from_env(descriptors: u64) -> Result<ServeLimits, LimitError> {
        let mut l = ServeLimits::for_descriptors(descriptors);
        if let Some(d) = env_ms(HEADER_READ_TIMEOUT_ENV)? {
            l.header_read_timeout = d;
        }
        if let Some(d) = env_ms(IDLE_TIMEOUT_ENV)? {
            l.idle_timeout = d;
        }
        Ok(l)
    }
}

/// A positive number of milliseconds from the environment variable `name`, if set.
fn env_ms(name: &'static str) -> Result<Option<Duration>, LimitError> {
    match std::env::var(name) {
        Err(_) => Ok(None),
        Ok(v) => match v.trim().parse::<u64>() {
            Ok(ms) if ms > 0 => Ok(Some(Duration::from_millis(ms))),
            _ => Err(LimitError { name, value: v }),
        },
    }
}

/// Connections the kernel completes and queues for [`listen`]'s socket before they are
/// accepted (capped by `net.core.somaxconn`): a burst of new connections must not fill the
/// queue, or a newcomer's SYN is dropped and it waits a second for the retransmission.
pub const ACCEPT_BACKLOG: u32 = 1024;

/// A listening socket on `addr` with an accept queue of [`ACCEPT_BACKLOG`] (std's `bind` has
/// 128). Must be called within a tokio runtime.
pub fn listen(addr: std::net::SocketAddr) -> std::io::Result<std::net::TcpListener> {
    let socket = if addr.is_ipv4() {
        tokio::net::TcpSocket::new_v4()?
    } else {
        tokio::net::TcpSocket::new_v6()?
    };
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(ACCEPT_BACKLOG)?.into_std()
}

/// Raise this process's soft limit of open files to its hard limit; the limit now in force.
pub fn raise_descriptor_limit() -> std::io::Result<u64> {
    use nix::sys::resource::{getrlimit, setrlimit, Resource};
    let (soft, hard) = getrlimit(Resource::RLIMIT_NOFILE).map_err(std::io::Error::from)?;
    if soft < hard && setrlimit(Resource::RLIMIT_NOFILE, hard, hard).is_ok() {
        return Ok(hard);
    }
    Ok(soft)
}

/// At most one log line per [`LOG_EVERY`]; counts what it held back.
#[derive(Debug, Default)]
struct Throttle {
    last: Option<Instant>,
    held: u64,
}

impl Throttle {
    /// `Some(n)` (n events held back since the last line) when a line may be logged now.
    fn pass(&mut self, now: Instant) -> Option<u64> {
        if self.last.is_some_and(|t| now.duration_since(t) < LOG_EVERY) {
            self.held += 1;
            return None;
        }
        self.last = Some(now);
        Some(std::mem::take(&mut self.held))
    }
}

/// One open connection.
#[derive(Debug)]
pub(crate) struct Slot {
    id: u64,
    accepted: Instant,
    closed: AtomicBool,
    state: Mutex<SlotState>,
}

#[derive(Debug)]
struct SlotState {
    in_flight: usize,
    /// Since when no request is in flight (the accept for a new connection).
    idle_since: Instant,
    /// A request on it passed the token check.
    authenticated: bool,
    /// Tasks waiting on its socket, woken when it is closed.
    read_waker: Option<Waker>,
    write_waker: Option<Waker>,
}

/// Lock `m`, also when another thread panicked holding it (the data stay consistent: every
/// update is a single assignment).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Slot {
    /// Close it: its socket's next read or write fails, so hyper drops the connection.
    fn close(&self) {
        self.closed.store(true, Ordering::SeqCst);
        let (r, w) = {
            let mut s = lock(&self.state);
            (s.read_waker.take(), s.write_waker.take())
        };
        for waker in [r, w].into_iter().flatten() {
            waker.wake();
        }
    }

    fn is_closed(&self) -> bool {
        self.closed.load(Ordering::SeqCst)
    }

    /// A request was dispatched; in flight until the guard drops.
    fn begin(self: &Arc<Self>) -> InFlight {
        lock(&self.state).in_flight += 1;
        InFlight(Arc::clone(self))
    }
}

/// A request in flight on a connection (see the module doc).
#[derive(Debug)]
pub(crate) struct InFlight(Arc<Slot>);

impl Drop for InFlight {
    fn drop(&mut self) {
        let mut s = lock(&self.0.state);
        s.in_flight = s.in_flight.saturating_sub(1);
        if s.in_flight == 0 {
            s.idle_since = Instant::now();
        }
    }
}

/// The connection a request came on, in the request's extensions: the gate marks it
/// authenticated, which protects it from being closed for a newcomer while it is busy.
#[derive(Debug, Clone)]
pub struct Connection(Arc<Slot>);

impl Connection {
    /// A request on this connection passed the token check.
    pub fn authenticated(&self) {
        lock(&self.0.state).authenticated = true;
    }
}

/// Which connection to close for a newcomer, by rank (lower first), then age.
#[derive(Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Victim {
    /// No request in flight, since the instant given.
    Idle(Instant),
    /// A request in flight, never authenticated; accepted at the instant given.
    Anonymous(Instant),
}

/// Every open connection of one server, and its limits.
#[derive(Debug)]
pub(crate) struct Connections {
    limits: ServeLimits,
    inner: Mutex<Table>,
}

#[derive(Debug, Default)]
struct Table {
    next_id: u64,
    open: BTreeMap<u64, Arc<Slot>>,
    closed_for_room: u64,
    evictions: Throttle,
    accept_errors: Throttle,
}

impl Connections {
    /// No connection yet.
    pub(crate) fn new(limits: ServeLimits) -> Connections {
        Connections {
            limits,
            inner: Mutex::new(Table::default()),
        }
    }

    /// How many are open.
    #[cfg(test)]
    fn open(&self) -> usize {
        lock(&self.inner).open.len()
    }

    /// A new connection: tracked, and room made for it (module doc). A connection refused
    /// for lack of room comes back closed.
    fn admit(&self, now: Instant) -> Arc<Slot> {
        let mut t = lock(&self.inner);
        t.next_id += 1;
        let slot = Arc::new(Slot {
            id: t.next_id,
            accepted: now,
            closed: AtomicBool::new(false),
            state: Mutex::new(SlotState {
                in_flight: 0,
                idle_since: now,
                authenticated: false,
                read_waker: None,
                write_waker: None,
            }),
        });
        let live = t.open.values().filter(|s| !s.is_closed()).count();
        if live >= self.limits.max_connections {
            match t.victim() {
                Some(v) => {
                    v.close();
                    t.closed_for_room += 1;
                    if let Some(held) = t.evictions.pass(now) {
                        tracing::warn!(
                            open = live,
                            max = self.limits.max_connections,
                            closed = t.closed_for_room,
                            held_back = held,
                            "connection cap reached: closing idle or anonymous connections for new ones"
                        );
                    }
                }
                None => {
                    slot.close();
                    if let Some(held) = t.evictions.pass(now) {
                        tracing::warn!(
                            open = live,
                            max = self.limits.max_connections,
                            held_back = held,
                            "connection cap reached with every connection busy: new connection refused"
                        );
                    }
                }
            }
        }
        t.open.insert(slot.id, Arc::clone(&slot));
        slot
    }

    /// The connection is gone (its socket dropped).
    fn forget(&self, id: u64) {
        lock(&self.inner).open.remove(&id);
    }

    /// Close every connection idle longer than the idle timeout.
    pub(crate) fn close_idle(&self, now: Instant) {
        let t = lock(&self.inner);
        for s in t.open.values() {
            let st = lock(&s.state);
            let idle =
                st.in_flight == 0 && now.duration_since(st.idle_since) >= self.limits.idle_timeout;
            drop(st);
            if idle && !s.is_closed() {
                s.close();
            }
        }
    }

    /// An accept failed: log it (throttled); on a descriptor shortage close the idlest
    /// connection, so the next accept has a descriptor.
    pub(crate) fn accept_failed(&self, e: &std::io::Error, now: Instant) {
        let mut t = lock(&self.inner);
        if e.raw_os_error().is_some_and(is_descriptor_shortage) {
            if let Some(v) = t.victim() {
                v.close();
                t.closed_for_room += 1;
            }
        }
        if let Some(held) = t.accept_errors.pass(now) {
            tracing::warn!(error = %e, held_back = held, open = t.open.len(), "accepting a connection failed");
        }
    }
}

/// `EMFILE` or `ENFILE`.
fn is_descriptor_shortage(errno: i32) -> bool {
    errno == nix::errno::Errno::EMFILE as i32 || errno == nix::errno::Errno::ENFILE as i32
}

impl Table {
    /// The connection to close for a newcomer: the one idle the longest, else the oldest
    /// anonymous one in flight; `None` when all are authenticated and busy.
    fn victim(&self) -> Option<Arc<Slot>> {
        self.open
            .values()
            .filter(|s| !s.is_closed())
            .filter_map(|s| {
                let st = lock(&s.state);
                let rank = if st.in_flight == 0 {
                    Victim::Idle(st.idle_since)
                } else if !st.authenticated {
                    Victim::Anonymous(s.accepted)
                } else {
                    return None;
                };
                Some((rank, s.id, s))
            })
            .min_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)))
            .map(|(_, _, s)| Arc::clone(s))
    }
}

/// The task closing idle connections (see [`Connections::close_idle`]); it ends when dropped.
pub(crate) struct Reaper(tokio::task::JoinHandle<()>);

impl Reaper {
    /// Check `conns` a few times per idle timeout (at most every second). Must be called within
    /// a tokio runtime.
    pub(crate) fn start(conns: Arc<Connections>) -> Reaper {
        let every = (conns.limits.idle_timeout / 4)
            .clamp(Duration::from_millis(10), Duration::from_secs(1));
        Reaper(tokio::spawn(async move {
            let mut tick = tokio::time::interval(every);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            loop {
                tick.tick().await;
                conns.close_idle(Instant::now());
            }
        }))
    }
}

impl Drop for Reaper {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// The acceptor of [`super::serve`]: tracks each accepted connection (then hands it to
/// `inner`, e.g. TLS).
#[derive(Debug, Clone)]
pub(crate) struct Tracking<A> {
    inner: A,
    conns: Arc<Connections>,
}

impl<A> Tracking<A> {
    pub(crate) fn new(inner: A, conns: Arc<Connections>) -> Tracking<A> {
        Tracking { inner, conns }
    }
}

impl<A, S> Accept<tokio::net::TcpStream, S> for Tracking<A>
where
    A: Accept<Tracked<tokio::net::TcpStream>, TrackedService<S>>,
{
    type Stream = A::Stream;
    type Service = A::Service;
    type Future = A::Future;

    fn accept(&self, stream: tokio::net::TcpStream, service: S) -> A::Future {
        let slot = self.conns.admit(Instant::now());
        let tracked = Tracked {
            inner: stream,
            slot: Arc::clone(&slot),
            conns: Arc::clone(&self.conns),
        };
        self.inner.accept(
            tracked,
            TrackedService {
                inner: service,
                slot,
            },
        )
    }
}

/// A tracked connection's socket: fails every read and write once the connection is closed;
/// forgotten by [`Connections`] when dropped.
#[derive(Debug)]
pub(crate) struct Tracked<T> {
    inner: T,
    slot: Arc<Slot>,
    conns: Arc<Connections>,
}

impl<T> Drop for Tracked<T> {
    fn drop(&mut self) {
        self.conns.forget(self.slot.id);
    }
}

/// The error of a read or write on a closed connection.
fn closed_error() -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::ConnectionAborted,
        "connection closed by the server (idle, or room for a new one)",
    )
}

impl<T> Tracked<T> {
    /// `Err` when closed; else the waker is kept (read or write side) for [`Slot::close`].
    fn check(&self, cx: &Context<'_>, read: bool) -> std::io::Result<()> {
        if self.slot.is_closed() {
            return Err(closed_error());
        }
        let mut s = lock(&self.slot.state);
        let w = if read {
            &mut s.read_waker
        } else {
            &mut s.write_waker
        };
        if !w.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
            *w = Some(cx.waker().clone());
        }
        drop(s);
        // closed between the check and the waker's registration: no wake-up would come
        if self.slot.is_closed() {
            return Err(closed_error());
        }
        Ok(())
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Tracked<T> {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        this.check(cx, true)?;
        Pin::new(&mut this.inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Tracked<T> {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        this.check(cx, false)?;
        Pin::new(&mut this.inner).poll_write(cx, buf)
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        this.check(cx, false)?;
        Pin::new(&mut this.inner).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        this.check(cx, false)?;
        Pin::new(&mut this.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

/// A tracked connection's service: each request is in flight (and carries its
/// [`Connection`]) until its response body is dropped.
#[derive(Debug, Clone)]
pub(crate) struct TrackedService<S> {
    inner: S,
    slot: Arc<Slot>,
}

type BoxFuture<T> = Pin<Box<dyn Future<Output = T> + Send + 'static>>;

impl<S, ReqBody, ResBody> tower_service::Service<Request<ReqBody>> for TrackedService<S>
where
    S: tower_service::Service<Request<ReqBody>, Response = Response<ResBody>>,
    S::Future: Send + 'static,
{
    type Response = Response<TrackedBody<ResBody>>;
    type Error = S::Error;
    type Future = BoxFuture<Result<Self::Response, S::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), S::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, mut req: Request<ReqBody>) -> Self::Future {
        let busy = self.slot.begin();
        req.extensions_mut()
            .insert(Connection(Arc::clone(&self.slot)));
        let fut = self.inner.call(req);
        Box::pin(async move {
            let res = fut.await?;
            Ok(res.map(|inner| TrackedBody { inner, _busy: busy }))
        })
    }
}

/// A response body that keeps its request in flight until dropped.
#[derive(Debug)]
pub(crate) struct TrackedBody<B> {
    inner: B,
    _busy: InFlight,
}

impl<B: Body + Unpin> Body for TrackedBody<B> {
    type Data = B::Data;
    type Error = B::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        Pin::new(&mut self.get_mut().inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(max: usize) -> ServeLimits {
        ServeLimits {
            max_connections: max,
            ..ServeLimits::for_descriptors(1024)
        }
    }

    #[test]
    fn the_cap_leaves_room_for_the_cell_below_the_descriptor_limit() {
        assert_eq!(ServeLimits::for_descriptors(256).max_connections, 192);
        assert_eq!(ServeLimits::for_descriptors(1 << 20).max_connections, 512);
        assert_eq!(ServeLimits::for_descriptors(20).max_connections, 16);
    }

    #[test]
    fn a_newcomer_over_the_cap_closes_the_longest_idle_then_the_oldest_anonymous() {
        let c = Connections::new(limits(3));
        let t0 = Instant::now();
        let at = |ms| t0 + Duration::from_millis(ms);
        let a = c.admit(at(0));
        let b = c.admit(at(1));
        let d = c.admit(at(2));
        // a: an authenticated request in flight; b: anonymous, in flight; d idle
        let _a_busy = a.begin();
        Connection(Arc::clone(&a)).authenticated();
        let _b_busy = b.begin();
        let e = c.admit(at(3));
        assert!(d.is_closed() && !a.is_closed() && !b.is_closed() && !e.is_closed());
        c.forget(d.id);
        // e is idle now: it goes before the anonymous busy b
        let f = c.admit(at(4));
        assert!(e.is_closed() && !b.is_closed() && !f.is_closed());
        c.forget(e.id);
        let _f_busy = f.begin();
        Connection(Arc::clone(&f)).authenticated();
        // only b is anonymous: it goes
        let g = c.admit(at(5));
        assert!(b.is_closed() && !g.is_closed());
        c.forget(b.id);
        let _g_busy = g.begin();
        Connection(Arc::clone(&g)).authenticated();
        // every connection authenticated and busy: the newcomer is refused
        let h = c.admit(at(6));
        assert!(h.is_closed() && !a.is_closed() && !f.is_closed() && !g.is_closed());
        c.forget(h.id);
        assert_eq!(c.open(), 3);
    }

    #[test]
    fn the_longest_idle_goes_first_and_a_finished_request_makes_a_connection_idle_again() {
        let c = Connections::new(limits(2));
        let a = c.admit(Instant::now());
        let b = c.admit(Instant::now());
        {
            let _busy = a.begin();
        }
        // a became idle after b: b has been idle longer
        let n = c.admit(Instant::now());
        assert!(b.is_closed() && !a.is_closed() && !n.is_closed());
    }

    #[test]
    fn idle_connections_close_after_the_idle_timeout_and_busy_ones_never() {
        let c = Connections::new(ServeLimits {
            idle_timeout: Duration::from_secs(60),
            ..limits(10)
        });
        let t0 = Instant::now();
        let idle = c.admit(t0);
        let busy = c.admit(t0);
        let _b = busy.begin();
        c.close_idle(t0 + Duration::from_secs(59));
        assert!(!idle.is_closed());
        c.close_idle(t0 + Duration::from_secs(61));
        assert!(idle.is_closed() && !busy.is_closed());
    }

    #[test]
    fn a_descriptor_shortage_on_accept_closes_the_idlest_connection() {
        let c = Connections::new(limits(10));
        let t0 = Instant::now();
        let a = c.admit(t0);
        let b = c.admit(t0 + Duration::from_millis(1));
        let emfile = std::io::Error::from_raw_os_error(nix::errno::Errno::EMFILE as i32);
        c.accept_failed(&emfile, t0);
        assert!(a.is_closed() && !b.is_closed());
        // another failure frees nothing
        let aborted = std::io::Error::from(std::io::ErrorKind::ConnectionAborted);
        c.accept_failed(&aborted, t0);
        assert!(!b.is_closed());
    }

    #[test]
    fn the_throttle_lets_one_line_through_per_interval_and_counts_the_rest() {
        let mut t = Throttle::default();
        let t0 = Instant::now();
        assert_eq!(t.pass(t0), Some(0));
        assert_eq!(t.pass(t0 + Duration::from_secs(1)), None);
        assert_eq!(t.pass(t0 + Duration::from_secs(2)), None);
        assert_eq!(t.pass(t0 + LOG_EVERY + Duration::from_secs(1)), Some(2));
    }
}
