//! RTDE (Real-Time Data Exchange, TCP 30004) wire format, protocol version 2.
//!
//! Every package is `uint16 size` (header included) + `uint8 type` + payload, big-endian
//! (UR's RTDE guide; `rtde/serialize.py` of UR's RTDE client library: `struct ">HB"`).
//! The package types are ASCII letters: `V` request protocol version, `v` get URControl
//! version, `M` text message, `U` data package, `O` setup outputs, `I` setup inputs,
//! `S` start, `P` pause.

use thiserror::Error;

/// Bytes of the package header (`uint16 size`, `uint8 type`).
pub const HEADER_LEN: usize = 3;
/// The protocol version this crate speaks.
pub const PROTOCOL_VERSION: u16 = 2;

/// `V`: request protocol version.
pub const REQUEST_PROTOCOL_VERSION: u8 = b'V';
/// `v`: get URControl version.
pub const GET_URCONTROL_VERSION: u8 = b'v';
/// `M`: text message.
pub const TEXT_MESSAGE: u8 = b'M';
/// `U`: data package.
pub const DATA_PACKAGE: u8 = b'U';
/// `O`: control package setup outputs.
pub const SETUP_OUTPUTS: u8 = b'O';
/// `I`: control package setup inputs.
pub const SETUP_INPUTS: u8 = b'I';
/// `S`: control package start.
pub const START: u8 = b'S';
/// `P`: control package pause.
pub const PAUSE: u8 = b'P';

/// A package that cannot be decoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum RtdeCodecError {
    /// The header's size is below the header length: the stream cannot be resynchronised.
    #[error("RTDE package size {0} is below the 3-byte header")]
    BadSize(u16),
    /// The package type letter is not one this side understands.
    #[error("unknown RTDE package type {0:#04x}")]
    UnknownType(u8),
    /// The payload does not have the layout its type requires.
    #[error("malformed RTDE package {kind:?}: {why}")]
    Malformed {
        /// The package type letter.
        kind: char,
        /// What is wrong.
        why: String,
    },
    /// The package would not fit the 16-bit size field.
    #[error("RTDE package of {0} bytes does not fit the 16-bit size field")]
    TooLong(usize),
}

impl RtdeCodecError {
    /// Whether the byte stream is lost (no later package can be found in it).
    pub fn is_fatal(&self) -> bool {
        matches!(self, RtdeCodecError::BadSize(_))
    }
}

fn malformed(kind: u8, why: impl Into<String>) -> RtdeCodecError {
    RtdeCodecError::Malformed {
        kind: char::from(kind),
        why: why.into(),
    }
}

/// The value types of RTDE fields, by their wire names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RtdeType {
    /// `BOOL`: one byte, 0 or 1.
    Bool,
    /// `UINT8`.
    Uint8,
    /// `UINT32`.
    Uint32,
    /// `UINT64`.
    Uint64,
    /// `INT32`.
    Int32,
    /// `DOUBLE` (IEEE 754 binary64).
    Double,
    /// `VECTOR3D`: three doubles.
    Vector3d,
    /// `VECTOR6D`: six doubles.
    Vector6d,
    /// `VECTOR6INT32`: six INT32.
    Vector6Int32,
    /// `VECTOR6UINT32`: six UINT32.
    Vector6Uint32,
}

