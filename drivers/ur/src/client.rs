//! Async clients: [`DashboardClient`] (29999), [`RtdeClient`] (30004), [`ScriptClient`]
//! (30002/30003). Each has a reply timeout; none retries or reconnects on its own.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::time::Duration;

use lineio::{LineRead, LineReader};
use thiserror::Error;
use tokio::io::{AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::TcpStream;
use tracing::{debug, warn};

use crate::dashboard::{self, Command, RobotMode, RuntimeState, SafetyMode};
use crate::rtde::{
    decode_values, ClientPackage, FrameDecoder, MessageLevel, RtdeCodecError, RtdeType,
    ServerPackage, TextMessage, Value, PROTOCOL_VERSION,
};
use crate::script::ScriptError;

/// Dashboard server port.
pub const DASHBOARD_PORT: u16 = 29999;
/// RTDE port.
pub const RTDE_PORT: u16 = 30004;
/// Primary client interface (URScript in, robot state out at 10 Hz).
pub const PRIMARY_PORT: u16 = 30001;
/// Secondary client interface (URScript in, robot state out at 10 Hz).
pub const SECONDARY_PORT: u16 = 30002;
/// Real-time client interface (URScript in, robot state out at the control rate).
pub const REALTIME_PORT: u16 = 30003;

/// Longest Dashboard reply line accepted.
const MAX_LINE: usize = 4096;

/// Any failure of the clients.
#[derive(Debug, Error)]
pub enum UrError {
    /// Socket error (connect, read, write).
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: String,
        /// The socket error.
        source: std::io::Error,
    },
    /// No reply within the timeout.
    #[error("{0}: no reply within {1:?}")]
    Timeout(String, Duration),
    /// The controller closed the connection.
    #[error("{0}: the controller closed the connection")]
    Closed(String),
    /// A reply that is not what the protocol says it should be.
    #[error("{0}")]
    Protocol(String),
    /// The controller answered, but with a refusal (the reply text).
    #[error("{command}: controller replied {reply:?}")]
    Refused {
        /// The command sent.
        command: String,
        /// The controller's reply.
        reply: String,
    },
    /// The RTDE byte stream cannot be decoded.
    #[error("RTDE: {0}")]
    Codec(#[from] RtdeCodecError),
    /// A script that cannot be formatted.
    #[error(transparent)]
    Script(#[from] ScriptError),
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> UrError {
    let what = what.into();
    move |source| UrError::Io { what, source }
}

/// Connects with a timeout.
/// Cancel-safe: a drop only abandons the connection attempt.
async fn connect(addr: SocketAddr, timeout: Duration, what: &str) -> Result<TcpStream, UrError> {
    let s = tokio::time::timeout(timeout, TcpStream::connect(addr))
        .await
        .map_err(|_| UrError::Timeout(format!("connect {what} {addr}"), timeout))?
        .map_err(io(format!("connect {what} {addr}")))?;
    let _ = s.set_nodelay(true);
    Ok(s)
}

/// Client of the Dashboard server: one command, one reply line.
#[derive(Debug)]
pub struct DashboardClient {
    reader: LineReader<BufReader<OwnedReadHalf>>,
    writer: OwnedWriteHalf,
    timeout: Duration,
    banner: String,
}

impl DashboardClient {
    /// Connects to `addr` (port 29999 on a controller) and reads the banner.
    /// Cancel-safe: a drop closes the half-open connection.
    pub async fn connect(addr: SocketAddr, timeout: Duration) -> Result<Self, UrError> {
        let stream = connect(addr, timeout, "dashboard").await?;
        let (r, w) = stream.into_split();
        let mut c = DashboardClient {
            reader: LineReader::new(BufReader::new(r), MAX_LINE),
            writer: w,
            timeout,
            banner: String::new(),
        };
        let banner = c.read_line("dashboard banner").await?;
        if !banner.starts_with("Connected: Universal Robots Dashboard Server") {
            return Err(UrError::Protocol(format!(
                "dashboard {addr}: unexpected banner {banner:?}"
            )));
        }
        c.banner = banner;
        Ok(c)
    }

    /// The banner the controller sent.
    pub fn banner(&self) -> &str {
        &self.banner
    }

    /// Reads one reply line.
    /// Cancel-safe: a partial line stays in the reader (lineio).
    async fn read_line(&mut self, what: &str) -> Result<String, UrError> {
        let read = tokio::time::timeout(self.timeout, self.reader.next_line())
            .await
            .map_err(|_| UrError::Timeout(what.to_owned(), self.timeout))?
            .map_err(io(what))?;
        match read {
            LineRead::Line(l) => Ok(l),
            LineRead::Eof => Err(UrError::Closed(what.to_owned())),
            LineRead::Bad(why) => Err(UrError::Protocol(format!("{what}: bad reply line: {why}"))),
        }
    }

    /// Sends `text` + `\n` and returns the reply line.
    /// Not cancel-safe: a drop after the command is written leaves its reply unread, and the
    /// next command would read it; drop the client instead.
    pub async fn raw(&mut self, text: &str) -> Result<String, UrError> {
        if text.contains('\n') {
            return Err(UrError::Protocol("a dashboard command is one line".into()));
        }
        let line = format!("{text}\n");
        tokio::time::timeout(self.timeout, self.writer.write_all(line.as_bytes()))
            .await
            .map_err(|_| UrError::Timeout(format!("send {text:?}"), self.timeout))?
            .map_err(io(format!("send {text:?}")))?;
        let reply = self.read_line(text).await?;
        debug!("dashboard {text:?} -> {reply:?}");
        Ok(reply)
    }

    /// Sends `cmd`; the reply must start with `expect`, or it is [`UrError::Refused`].
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    async fn expect(&mut self, cmd: Command, expect: &str) -> Result<String, UrError> {
        let text = cmd.text();
        let reply = self.raw(&text).await?;
        if reply.starts_with(expect) {
            Ok(reply)
        } else {
            Err(UrError::Refused {
                command: text,
                reply,
            })
        }
    }

    /// `power on` (reply `Powering on`; the arm reaches IDLE later: poll `robotmode`).
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn power_on(&mut self) -> Result<(), UrError> {
        self.expect(Command::PowerOn, dashboard::POWERING_ON)
            .await
            .map(drop)
    }

    /// `power off` (reply `Powering off`).
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn power_off(&mut self) -> Result<(), UrError> {
        self.expect(Command::PowerOff, dashboard::POWERING_OFF)
            .await
            .map(drop)
    }

    /// `brake release` (reply `Brake releasing`; RUNNING follows: poll `robotmode`).
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn brake_release(&mut self) -> Result<(), UrError> {
        self.expect(Command::BrakeRelease, dashboard::BRAKE_RELEASING)
            .await
            .map(drop)
    }

    /// `stop`: stops the running program (reply `Stopped`).
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn stop(&mut self) -> Result<(), UrError> {
        self.expect(Command::Stop, dashboard::STOPPED)
            .await
            .map(drop)
    }

    /// `unlock protective stop` (reply `Protective stop releasing`).
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn unlock_protective_stop(&mut self) -> Result<(), UrError> {
        self.expect(
            Command::UnlockProtectiveStop,
            dashboard::PROTECTIVE_STOP_RELEASING,
        )
        .await
        .map(drop)
    }

    /// `close popup`.
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn close_popup(&mut self) -> Result<(), UrError> {
        self.expect(Command::ClosePopup, dashboard::CLOSING_POPUP)
            .await
            .map(drop)
    }

    /// `close safety popup`.
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn close_safety_popup(&mut self) -> Result<(), UrError> {
        self.expect(Command::CloseSafetyPopup, dashboard::CLOSING_SAFETY_POPUP)
            .await
            .map(drop)
    }

    /// `robotmode`, parsed.
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn robot_mode(&mut self) -> Result<RobotMode, UrError> {
        let reply = self.raw(&Command::RobotMode.text()).await?;
        dashboard::parse_robot_mode(&reply)
            .ok_or_else(|| UrError::Protocol(format!("robotmode: unexpected reply {reply:?}")))
    }

    /// `safetystatus` (PolyScope ≥ 5.4), parsed.
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn safety_status(&mut self) -> Result<SafetyMode, UrError> {
        let reply = self.raw(&Command::SafetyStatus.text()).await?;
        dashboard::parse_safety_mode(&reply)
            .ok_or_else(|| UrError::Protocol(format!("safetystatus: unexpected reply {reply:?}")))
    }

    /// `safetymode`, parsed.
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn safety_mode(&mut self) -> Result<SafetyMode, UrError> {
        let reply = self.raw(&Command::SafetyMode.text()).await?;
        dashboard::parse_safety_mode(&reply)
            .ok_or_else(|| UrError::Protocol(format!("safetymode: unexpected reply {reply:?}")))
    }

    /// `is in remote control` (PolyScope ≥ 5.6), parsed.
    /// Not cancel-safe (see [`DashboardClient::raw`]).
    pub async fn is_in_remote_control(&mut self) -> Result<bool, UrError> {
        let reply = self.raw(&Command::IsInRemoteControl.text()).await?;
        dashboard::parse_remote_control(&reply).ok_or_else(|| {
            UrError::Protocol(format!("is in remote control: unexpected reply {reply:?}"))
        })
    }

    /// `quit`: the controller answers `Disconnected` and closes.
    /// Cancel-safe: the connection is being closed anyway.
    pub async fn quit(mut self) -> Result<(), UrError> {
        self.expect(Command::Quit, dashboard::DISCONNECTED)
            .await
            .map(drop)
    }
}

/// The controller's software version (RTDE `v`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ControllerVersion {
    /// 3: CB3, 5: e-Series.
    pub major: u32,
    /// Minor.
    pub minor: u32,
    /// Bugfix.
    pub bugfix: u32,
    /// Build.
    pub build: u32,
}

/// An output recipe the controller accepted.
#[derive(Debug, Clone, PartialEq)]
pub struct Recipe {
    /// Recipe id the data packages carry.
    pub id: u8,
    /// Variable names, in order.
    pub names: Vec<String>,
    /// Their types, in order.
    pub types: Vec<RtdeType>,
}

/// One output data package, by variable name.
#[derive(Debug, Clone, PartialEq)]
pub struct DataPackage {
    /// Values by variable name.
    pub values: HashMap<String, Value>,
}

impl DataPackage {
    /// The `VECTOR6D` variable `name`.
    pub fn vector6d(&self, name: &str) -> Option<[f64; 6]> {
        match self.values.get(name)? {
            Value::Vector6d(v) => Some(*v),
            _ => None,
        }
    }
    /// The `INT32` variable `name`.
    pub fn int32(&self, name: &str) -> Option<i32> {
        match self.values.get(name)? {
            Value::Int32(v) => Some(*v),
            _ => None,
        }
    }
    /// The `UINT32` variable `name`.
    pub fn uint32(&self, name: &str) -> Option<u32> {
        match self.values.get(name)? {
            Value::Uint32(v) => Some(*v),
            _ => None,
        }
    }
    /// The `DOUBLE` variable `name`.
    pub fn double(&self, name: &str) -> Option<f64> {
        match self.values.get(name)? {
            Value::Double(v) => Some(*v),
            _ => None,
        }
    }
}

/// The variables a motion client follows ([`RobotState::from_package`] reads them).
pub const STATE_RECIPE: [&str; 8] = [
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_q",
    "robot_mode",
    "safety_mode",
    "runtime_state",
    "robot_status_bits",
];

/// The state a motion client follows, from a [`STATE_RECIPE`] package.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotState {
    /// Controller time, s.
    pub timestamp: f64,
    /// Measured joint positions, rad.
    pub actual_q: [f64; 6],
    /// Measured joint speeds, rad/s.
    pub actual_qd: [f64; 6],
    /// Commanded joint positions, rad.
    pub target_q: [f64; 6],
    /// Robot mode.
    pub robot_mode: RobotMode,
    /// Safety mode.
    pub safety_mode: SafetyMode,
    /// Program state.
    pub runtime_state: RuntimeState,
    /// Robot status bits (bit 0 power on, bit 1 program running).
    pub robot_status_bits: u32,
}

impl RobotState {
    /// Reads the [`STATE_RECIPE`] variables; an error names the missing or unknown one.
    /// Non-finite joint values are refused.
    pub fn from_package(p: &DataPackage) -> Result<Self, UrError> {
        let miss = |n: &str| UrError::Protocol(format!("RTDE: {n} missing or mistyped"));
        let vec6 = |n: &str| -> Result<[f64; 6], UrError> {
            let v = p.vector6d(n).ok_or_else(|| miss(n))?;
            if v.iter().all(|x| x.is_finite()) {
                Ok(v)
            } else {
                Err(UrError::Protocol(format!("RTDE: {n} is not finite: {v:?}")))
            }
        };
        let rm = p.int32("robot_mode").ok_or_else(|| miss("robot_mode"))?;
        let sm = p.int32("safety_mode").ok_or_else(|| miss("safety_mode"))?;
        let rs = p
            .uint32("runtime_state")
            .ok_or_else(|| miss("runtime_state"))?;
        Ok(RobotState {
            timestamp: p.double("timestamp").ok_or_else(|| miss("timestamp"))?,
            actual_q: vec6("actual_q")?,
            actual_qd: vec6("actual_qd")?,
            target_q: vec6("target_q")?,
            robot_mode: RobotMode::from_code(rm)
                .ok_or_else(|| UrError::Protocol(format!("RTDE: unknown robot_mode {rm}")))?,
            safety_mode: SafetyMode::from_code(sm)
                .ok_or_else(|| UrError::Protocol(format!("RTDE: unknown safety_mode {sm}")))?,
            runtime_state: RuntimeState::from_code(rs)
                .ok_or_else(|| UrError::Protocol(format!("RTDE: unknown runtime_state {rs}")))?,
            robot_status_bits: p
                .uint32("robot_status_bits")
                .ok_or_else(|| miss("robot_status_bits"))?,
        })
    }

    /// Whether a program runs (runtime state PLAYING or robot status bit 1).
    pub fn program_running(&self) -> bool {
        self.runtime_state == RuntimeState::Playing || self.robot_status_bits & 0b10 != 0
    }
}

/// RTDE client, protocol version 2.
#[derive(Debug)]
pub struct RtdeClient {
    stream: TcpStream,
    decoder: FrameDecoder,
    timeout: Duration,
    recipe: Option<Recipe>,
    messages: Vec<TextMessage>,
}

impl RtdeClient {
    /// Connects to `addr` (port 30004) and negotiates protocol version 2.
    /// Cancel-safe: a drop closes the half-open connection.
    pub async fn connect(addr: SocketAddr, timeout: Duration) -> Result<Self, UrError> {
        let stream = connect(addr, timeout, "RTDE").await?;
        let mut c = RtdeClient {
            stream,
            decoder: FrameDecoder::new(),
            timeout,
            recipe: None,
            messages: Vec::new(),
        };
        match c
            .request(ClientPackage::RequestProtocolVersion(PROTOCOL_VERSION))
            .await?
        {
            ServerPackage::ProtocolVersion(true) => Ok(c),
            ServerPackage::ProtocolVersion(false) => Err(UrError::Protocol(format!(
                "RTDE {addr}: the controller refused protocol version {PROTOCOL_VERSION}"
            ))),
            other => Err(unexpected("protocol version", &other)),
        }
    }

    /// Text messages the controller sent so far (taken).
    pub fn take_messages(&mut self) -> Vec<TextMessage> {
        std::mem::take(&mut self.messages)
    }

    /// Writes one package.
    /// Not cancel-safe: a drop may leave a partial package on the wire; drop the client.
    async fn send(&mut self, p: &ClientPackage) -> Result<(), UrError> {
        let bytes = p.encode()?;
        tokio::time::timeout(self.timeout, self.stream.write_all(&bytes))
            .await
            .map_err(|_| UrError::Timeout("RTDE send".into(), self.timeout))?
            .map_err(io("RTDE send"))
    }

    /// The next package; text messages are logged and kept, not returned.
    /// Cancel-safe: received bytes stay in the decoder, so a dropped call loses nothing.
    async fn next_package(&mut self, what: &str) -> Result<ServerPackage, UrError> {
        let deadline = tokio::time::Instant::now() + self.timeout;
        loop {
            while let Some(p) = self.decoder.next_server()? {
                if let ServerPackage::Text(t) = p {
                    match t.level {
                        MessageLevel::Exception | MessageLevel::Error => {
                            warn!("RTDE {}: {}", t.source, t.message)
                        }
                        _ => debug!("RTDE {}: {}", t.source, t.message),
                    }
                    self.messages.push(t);
                    continue;
                }
                return Ok(p);
            }
            let mut buf = [0u8; 4096];
            let n = tokio::time::timeout_at(deadline, self.stream.read(&mut buf))
                .await
                .map_err(|_| UrError::Timeout(what.to_owned(), self.timeout))?
                .map_err(io(what))?;
            if n == 0 {
                return Err(UrError::Closed(what.to_owned()));
            }
            self.decoder.push(&buf[..n]);
        }
    }

    /// Sends `p` and returns the reply of the same type, skipping data packages.
    /// Not cancel-safe: a drop after the request is sent leaves its reply unread.
    async fn request(&mut self, p: ClientPackage) -> Result<ServerPackage, UrError> {
        let kind = p.kind();
        self.send(&p).await?;
        let what = format!("RTDE reply to {:?}", char::from(kind));
        loop {
            let reply = self.next_package(&what).await?;
            if reply.kind() == kind {
                return Ok(reply);
            }
            if !matches!(reply, ServerPackage::Data { .. }) {
                return Err(unexpected(&what, &reply));
            }
        }
    }

    /// The controller's version (`v`).
    /// Not cancel-safe: a drop after the request is sent leaves its reply unread.
    pub async fn controller_version(&mut self) -> Result<ControllerVersion, UrError> {
        match self.request(ClientPackage::GetUrcontrolVersion).await? {
            ServerPackage::UrcontrolVersion {
                major,
                minor,
                bugfix,
                build,
            } => Ok(ControllerVersion {
                major,
                minor,
                bugfix,
                build,
            }),
            other => Err(unexpected("URControl version", &other)),
        }
    }

    /// Sets up the output recipe: `names` at `frequency_hz`. Fails when the controller does
    /// not know a name (`NOT_FOUND`), names the type of none, or refuses the recipe (id 0).
    /// Not cancel-safe: a drop after the request is sent leaves its reply unread.
    pub async fn setup_outputs(
        &mut self,
        names: &[&str],
        frequency_hz: f64,
    ) -> Result<Recipe, UrError> {
        if !(frequency_hz.is_finite() && frequency_hz > 0.0) {
            return Err(UrError::Protocol(format!(
                "RTDE output frequency must be positive, got {frequency_hz}"
            )));
        }
        if names.is_empty() || names.iter().any(|n| n.is_empty() || n.contains(',')) {
            return Err(UrError::Protocol(format!(
                "bad RTDE variable list {names:?}"
            )));
        }
        let reply = self
            .request(ClientPackage::SetupOutputs {
                frequency: frequency_hz,
                names: names.iter().map(|s| (*s).to_owned()).collect(),
            })
            .await?;
        let ServerPackage::SetupOutputs { recipe, types } = reply else {
            return Err(unexpected("setup outputs", &reply));
        };
        if types.len() != names.len() {
            return Err(UrError::Protocol(format!(
                "RTDE setup outputs: {} types for {} variables",
                types.len(),
                names.len()
            )));
        }
        let mut parsed = Vec::new();
        let mut bad = Vec::new();
        for (n, t) in names.iter().zip(&types) {
            match RtdeType::from_name(t) {
                Some(t) => parsed.push(t),
                None => bad.push(format!("{n}: {t}")),
            }
        }
        if !bad.is_empty() {
            return Err(UrError::Refused {
                command: "RTDE setup outputs".into(),
                reply: bad.join(", "),
            });
        }
        if recipe == 0 {
            return Err(UrError::Refused {
                command: "RTDE setup outputs".into(),
                reply: "recipe id 0".into(),
            });
        }
        let r = Recipe {
            id: recipe,
            names: names.iter().map(|s| (*s).to_owned()).collect(),
            types: parsed,
        };
        self.recipe = Some(r.clone());
        Ok(r)
    }

    /// Starts the data synchronisation (`S`).
    /// Not cancel-safe: a drop after the request is sent leaves its reply unread.
    pub async fn start(&mut self) -> Result<(), UrError> {
        match self.request(ClientPackage::Start).await? {
            ServerPackage::Start(true) => Ok(()),
            ServerPackage::Start(false) => Err(UrError::Refused {
                command: "RTDE start".into(),
                reply: "0".into(),
            }),
            other => Err(unexpected("start", &other)),
        }
    }

    /// Pauses the data synchronisation (`P`); data packages in flight are dropped.
    /// Not cancel-safe: a drop after the request is sent leaves its reply unread.
    pub async fn pause(&mut self) -> Result<(), UrError> {
        match self.request(ClientPackage::Pause).await? {
            ServerPackage::Pause(true) => Ok(()),
            ServerPackage::Pause(false) => Err(UrError::Refused {
                command: "RTDE pause".into(),
                reply: "0".into(),
            }),
            other => Err(unexpected("pause", &other)),
        }
    }

    /// The next data package of the output recipe.
    /// Cancel-safe: received bytes stay in the decoder, so a dropped call loses nothing.
    pub async fn next_data(&mut self) -> Result<DataPackage, UrError> {
        let recipe = self
            .recipe
            .clone()
            .ok_or_else(|| UrError::Protocol("RTDE: no output recipe set up".into()))?;
        match self.next_package("RTDE data package").await? {
            ServerPackage::Data { recipe: id, values } if id == recipe.id => {
                let values = decode_values(&recipe.types, &values)?;
                Ok(DataPackage {
                    values: recipe.names.iter().cloned().zip(values).collect(),
                })
            }
            ServerPackage::Data { recipe: id, .. } => Err(UrError::Protocol(format!(
                "RTDE data package for recipe {id}, expected {}",
                recipe.id
            ))),
            other => Err(unexpected("data package", &other)),
        }
    }

    /// The newest [`RobotState`]: drains the packages already received and returns the last,
    /// or waits for the next one.
    /// Cancel-safe: as [`RtdeClient::next_data`].
    pub async fn latest_state(&mut self) -> Result<RobotState, UrError> {
        let mut last = self.next_data().await?;
        loop {
            // another complete package already buffered?
            if self.decoder.buffered() < crate::rtde::HEADER_LEN {
                break;
            }
            match tokio::time::timeout(Duration::ZERO, self.next_data()).await {
                Ok(p) => last = p?,
                Err(_) => break,
            }
        }
        RobotState::from_package(&last)
    }
}

fn unexpected(what: &str, p: &ServerPackage) -> UrError {
    UrError::Protocol(format!(
        "RTDE {what}: unexpected package {:?}",
        char::from(p.kind())
    ))
}

/// Sends URScript programs to a client interface (30001, 30002 or 30003).
///
/// Each program goes over its own short connection: connect, write, close. A controller runs a
/// program it received in full and replaces a running one with it.
#[derive(Debug, Clone)]
pub struct ScriptClient {
    addr: SocketAddr,
    timeout: Duration,
}

impl ScriptClient {
    /// A sender to `addr` (the controller's host with port 30002 or 30003).
    pub fn new(addr: SocketAddr, timeout: Duration) -> Self {
        ScriptClient { addr, timeout }
    }

    /// Sends `program` (newline-terminated URScript).
    /// Not cancel-safe: a drop mid-write may deliver part of the program, which a controller
    /// does not compile; a dropped send must be followed by a new one.
    pub async fn send(&self, program: &str) -> Result<(), UrError> {
        let mut s = connect(self.addr, self.timeout, "URScript").await?;
        let mut text = program.to_owned();
        if !text.ends_with('\n') {
            text.push('\n');
        }
        tokio::time::timeout(self.timeout, async {
            s.write_all(text.as_bytes()).await?;
            s.flush().await?;
            s.shutdown().await
        })
        .await
        .map_err(|_| UrError::Timeout(format!("URScript to {}", self.addr), self.timeout))?
        .map_err(io(format!("URScript to {}", self.addr)))
    }

    /// Sends `def cellcal_move(): movej(q, a, v) end`.
    /// Not cancel-safe (see [`ScriptClient::send`]).
    pub async fn movej(&self, q: &[f64; 6], a: f64, v: f64) -> Result<(), UrError> {
        let p = crate::script::program("cellcal_move", &[crate::script::movej(q, a, v)?])?;
        self.send(&p).await
    }

    /// Sends `def cellcal_stop(): stopj(a) end` (replaces the running program).
    /// Not cancel-safe (see [`ScriptClient::send`]).
    pub async fn stopj(&self, a: f64) -> Result<(), UrError> {
        let p = crate::script::program("cellcal_stop", &[crate::script::stopj(a)?])?;
        self.send(&p).await
    }
}
