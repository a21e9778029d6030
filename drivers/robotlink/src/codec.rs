//! Line codec: parse and format requests, replies and events of the robotlink protocol.
//!
//! Every function here is pure and total: arbitrary input never panics, it yields a
//! [`CodecError`]. See `PROTOCOL.md` for the grammar.

use std::fmt;
use std::str::FromStr;

use crate::auth::{Nonce, Proof};

/// The protocol version spoken by this crate: v3, authenticated (`PROTOCOL.md` §3a). The
/// client offers only it and the server accepts only it: v1 and v2 let anyone who reached the
/// port move the arm.
pub const PROTO_VERSION: u32 = 3;
/// Longest accepted line in bytes, terminator excluded.
pub const MAX_LINE: usize = 1024;
/// Largest accepted sequence number; sequence numbers run `1..=MAX_SEQ`, `0` is reserved.
pub const MAX_SEQ: u32 = 999_999;
/// Number of decimals used when formatting floating-point fields.
pub const DECIMALS: usize = 6;

/// Typed error of the codec.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    /// The line is empty (after trimming the terminator).
    #[error("empty line")]
    Empty,
    /// The line is longer than [`MAX_LINE`].
    #[error("line too long ({0} bytes)")]
    TooLong(usize),
    /// The line contains a non-printable or non-ASCII byte.
    #[error("non-printable or non-ASCII character in line")]
    NotAscii,
    /// The sequence-number field is missing or not a decimal in range.
    #[error("bad sequence number {0:?}")]
    BadSeq(String),
    /// The verb is not part of the protocol.
    #[error("unknown verb {0:?}")]
    UnknownVerb(String),
    /// The reply status is neither `OK` nor `ERR`, or the event lacks `EVT`.
    #[error("bad reply or event keyword {0:?}")]
    BadKeyword(String),
    /// Wrong number of fields.
    #[error("{what}: expected {expected} field(s), got {got}")]
    Arity {
        /// What was being parsed.
        what: &'static str,
        /// Expected count (description).
        expected: &'static str,
        /// Actual count.
        got: usize,
    },
    /// A field that must be numeric is not (or is not finite).
    #[error("{what}: field {field:?} is not a finite number")]
    NotNumeric {
        /// What was being parsed.
        what: &'static str,
        /// The offending field.
        field: String,
    },
    /// A field has a value outside its allowed set or range.
    #[error("{what}: bad value {field:?}")]
    BadValue {
        /// What was being parsed.
        what: &'static str,
        /// The offending field.
        field: String,
    },
}

impl CodecError {
    /// True when the line was framed correctly but its arguments are wrong (`E_ARGS`),
    /// false when the line is malformed (`E_SYNTAX`).
    pub fn is_args_error(&self) -> bool {
        matches!(
            self,
            CodecError::Arity { .. } | CodecError::NotNumeric { .. } | CodecError::BadValue { .. }
        )
    }
}

/// Known protocol error codes (`ERR <CODE>`), plus a catch-all for forward compatibility.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// `E_SYNTAX`: malformed line.
    Syntax,
    /// `E_ARGS`: wrong arity or bad argument value.
    Args,
    /// `E_BUSY`: another client is connected or the robot is moving.
    Busy,
    /// `E_POWER`: arm power is off.
    Power,
    /// `E_ESTOP`: emergency stop is active.
    EStop,
    /// `E_UNREACHABLE`: target cannot be reached.
    Unreachable,
    /// `E_LIMIT`: target outside joint limits.
    Limit,
    /// `E_TIMEOUT`: `WAIT` ran out of time before the arm settled.
    Timeout,
    /// `E_MODE`: controller is not in the remote/automatic mode required.
    Mode,
    /// `E_STOPPED` (v2): the request was ended by an out-of-band `STOP`.
    Stopped,
    /// `E_AUTH` (v3): not authenticated, or the proof was wrong; the server closes.
    Auth,
    /// Any other `E_*` code sent by a newer server.
    Other(String),
}