impl RtdeType {
    /// The wire name (`VECTOR6D`, ...).
    pub fn name(self) -> &'static str {
        match self {
            RtdeType::Bool => "BOOL",
            RtdeType::Uint8 => "UINT8",
            RtdeType::Uint32 => "UINT32",
            RtdeType::Uint64 => "UINT64",
            RtdeType::Int32 => "INT32",
            RtdeType::Double => "DOUBLE",
            RtdeType::Vector3d => "VECTOR3D",
            RtdeType::Vector6d => "VECTOR6D",
            RtdeType::Vector6Int32 => "VECTOR6INT32",
            RtdeType::Vector6Uint32 => "VECTOR6UINT32",
        }
    }

    /// The type named `name` on the wire; `None` for `NOT_FOUND`, `IN_USE` and anything else.
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "BOOL" => RtdeType::Bool,
            "UINT8" => RtdeType::Uint8,
            "UINT32" => RtdeType::Uint32,
            "UINT64" => RtdeType::Uint64,
            "INT32" => RtdeType::Int32,
            "DOUBLE" => RtdeType::Double,
            "VECTOR3D" => RtdeType::Vector3d,
            "VECTOR6D" => RtdeType::Vector6d,
            "VECTOR6INT32" => RtdeType::Vector6Int32,
            "VECTOR6UINT32" => RtdeType::Vector6Uint32,
            _ => return None,
        })
    }

    /// Encoded size in bytes.
    pub fn size(self) -> usize {
        match self {
            RtdeType::Bool | RtdeType::Uint8 => 1,
            RtdeType::Uint32 | RtdeType::Int32 => 4,
            RtdeType::Uint64 | RtdeType::Double => 8,
            RtdeType::Vector3d => 24,
            RtdeType::Vector6d => 48,
            RtdeType::Vector6Int32 | RtdeType::Vector6Uint32 => 24,
        }
    }
}

/// One field value of a data package.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// `BOOL`.
    Bool(bool),
    /// `UINT8`.
    Uint8(u8),
    /// `UINT32`.
    Uint32(u32),
    /// `UINT64`.
    Uint64(u64),
    /// `INT32`.
    Int32(i32),
    /// `DOUBLE`.
    Double(f64),
    /// `VECTOR3D`.
    Vector3d([f64; 3]),
    /// `VECTOR6D`.
    Vector6d([f64; 6]),
    /// `VECTOR6INT32`.
    Vector6Int32([i32; 6]),
    /// `VECTOR6UINT32`.
    Vector6Uint32([u32; 6]),
}

impl Value {
    /// The type of this value.
    pub fn ty(&self) -> RtdeType {
        match self {
            Value::Bool(_) => RtdeType::Bool,
            Value::Uint8(_) => RtdeType::Uint8,
            Value::Uint32(_) => RtdeType::Uint32,
            Value::Uint64(_) => RtdeType::Uint64,
            Value::Int32(_) => RtdeType::Int32,
            Value::Double(_) => RtdeType::Double,
            Value::Vector3d(_) => RtdeType::Vector3d,
            Value::Vector6d(_) => RtdeType::Vector6d,
            Value::Vector6Int32(_) => RtdeType::Vector6Int32,
            Value::Vector6Uint32(_) => RtdeType::Vector6Uint32,
        }
    }

    /// The zero value of `ty`.
    pub fn zero(ty: RtdeType) -> Value {
        match ty {
            RtdeType::Bool => Value::Bool(false),
            RtdeType::Uint8 => Value::Uint8(0),
            RtdeType::Uint32 => Value::Uint32(0),
            RtdeType::Uint64 => Value::Uint64(0),
            RtdeType::Int32 => Value::Int32(0),
            RtdeType::Double => Value::Double(0.0),
            RtdeType::Vector3d => Value::Vector3d([0.0; 3]),
            RtdeType::Vector6d => Value::Vector6d([0.0; 6]),
            RtdeType::Vector6Int32 => Value::Vector6Int32([0; 6]),
            RtdeType::Vector6Uint32 => Value::Vector6Uint32([0; 6]),
        }
    }

    /// Appends the big-endian encoding.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        match self {
            Value::Bool(b) => out.push(u8::from(*b)),
            Value::Uint8(v) => out.push(*v),
            Value::Uint32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Uint64(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Int32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Double(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Vector3d(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6d(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Int32(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Uint32(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
        }
    }

    /// Decodes one value of `ty` from the front of `b` (exactly `ty.size()` bytes are read).
    fn decode(ty: RtdeType, b: &[u8]) -> Value {
        let d = |i: usize| f64::from_be_bytes(b[i * 8..i * 8 + 8].try_into().expect("8 bytes"));
        let i32_at = |i: usize| i32::from_be_bytes(b[i * 4..i * 4 + 4].try_into().expect("4"));
        let u32_at = |i: usize| u32::from_be_bytes(b[i * 4..i * 4 + 4].try_into().expect("4"));
        match ty {
            RtdeType::Bool => Value::Bool(b[0] != 0),
            RtdeType::Uint8 => Value::Uint8(b[0]),
            RtdeType::Uint32 => Value::Uint32(u32_at(0)),
            RtdeType::Uint64 => Value::Uint64(u64::from_be_bytes(b[..8].try_into().expect("8"))),
            RtdeType::Int32 => Value::Int32(i32_at(0)),
            RtdeType::Double => Value::Double(d(0)),
            RtdeType::Vector3d => Value::Vector3d(std::array::from_fn(d)),
            RtdeType::Vector6d => Value::Vector6d(std::array::from_fn(d)),
            RtdeType::Vector6Int32 => Value::Vector6Int32(std::array::from_fn(i32_at)),
            RtdeType::Vector6Uint32 => Value::Vector6Uint32(std::array::from_fn(u32_at)),
        }
    }
}

/// Encodes a data package payload's values (after the recipe id byte).
pub fn encode_values(values: &[Value]) -> Vec<u8> {
    let mut out = Vec::new();
    values.iter().for_each(|v| v.encode_into(&mut out));
    out
}

/// Decodes a data package's values (after the recipe id byte) with the recipe's `types`.
/// The length must match the recipe exactly.
pub fn decode_values(types: &[RtdeType], bytes: &[u8]) -> Result<Vec<Value>, RtdeCodecError> {
    let want: usize = types.iter().map(|t| t.size()).sum();
    if bytes.len() != want {
        return Err(malformed(
            DATA_PACKAGE,
            format!("{} value bytes, the recipe needs {want}", bytes.len()),
        ));
    }
    let mut at = 0;
    Ok(types
        .iter()
        .map(|&t| {
            let v = Value::decode(t, &bytes[at..at + t.size()]);
            at += t.size();
            v
        })
        .collect())
}

/// Severity of a text message (protocol version 2 numbering).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageLevel {
    /// 0: exception.
    Exception,
    /// 1: error.
    Error,
    /// 2: warning.
    Warning,
    /// 3: info.
    Info,
}

impl MessageLevel {
    /// The wire byte.
    pub fn code(self) -> u8 {
        match self {
            MessageLevel::Exception => 0,
            MessageLevel::Error => 1,
            MessageLevel::Warning => 2,
            MessageLevel::Info => 3,
        }
    }
    /// The level of wire byte `b`.
    pub fn from_code(b: u8) -> Option<Self> {
        Some(match b {
            0 => MessageLevel::Exception,
            1 => MessageLevel::Error,
            2 => MessageLevel::Warning,
            3 => MessageLevel::Info,
            _ => return None,
        })
    }
}

/// A text message (v2 layout: `uint8 len, message, uint8 len, source, uint8 level`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TextMessage {
    /// The message.
    pub message: String,
    /// Who sent it.
    pub source: String,
    /// How severe it is.
    pub level: MessageLevel,
}

impl TextMessage {
    fn encode_into(&self, out: &mut Vec<u8>) {
        for s in [&self.message, &self.source] {
            let b = s.as_bytes();
            let b = &b[..b.len().min(255)];
            out.push(b.len() as u8);
            out.extend_from_slice(b);
        }
        out.push(self.level.code());
    }

    fn decode(p: &[u8]) -> Result<Self, RtdeCodecError> {
        let bad = |why: &str| malformed(TEXT_MESSAGE, why);
        let (mlen, rest) = p.split_first().ok_or_else(|| bad("empty"))?;
        let mlen = usize::from(*mlen);
        if rest.len() < mlen + 1 {
            return Err(bad("message shorter than its length byte"));
        }
        let (msg, rest) = rest.split_at(mlen);
        let (slen, rest) = rest.split_first().ok_or_else(|| bad("no source length"))?;
        let slen = usize::from(*slen);
        if rest.len() != slen + 1 {
            return Err(bad("source and level do not fill the package"));
        }
        let (src, level) = rest.split_at(slen);
        let level = MessageLevel::from_code(level[0]).ok_or_else(|| bad("unknown level"))?;
        Ok(TextMessage {
            message: String::from_utf8_lossy(msg).into_owned(),
            source: String::from_utf8_lossy(src).into_owned(),
            level,
        })
    }
}

/// A package the client sends to the controller.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientPackage {
    /// `V` + `uint16 version`.
    RequestProtocolVersion(u16),
    /// `v`, no payload.
    GetUrcontrolVersion,
    /// `O` (v2): `double frequency` + comma-separated variable names.
    SetupOutputs {
        /// Requested output rate in Hz.
        frequency: f64,
        /// Output variable names, in the order the data packages carry them.
        names: Vec<String>,
    },
    /// `I`: comma-separated input variable names.
    SetupInputs(Vec<String>),
    /// `S`, no payload.
    Start,
    /// `P`, no payload.
    Pause,
    /// `U`: `uint8 recipe id` + the input values.
    Data {
        /// Input recipe id.
        recipe: u8,
        /// The encoded values (see [`decode_values`]).
        values: Vec<u8>,
    },
    /// `M`: a text message for the controller's log.
    Text(TextMessage),
}

/// A package the controller sends to the client.
#[derive(Debug, Clone, PartialEq)]
pub enum ServerPackage {
    /// `V` + `uint8 accepted`.
    ProtocolVersion(bool),
    /// `v` + four `uint32`: major, minor, bugfix, build.
    UrcontrolVersion {
        /// Major version (3 = CB3, 5 = e-Series).
        major: u32,
        /// Minor version.
        minor: u32,
        /// Bugfix version.
        bugfix: u32,
        /// Build number.
        build: u32,
    },
    /// `O` (v2): `uint8 recipe id` + comma-separated types (`NOT_FOUND` for unknown names).
    SetupOutputs {
        /// Output recipe id.
        recipe: u8,
        /// One wire type name per requested variable.
        types: Vec<String>,
    },
    /// `I`: `uint8 recipe id` + comma-separated types (`IN_USE`, `NOT_FOUND`).
    SetupInputs {
        /// Input recipe id (0: refused).
        recipe: u8,
        /// One wire type name per requested variable.
        types: Vec<String>,
    },
    /// `S` + `uint8 accepted`.
    Start(bool),
    /// `P` + `uint8 accepted`.
    Pause(bool),
    /// `U`: `uint8 recipe id` + the output values.
    Data {
        /// Output recipe id.
        recipe: u8,
        /// The encoded values (see [`decode_values`]).
        values: Vec<u8>,
    },
    /// `M` (v2 layout).
    Text(TextMessage),
}

fn frame(kind: u8, payload: &[u8]) -> Result<Vec<u8>, RtdeCodecError> {
    let size = HEADER_LEN + payload.len();
    let size16 = u16::try_from(size).map_err(|_| RtdeCodecError::TooLong(size))?;
    let mut out = Vec::with_capacity(size);
    out.extend_from_slice(&size16.to_be_bytes());
    out.push(kind);
    out.extend_from_slice(payload);
    Ok(out)
}

fn names_text(kind: u8, p: &[u8]) -> Result<Vec<String>, RtdeCodecError> {
    let s = std::str::from_utf8(p).map_err(|_| malformed(kind, "names are not UTF-8"))?;
    // ur_rtde ends its list with a comma; a controller takes that as no extra name
    let s = s.strip_suffix(',').unwrap_or(s);
    Ok(s.split(',').map(str::to_owned).collect())
}

fn bool_reply(kind: u8, p: &[u8]) -> Result<bool, RtdeCodecError> {
    match p {
        [b] => Ok(*b != 0),
        _ => Err(malformed(
            kind,
            format!("{} payload bytes, want 1", p.len()),
        )),
    }
}

fn no_payload(kind: u8, p: &[u8]) -> Result<(), RtdeCodecError> {
    if p.is_empty() {
        Ok(())
    } else {
        Err(malformed(
            kind,
            format!("{} payload bytes, want none", p.len()),
        ))
    }
}

impl ClientPackage {
    /// The package type letter.
    pub fn kind(&self) -> u8 {
        match self {
            ClientPackage::RequestProtocolVersion(_) => REQUEST_PROTOCOL_VERSION,
            ClientPackage::GetUrcontrolVersion => GET_URCONTROL_VERSION,
            ClientPackage::SetupOutputs { .. } => SETUP_OUTPUTS,
            ClientPackage::SetupInputs(_) => SETUP_INPUTS,
            ClientPackage::Start => START,
            ClientPackage::Pause => PAUSE,
            ClientPackage::Data { .. } => DATA_PACKAGE,
            ClientPackage::Text(_) => TEXT_MESSAGE,
        }
    }