impl ErrorCode {
    /// Wire spelling of the code.
    pub fn as_str(&self) -> &str {
        match self {
            ErrorCode::Syntax => "E_SYNTAX",
            ErrorCode::Args => "E_ARGS",
            ErrorCode::Busy => "E_BUSY",
            ErrorCode::Power => "E_POWER",
            ErrorCode::EStop => "E_ESTOP",
            ErrorCode::Unreachable => "E_UNREACHABLE",
            ErrorCode::Limit => "E_LIMIT",
            ErrorCode::Timeout => "E_TIMEOUT",
            ErrorCode::Mode => "E_MODE",
            ErrorCode::Stopped => "E_STOPPED",
            ErrorCode::Auth => "E_AUTH",
            ErrorCode::Other(s) => s,
        }
    }

    /// Parse a code token; unknown tokens shaped like a code become [`ErrorCode::Other`].
    pub fn parse(tok: &str) -> Result<Self, CodecError> {
        Ok(match tok {
            "E_SYNTAX" => ErrorCode::Syntax,
            "E_ARGS" => ErrorCode::Args,
            "E_BUSY" => ErrorCode::Busy,
            "E_POWER" => ErrorCode::Power,
            "E_ESTOP" => ErrorCode::EStop,
            "E_UNREACHABLE" => ErrorCode::Unreachable,
            "E_LIMIT" => ErrorCode::Limit,
            "E_TIMEOUT" => ErrorCode::Timeout,
            "E_MODE" => ErrorCode::Mode,
            "E_STOPPED" => ErrorCode::Stopped,
            "E_AUTH" => ErrorCode::Auth,
            other if is_code_token(other) => ErrorCode::Other(other.to_string()),
            other => {
                return Err(CodecError::BadValue {
                    what: "error code",
                    field: other.to_string(),
                })
            }
        })
    }
}

fn is_code_token(s: &str) -> bool {
    s.len() > 2
        && s.starts_with("E_")
        && s.bytes()
            .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_')
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A request verb with its typed arguments.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// `HELLO <proto_ver>`.
    Hello {
        /// Protocol version the client speaks.
        proto_ver: u32,
    },
    /// `AUTH <client_nonce> <client_proof>` (v3, after `HELLO 3`).
    Auth {
        /// The client's fresh nonce.
        client_nonce: Nonce,
        /// HMAC-SHA256 proof of the shared secret over both nonces ([`crate::auth`]).
        proof: Proof,
    },
    /// `PING`.
    Ping,
    /// `STATE`.
    State,
    /// `POWER ON|OFF`.
    Power(bool),
    /// `SPEED <pct>` (monitor speed, 0 < pct <= 100).
    Speed {
        /// Speed override in percent.
        pct: f64,
    },
    /// `MOVEJ j1..j6 [vel%]` (joint target in degrees).
    MoveJ {
        /// Target joints in degrees.
        joints_deg: [f64; 6],
        /// Optional joint velocity in percent of nominal.
        vel_pct: Option<f64>,
    },
    /// `WAIT <timeout_ms>`.
    Wait {
        /// Server-side settle timeout in milliseconds.
        timeout_ms: u64,
    },
    /// `JOINTS`.
    Joints,
    /// `POSE`.
    Pose,
    /// `STOP`.
    Stop,
}

impl Request {
    /// Wire verb of this request.
    pub fn verb(&self) -> &'static str {
        match self {
            Request::Hello { .. } => "HELLO",
            Request::Auth { .. } => "AUTH",
            Request::Ping => "PING",
            Request::State => "STATE",
            Request::Power(_) => "POWER",
            Request::Speed { .. } => "SPEED",
            Request::MoveJ { .. } => "MOVEJ",
            Request::Wait { .. } => "WAIT",
            Request::Joints => "JOINTS",
            Request::Pose => "POSE",
            Request::Stop => "STOP",
        }
    }
}

/// A request line: sequence number and request.
#[derive(Debug, Clone, PartialEq)]
pub struct RequestLine {
    /// Sequence number, `1..=MAX_SEQ`.
    pub seq: u32,
    /// The request.
    pub request: Request,
}

/// Outcome carried by a reply line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReplyBody {
    /// `OK [data]`; `data` are the whitespace-separated fields after `OK`.
    Ok(Vec<String>),
    /// `ERR <CODE> <text>`.
    Err {
        /// Error code.
        code: ErrorCode,
        /// Free human-readable text (may be empty).
        text: String,
    },
}

/// A reply line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Reply {
    /// Sequence number echoed from the request (`0` for a reply to an unparseable line).
    pub seq: u32,
    /// Outcome.
    pub body: ReplyBody,
}

/// Names of asynchronous events.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum EventName {
    /// `ESTOP`: emergency stop became active.
    EStop,
    /// `POWER_LOST`: arm power dropped without a `POWER OFF` request.
    PowerLost,
    /// `REFUSED`: connection refused because another client is connected (server closes next).
    Refused,
    /// Any other event name (e.g. `NOTE`).
    Other(String),
}

impl EventName {
    /// Wire spelling.
    pub fn as_str(&self) -> &str {
        match self {
            EventName::EStop => "ESTOP",
            EventName::PowerLost => "POWER_LOST",
            EventName::Refused => "REFUSED",
            EventName::Other(s) => s,
        }
    }

    fn parse(tok: &str) -> Result<Self, CodecError> {
        Ok(match tok {
            "ESTOP" => EventName::EStop,
            "POWER_LOST" => EventName::PowerLost,
            "REFUSED" => EventName::Refused,
            t if !t.is_empty()
                && t.bytes()
                    .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_') =>
            {
                EventName::Other(t.to_string())
            }
            t => {
                return Err(CodecError::BadValue {
                    what: "event name",
                    field: t.to_string(),
                })
            }
        })
    }
}

/// An asynchronous event line `* EVT <name> [data]`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Event {
    /// Event name.
    pub name: EventName,
    /// Rest of the line after the name, single-space normalised (may be empty).
    pub data: String,
}

/// Any line a server may send.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServerLine {
    /// A reply to a request.
    Reply(Reply),
    /// An asynchronous event.
    Event(Event),
}

/// Reply data of `STATE`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RobotState {
    /// Arm power on.
    pub power: bool,
    /// Controller mode (free token, e.g. `remote`, `manual`, `local`).
    pub mode: String,
    /// Emergency stop active.
    pub estop: bool,
    /// A motion is in progress.
    pub moving: bool,
    /// The arm is settled (no motion pending, position stable).
    pub settled: bool,
}

/// Reply data of `HELLO`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// Controller type, e.g. `CS9`.
    pub ctrl: String,
    /// Arm type, e.g. `TX2-90`.
    pub arm: String,
    /// Server software version.
    pub sw: String,
}

/// Cartesian pose: position in mm, rotation in degrees (`Rx, Ry, Rz`, see `PROTOCOL.md`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position `x, y, z` in millimetres.
    pub xyz_mm: [f64; 3],
    /// Rotation `rx, ry, rz` in degrees (VAL3 convention: R = Rx(rx)·Ry(ry)·Rz(rz)).
    pub rxyz_deg: [f64; 3],
}

// ----------------------------------------------------------------------------------------------
// Line helpers

/// Strip a trailing `\n` or `\r\n` (and a lone trailing `\r`) and check length / character set.
pub fn clean_line(raw: &str) -> Result<&str, CodecError> {
    let s = raw.strip_suffix('\n').unwrap_or(raw);
    let s = s.strip_suffix('\r').unwrap_or(s);
    if s.len() > MAX_LINE {
        return Err(CodecError::TooLong(s.len()));
    }
    if !s.bytes().all(|b| (0x20..0x7f).contains(&b) || b == b'\t') {
        return Err(CodecError::NotAscii);
    }
    if s.trim().is_empty() {
        return Err(CodecError::Empty);
    }
    Ok(s)
}