    /// The complete package, header included.
    pub fn encode(&self) -> Result<Vec<u8>, RtdeCodecError> {
        let mut p = Vec::new();
        match self {
            ClientPackage::RequestProtocolVersion(v) => p.extend_from_slice(&v.to_be_bytes()),
            ClientPackage::GetUrcontrolVersion | ClientPackage::Start | ClientPackage::Pause => {}
            ClientPackage::SetupOutputs { frequency, names } => {
                p.extend_from_slice(&frequency.to_be_bytes());
                p.extend_from_slice(names.join(",").as_bytes());
            }
            ClientPackage::SetupInputs(names) => p.extend_from_slice(names.join(",").as_bytes()),
            ClientPackage::Data { recipe, values } => {
                p.push(*recipe);
                p.extend_from_slice(values);
            }
            ClientPackage::Text(t) => t.encode_into(&mut p),
        }
        frame(self.kind(), &p)
    }

    /// Decodes the payload `p` of a package of type `kind`.
    pub fn decode(kind: u8, p: &[u8]) -> Result<Self, RtdeCodecError> {
        Ok(match kind {
            REQUEST_PROTOCOL_VERSION => match p {
                [a, b] => ClientPackage::RequestProtocolVersion(u16::from_be_bytes([*a, *b])),
                _ => return Err(malformed(kind, "want a uint16 version")),
            },
            GET_URCONTROL_VERSION => {
                no_payload(kind, p)?;
                ClientPackage::GetUrcontrolVersion
            }
            SETUP_OUTPUTS => {
                if p.len() < 8 {
                    return Err(malformed(kind, "no frequency"));
                }
                let frequency = f64::from_be_bytes(p[..8].try_into().expect("8 bytes"));
                ClientPackage::SetupOutputs {
                    frequency,
                    names: names_text(kind, &p[8..])?,
                }
            }
            SETUP_INPUTS => ClientPackage::SetupInputs(names_text(kind, p)?),
            START => {
                no_payload(kind, p)?;
                ClientPackage::Start
            }
            PAUSE => {
                no_payload(kind, p)?;
                ClientPackage::Pause
            }
            DATA_PACKAGE => match p.split_first() {
                Some((recipe, values)) => ClientPackage::Data {
                    recipe: *recipe,
                    values: values.to_vec(),
                },
                None => return Err(malformed(kind, "no recipe id")),
            },
            TEXT_MESSAGE => ClientPackage::Text(TextMessage::decode(p)?),
            other => return Err(RtdeCodecError::UnknownType(other)),
        })
    }
}

impl ServerPackage {
    /// The package type letter.
    pub fn kind(&self) -> u8 {
        match self {
            ServerPackage::ProtocolVersion(_) => REQUEST_PROTOCOL_VERSION,
            ServerPackage::UrcontrolVersion { .. } => GET_URCONTROL_VERSION,
            ServerPackage::SetupOutputs { .. } => SETUP_OUTPUTS,
            ServerPackage::SetupInputs { .. } => SETUP_INPUTS,
            ServerPackage::Start(_) => START,
            ServerPackage::Pause(_) => PAUSE,
            ServerPackage::Data { .. } => DATA_PACKAGE,
            ServerPackage::Text(_) => TEXT_MESSAGE,
        }
    }

    /// The complete package, header included.
    pub fn encode(&self) -> Result<Vec<u8>, RtdeCodecError> {
        let mut p = Vec::new();
        match self {
            ServerPackage::ProtocolVersion(ok) | ServerPackage::Start(ok) => p.push(u8::from(*ok)),
            ServerPackage::Pause(ok) => p.push(u8::from(*ok)),
            ServerPackage::UrcontrolVersion {
                major,
                minor,
                bugfix,
                build,
            } => [major, minor, bugfix, build]
                .iter()
                .for_each(|v| p.extend_from_slice(&v.to_be_bytes())),
            ServerPackage::SetupOutputs { recipe, types }
            | ServerPackage::SetupInputs { recipe, types } => {
                p.push(*recipe);
                p.extend_from_slice(types.join(",").as_bytes());
            }
            ServerPackage::Data { recipe, values } => {
                p.push(*recipe);
                p.extend_from_slice(values);
            }
            ServerPackage::Text(t) => t.encode_into(&mut p),
        }
        frame(self.kind(), &p)
    }

    /// Decodes the payload `p` of a package of type `kind`.
    pub fn decode(kind: u8, p: &[u8]) -> Result<Self, RtdeCodecError> {
        Ok(match kind {
            REQUEST_PROTOCOL_VERSION => ServerPackage::ProtocolVersion(bool_reply(kind, p)?),
            GET_URCONTROL_VERSION => {
                if p.len() != 16 {
                    return Err(malformed(
                        kind,
                        format!("{} payload bytes, want 16", p.len()),
                    ));
                }
                let u = |i: usize| u32::from_be_bytes(p[i * 4..i * 4 + 4].try_into().expect("4"));
                ServerPackage::UrcontrolVersion {
                    major: u(0),
                    minor: u(1),
                    bugfix: u(2),
                    build: u(3),
                }
            }
            SETUP_OUTPUTS | SETUP_INPUTS => {
                let (recipe, rest) = p
                    .split_first()
                    .ok_or_else(|| malformed(kind, "no recipe id"))?;
                let types = names_text(kind, rest)?;
                if kind == SETUP_OUTPUTS {
                    ServerPackage::SetupOutputs {
                        recipe: *recipe,
                        types,
                    }
                } else {
                    ServerPackage::SetupInputs {
                        recipe: *recipe,
                        types,
                    }
                }
            }
            START => ServerPackage::Start(bool_reply(kind, p)?),
            PAUSE => ServerPackage::Pause(bool_reply(kind, p)?),
            DATA_PACKAGE => match p.split_first() {
                Some((recipe, values)) => ServerPackage::Data {
                    recipe: *recipe,
                    values: values.to_vec(),
                },
                None => return Err(malformed(kind, "no recipe id")),
            },
            TEXT_MESSAGE => ServerPackage::Text(TextMessage::decode(p)?),
            other => return Err(RtdeCodecError::UnknownType(other)),
        })
    }
}

/// Splits a byte stream into packages; keeps partial packages across pushes.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    buf: Vec<u8>,
    failed: bool,
}