fn parse_seq(tok: &str) -> Result<u32, CodecError> {
    if tok.is_empty() || tok.len() > 6 || !tok.bytes().all(|b| b.is_ascii_digit()) {
        return Err(CodecError::BadSeq(tok.to_string()));
    }
    tok.parse::<u32>()
        .map_err(|_| CodecError::BadSeq(tok.to_string()))
}

/// Largest magnitude accepted for a numeric field (keeps formatted lines short).
pub const MAX_ABS_NUM: f64 = 1.0e9;

/// Parse a finite decimal number (`[+-]digits[.digits][e[+-]digits]`, |v| <= [`MAX_ABS_NUM`]); rejects `inf`, `nan`, hex.
pub fn parse_num(what: &'static str, tok: &str) -> Result<f64, CodecError> {
    let ok_chars = !tok.is_empty()
        && tok
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'+' | b'-' | b'.' | b'e' | b'E'))
        && tok.bytes().any(|b| b.is_ascii_digit());
    let err = || CodecError::NotNumeric {
        what,
        field: tok.to_string(),
    };
    if !ok_chars {
        return Err(err());
    }
    match f64::from_str(tok) {
        Ok(v) if v.is_finite() && v.abs() <= MAX_ABS_NUM => Ok(v),
        Ok(v) if v.is_finite() => Err(CodecError::BadValue {
            what,
            field: tok.to_string(),
        }),
        _ => Err(err()),
    }
}

/// Format a float with [`DECIMALS`] decimals; `-0` is printed as `0`.
pub fn fmt_num(v: f64) -> String {
    let v = if v == 0.0 { 0.0 } else { v };
    format!("{v:.DECIMALS$}")
}

fn parse_nums<const N: usize>(what: &'static str, toks: &[&str]) -> Result<[f64; N], CodecError> {
    let mut out = [0.0; N];
    for (slot, tok) in out.iter_mut().zip(toks) {
        *slot = parse_num(what, tok)?;
    }
    Ok(out)
}

fn check_arity(
    what: &'static str,
    expected: &'static str,
    got: usize,
    ok: bool,
) -> Result<(), CodecError> {
    if ok {
        Ok(())
    } else {
        Err(CodecError::Arity {
            what,
            expected,
            got,
        })
    }
}

// ----------------------------------------------------------------------------------------------
// Requests

/// Best-effort extraction of the sequence number of a (possibly malformed) request line.
pub fn request_seq(raw: &str) -> Option<u32> {
    raw.split_whitespace()
        .next()
        .and_then(|t| parse_seq(t).ok())
}