impl FrameDecoder {
    /// An empty decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes buffered and not yet returned.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Whether a fatal error lost the stream.
    pub fn is_failed(&self) -> bool {
        self.failed
    }

    /// The next complete package as `(type, payload)`; `Ok(None)` until one is complete.
    pub fn next_frame(&mut self) -> Result<Option<(u8, Vec<u8>)>, RtdeCodecError> {
        if self.failed {
            return Err(RtdeCodecError::BadSize(0));
        }
        if self.buf.len() < HEADER_LEN {
            return Ok(None);
        }
        let size = u16::from_be_bytes([self.buf[0], self.buf[1]]);
        if usize::from(size) < HEADER_LEN {
            self.failed = true;
            return Err(RtdeCodecError::BadSize(size));
        }
        let size = usize::from(size);
        if self.buf.len() < size {
            return Ok(None);
        }
        let kind = self.buf[2];
        let payload = self.buf[HEADER_LEN..size].to_vec();
        self.buf.drain(..size);
        Ok(Some((kind, payload)))
    }

    /// The next complete package decoded as a [`ServerPackage`].
    pub fn next_server(&mut self) -> Result<Option<ServerPackage>, RtdeCodecError> {
        match self.next_frame()? {
            Some((k, p)) => ServerPackage::decode(k, &p).map(Some),
            None => Ok(None),
        }
    }

    /// The next complete package decoded as a [`ClientPackage`].
    pub fn next_client(&mut self) -> Result<Option<ClientPackage>, RtdeCodecError> {
        match self.next_frame()? {
            Some((k, p)) => ClientPackage::decode(k, &p).map(Some),
            None => Ok(None),
        }
    }
}