/// Parse one request line (terminator optional).
pub fn parse_request(raw: &str) -> Result<RequestLine, CodecError> {
    let line = clean_line(raw)?;
    let toks: Vec<&str> = line.split_whitespace().collect();
    let seq = parse_seq(toks.first().copied().unwrap_or(""))?;
    if seq == 0 {
        return Err(CodecError::BadSeq("0".into()));
    }
    let verb = toks
        .get(1)
        .copied()
        .ok_or_else(|| CodecError::UnknownVerb(String::new()))?;
    let args = &toks[2..];
    let n = args.len();
    let request = match verb {
        "HELLO" => {
            check_arity("HELLO", "1", n, n == 1)?;
            let v = args[0].parse::<u32>().map_err(|_| CodecError::NotNumeric {
                what: "HELLO",
                field: args[0].to_string(),
            })?;
            Request::Hello { proto_ver: v }
        }
        "AUTH" => {
            check_arity("AUTH", "2", n, n == 2)?;
            let bad = |field: &str| CodecError::BadValue {
                what: "AUTH",
                field: field.to_string(),
            };
            Request::Auth {
                client_nonce: Nonce::from_hex(args[0]).ok_or_else(|| bad(args[0]))?,
                proof: Proof::from_hex(args[1]).ok_or_else(|| bad(args[1]))?,
            }
        }
        "PING" => {
            check_arity("PING", "0", n, n == 0)?;
            Request::Ping
        }
        "STATE" => {
            check_arity("STATE", "0", n, n == 0)?;
            Request::State
        }
        "POWER" => {
            check_arity("POWER", "1", n, n == 1)?;
            match args[0] {
                "ON" => Request::Power(true),
                "OFF" => Request::Power(false),
                o => {
                    return Err(CodecError::BadValue {
                        what: "POWER",
                        field: o.to_string(),
                    })
                }
            }
        }
        "SPEED" => {
            check_arity("SPEED", "1", n, n == 1)?;
            Request::Speed {
                pct: parse_num("SPEED", args[0])?,
            }
        }
        "MOVEJ" => {
            check_arity("MOVEJ", "6 or 7", n, n == 6 || n == 7)?;
            let joints_deg = parse_nums::<6>("MOVEJ", &args[..6])?;
            let vel_pct = match args.get(6) {
                Some(t) => Some(parse_num("MOVEJ", t)?),
                None => None,
            };
            Request::MoveJ {
                joints_deg,
                vel_pct,
            }
        }
        "WAIT" => {
            check_arity("WAIT", "1", n, n == 1)?;
            let ms = args[0].parse::<u64>().map_err(|_| CodecError::NotNumeric {
                what: "WAIT",
                field: args[0].to_string(),
            })?;
            Request::Wait { timeout_ms: ms }
        }
        "JOINTS" => {
            check_arity("JOINTS", "0", n, n == 0)?;
            Request::Joints
        }
        "POSE" => {
            check_arity("POSE", "0", n, n == 0)?;
            Request::Pose
        }
        "STOP" => {
            check_arity("STOP", "0", n, n == 0)?;
            Request::Stop
        }
        other => return Err(CodecError::UnknownVerb(other.to_string())),
    };
    Ok(RequestLine { seq, request })
}

/// Format a request line, terminator `\n` included.
pub fn format_request(seq: u32, req: &Request) -> String {
    let mut s = format!("{seq} {}", req.verb());
    match req {
        Request::Hello { proto_ver } => s.push_str(&format!(" {proto_ver}")),
        Request::Auth {
            client_nonce,
            proof,
        } => s.push_str(&format!(" {} {}", client_nonce.to_hex(), proof.to_hex())),
        Request::Power(on) => s.push_str(if *on { " ON" } else { " OFF" }),
        Request::Speed { pct } => {
            s.push(' ');
            s.push_str(&fmt_num(*pct));
        }
        Request::MoveJ {
            joints_deg,
            vel_pct,
        } => {
            for j in joints_deg {
                s.push(' ');
                s.push_str(&fmt_num(*j));
            }
            if let Some(v) = vel_pct {
                s.push(' ');
                s.push_str(&fmt_num(*v));
            }
        }
        Request::Wait { timeout_ms } => s.push_str(&format!(" {timeout_ms}")),
        Request::Ping | Request::State | Request::Joints | Request::Pose | Request::Stop => {}
    }
    s.push('\n');
    s
}

// ----------------------------------------------------------------------------------------------
// Server lines

/// Parse one line sent by a server: a reply or an event.
pub fn parse_server_line(raw: &str) -> Result<ServerLine, CodecError> {
    let line = clean_line(raw)?;
    let toks: Vec<&str> = line.split_whitespace().collect();
    let first = toks.first().copied().unwrap_or("");
    if first == "*" {
        if toks.get(1).copied() != Some("EVT") {
            return Err(CodecError::BadKeyword(
                toks.get(1).copied().unwrap_or("").to_string(),
            ));
        }
        let name_tok = toks.get(2).copied().ok_or(CodecError::Arity {
            what: "EVT",
            expected: ">= 1",
            got: 0,
        })?;
        let name = EventName::parse(name_tok)?;
        let data = toks[3..].join(" ");
        return Ok(ServerLine::Event(Event { name, data }));
    }
    let seq = parse_seq(first)?;
    let kw = toks.get(1).copied().unwrap_or("");
    let body = match kw {
        "OK" => ReplyBody::Ok(toks[2..].iter().map(|s| s.to_string()).collect()),
        "ERR" => {
            let code_tok = toks.get(2).copied().ok_or(CodecError::Arity {
                what: "ERR",
                expected: ">= 1",
                got: 0,
            })?;
            ReplyBody::Err {
                code: ErrorCode::parse(code_tok)?,
                text: toks[3..].join(" "),
            }
        }
        other => return Err(CodecError::BadKeyword(other.to_string())),
    };
    Ok(ServerLine::Reply(Reply { seq, body }))
}

/// Format a reply line, terminator `\n` included.
pub fn format_reply(reply: &Reply) -> String {
    match &reply.body {
        ReplyBody::Ok(data) => {
            let mut s = format!("{} OK", reply.seq);
            for d in data {
                s.push(' ');
                s.push_str(d);
            }
            s.push('\n');
            s
        }
        ReplyBody::Err { code, text } => {
            let text = sanitize_text(text);
            if text.is_empty() {
                format!("{} ERR {}\n", reply.seq, code)
            } else {
                format!("{} ERR {} {}\n", reply.seq, code, text)
            }
        }
    }
}

/// Format an event line, terminator `\n` included.
pub fn format_event(ev: &Event) -> String {
    let data = sanitize_text(&ev.data);
    if data.is_empty() {
        format!("* EVT {}\n", ev.name.as_str())
    } else {
        format!("* EVT {} {}\n", ev.name.as_str(), data)
    }
}

/// Normalise free text to printable ASCII words separated by single spaces.
pub fn sanitize_text(text: &str) -> String {
    text.split(|c: char| c.is_whitespace() || !c.is_ascii() || c.is_ascii_control())
        .filter(|w| !w.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

// ----------------------------------------------------------------------------------------------
// Typed reply data

/// Parse `OK j1..j6` data (degrees).
pub fn parse_joints(data: &[String]) -> Result<[f64; 6], CodecError> {
    check_arity("joints", "6", data.len(), data.len() == 6)?;
    let toks: Vec<&str> = data.iter().map(String::as_str).collect();
    parse_nums::<6>("joints", &toks)
}

/// Format joints (degrees) as reply data fields.
pub fn format_joints(joints_deg: &[f64; 6]) -> Vec<String> {
    joints_deg.iter().map(|v| fmt_num(*v)).collect()
}

/// Parse `OK x y z rx ry rz` data (mm, degrees).
pub fn parse_pose(data: &[String]) -> Result<Pose, CodecError> {
    check_arity("pose", "6", data.len(), data.len() == 6)?;
    let toks: Vec<&str> = data.iter().map(String::as_str).collect();
    let v = parse_nums::<6>("pose", &toks)?;
    Ok(Pose {
        xyz_mm: [v[0], v[1], v[2]],
        rxyz_deg: [v[3], v[4], v[5]],
    })
}

/// Format a pose as reply data fields.
pub fn format_pose(p: &Pose) -> Vec<String> {
    p.xyz_mm
        .iter()
        .chain(p.rxyz_deg.iter())
        .map(|v| fmt_num(*v))
        .collect()
}

/// Parse `OK <server_nonce>`, the data of a v3 `HELLO` reply.
pub fn parse_challenge(data: &[String]) -> Result<Nonce, CodecError> {
    check_arity("HELLO reply", "1", data.len(), data.len() == 1)?;
    Nonce::from_hex(&data[0]).ok_or_else(|| CodecError::BadValue {
        what: "HELLO reply (server nonce)",
        field: data[0].clone(),
    })
}

/// Parse `OK <ctrl> <arm> <sw> <server_proof>`, the data of an `AUTH` reply.
pub fn parse_auth_reply(data: &[String]) -> Result<(Identity, Proof), CodecError> {
    check_arity("AUTH reply", "4", data.len(), data.len() == 4)?;
    let proof = Proof::from_hex(&data[3]).ok_or_else(|| CodecError::BadValue {
        what: "AUTH reply (server proof)",
        field: data[3].clone(),
    })?;
    let identity = Identity {
        ctrl: data[0].clone(),
        arm: data[1].clone(),
        sw: data[2].clone(),
    };
    Ok((identity, proof))
}

/// Format an identity as reply data fields (spaces inside fields are replaced by `_`).
pub fn format_identity(id: &Identity) -> Vec<String> {
    [&id.ctrl, &id.arm, &id.sw]
        .iter()
        .map(|s| {
            let t = sanitize_text(s).replace(' ', "_");
            if t.is_empty() {
                "-".to_string()
            } else {
                t
            }
        })
        .collect()
}

fn parse_flag(key: &'static str, v: &str) -> Result<bool, CodecError> {
    match v {
        "0" => Ok(false),
        "1" => Ok(true),
        _ => Err(CodecError::BadValue {
            what: key,
            field: v.to_string(),
        }),
    }
}

/// Parse `OK power=0|1 mode=<m> estop=0|1 moving=0|1 settled=0|1` data (any order; all required).
pub fn parse_state(data: &[String]) -> Result<RobotState, CodecError> {
    check_arity("STATE reply", "5", data.len(), data.len() == 5)?;
    let (mut power, mut mode, mut estop, mut moving, mut settled) = (None, None, None, None, None);
    for f in data {
        let (k, v) = f.split_once('=').ok_or_else(|| CodecError::BadValue {
            what: "STATE reply",
            field: f.clone(),
        })?;
        match k {
            "power" => power = Some(parse_flag("power", v)?),
            "mode" if !v.is_empty() => mode = Some(v.to_string()),
            "estop" => estop = Some(parse_flag("estop", v)?),
            "moving" => moving = Some(parse_flag("moving", v)?),
            "settled" => settled = Some(parse_flag("settled", v)?),
            _ => {
                return Err(CodecError::BadValue {
                    what: "STATE reply",
                    field: f.clone(),
                })
            }
        }
    }
    match (power, mode, estop, moving, settled) {
        (Some(power), Some(mode), Some(estop), Some(moving), Some(settled)) => Ok(RobotState {
            power,
            mode,
            estop,
            moving,
            settled,
        }),
        _ => Err(CodecError::BadValue {
            what: "STATE reply",
            field: data.join(" "),
        }),
    }
}

/// Format a state as reply data fields.
pub fn format_state(s: &RobotState) -> Vec<String> {
    let b = |v: bool| if v { "1" } else { "0" };
    let mode = sanitize_text(&s.mode).replace(' ', "_");
    vec![
        format!("power={}", b(s.power)),
        format!("mode={}", if mode.is_empty() { "-" } else { &mode }),
        format!("estop={}", b(s.estop)),
        format!("moving={}", b(s.moving)),
        format!("settled={}", b(s.settled)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_examples() {
        let r = parse_request("12 MOVEJ 0 -90 90 0 45.5 0 20\r\n").unwrap();
        assert_eq!(r.seq, 12);
        assert_eq!(
            r.request,
            Request::MoveJ {
                joints_deg: [0.0, -90.0, 90.0, 0.0, 45.5, 0.0],
                vel_pct: Some(20.0)
            }
        );
        assert!(matches!(
            parse_request("1 MOVEJ 1 2 3").unwrap_err(),
            CodecError::Arity { .. }
        ));
        assert!(matches!(
            parse_request("1 MOVEJ 1 2 3 x 5 6").unwrap_err(),
            CodecError::NotNumeric { .. }
        ));
        assert!(matches!(
            parse_request("1 SPEED nan").unwrap_err(),
            CodecError::NotNumeric { .. }
        ));
        assert!(matches!(
            parse_request("1 FLY").unwrap_err(),
            CodecError::UnknownVerb(_)
        ));
        assert!(matches!(
            parse_request("x PING").unwrap_err(),
            CodecError::BadSeq(_)
        ));
        assert_eq!(
            parse_server_line("3 ERR E_LIMIT joint 2 out of range\n").unwrap(),
            ServerLine::Reply(Reply {
                seq: 3,
                body: ReplyBody::Err {
                    code: ErrorCode::Limit,
                    text: "joint 2 out of range".into()
                }
            })
        );
        assert_eq!(
            parse_server_line("* EVT ESTOP button\r\n").unwrap(),
            ServerLine::Event(Event {
                name: EventName::EStop,
                data: "button".into()
            })
        );
        let st = parse_server_line("4 OK power=1 mode=remote estop=0 moving=1 settled=0").unwrap();
        let ServerLine::Reply(Reply {
            body: ReplyBody::Ok(d),
            ..
        }) = st
        else {
            panic!("not ok")
        };
        let s = parse_state(&d).unwrap();
        assert!(s.power && s.moving && !s.settled && !s.estop);
        assert_eq!(s.mode, "remote");
    }

    #[test]
    fn error_classes() {
        assert!(parse_request("1 MOVEJ 1").unwrap_err().is_args_error());
        assert!(!parse_request("1 JUMP").unwrap_err().is_args_error());
        assert_eq!(parse_request(""), Err(CodecError::Empty));
        assert_eq!(parse_request("1 PI\u{e9}NG"), Err(CodecError::NotAscii));
        assert!(matches!(
            parse_request(&"1 ".repeat(1000)),
            Err(CodecError::TooLong(_))
        ));
    }

    #[test]
    fn v3_handshake_golden_bytes() {
        // PROTOCOL.md §3a example: K = 0x00..0x1f.
        let key = crate::auth::SharedSecret::from_hex(
            "000102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f",
            "test",
        )
        .unwrap();
        let ns = Nonce::from_hex("00112233445566778899aabbccddeeff").unwrap();
        let nc = Nonce::from_hex("0f0e0d0c0b0a09080706050403020100").unwrap();
        let auth = Request::Auth {
            client_nonce: nc,
            proof: key.client_proof(&ns, &nc),
        };
        assert_eq!(
            format_request(2, &auth),
            "2 AUTH 0f0e0d0c0b0a09080706050403020100 \
             4ec766f0727bc30b25adf756b618a2c0e144ae5264ce98c49f27cf6557f13cb2\n"
        );
        assert_eq!(
            format_request(1, &Request::Hello { proto_ver: 3 }),
            "1 HELLO 3\n"
        );
        let ServerLine::Reply(r) =
            parse_server_line("1 OK 00112233445566778899aabbccddeeff").unwrap()
        else {
            panic!("reply")
        };
        let ReplyBody::Ok(d) = r.body else {
            panic!("ok")
        };
        assert_eq!(parse_challenge(&d).unwrap(), ns);
        let line = "2 OK CS9 TX2-90 cellcal-val3-3 \
                    37719446d95386f3d2945a059f0b2c06a0a29f965a826f65eda2f6dab93cbfcf";
        let ServerLine::Reply(r) = parse_server_line(line).unwrap() else {
            panic!("reply")
        };
        let ReplyBody::Ok(d) = r.body else {
            panic!("ok")
        };
        let (id, proof) = parse_auth_reply(&d).unwrap();
        assert_eq!((id.ctrl.as_str(), id.arm.as_str()), ("CS9", "TX2-90"));
        assert!(key.verify_server(&ns, &nc, &proof));
        assert_eq!(
            format_reply(&Reply {
                seq: 2,
                body: ReplyBody::Err {
                    code: ErrorCode::Auth,
                    text: "authentication failed".into()
                }
            }),
            "2 ERR E_AUTH authentication failed\n"
        );
    }

    #[test]
    fn num_format() {
        assert_eq!(fmt_num(-0.0), "0.000000");
        assert_eq!(fmt_num(1.5), "1.500000");
        assert!(parse_num("t", "inf").is_err());
        assert!(parse_num("t", "-").is_err());
        assert_eq!(parse_num("t", "+1e2").unwrap(), 100.0);
    }
}
