//! Binary codec: typed packets, exact-size encode/decode (little-endian, pack(4), i32 `long`)
//! and an incremental [`FrameDecoder`] that turns arbitrary byte chunks into whole frames.

use crate::types::{
    cmd, data_type, status, Environment, MeasurementStatusInfo, ReflectorInfo, SystemSettings,
    SystemStatus, Units,
};

/// Size of `PacketHeaderT` (i32 size incl. header, i32 type).
pub const HEADER_SIZE: usize = 8;
/// Default upper bound for `lPacketSize` (64 KiB, as in emscon_ros).
pub const MAX_PACKET_SIZE: usize = 65536;
/// Size of a command without parameters (`BasicCommandCT`).
pub const BASIC_COMMAND_SIZE: usize = 12;
/// Size of a reply without payload (`BasicCommandRT`) and of `ErrorResponseT`.
pub const BASIC_REPLY_SIZE: usize = 16;
/// Size of `SystemStatusChangeT`.
pub const STATUS_CHANGE_SIZE: usize = 12;
/// Size of `SingleMeasResultT` (type 2).
pub const SINGLE_MEAS_RESULT_SIZE: usize = 156;
/// Size of `SingleMeasResult2T` (type 9).
pub const SINGLE_MEAS_RESULT2_SIZE: usize = 204;
/// Size of `ReflectorPosResultT` (type 7).
pub const REFLECTOR_POS_SIZE: usize = 36;
/// Size of `NivelResultT` (type 6).
pub const NIVEL_RESULT_SIZE: usize = 40;
/// Number of UTF-16 code units in a reflector name.
pub const REFLECTOR_NAME_LEN: usize = 32;

/// Codec failure; [`CodecError::is_fatal`] tells whether the byte stream can be resynchronised.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    /// The header's packet size is outside `8..=max`; the stream cannot be resynchronised.
    #[error("packet size {size} outside 8..={max}")]
    BadSize {
        /// Declared size.
        size: i32,
        /// Configured maximum.
        max: usize,
    },
    /// The data type is not one this codec knows (or not valid in this direction).
    #[error("unknown or unexpected data type {0}")]
    UnknownType(i32),
    /// A command packet carries an unknown command id.
    #[error("unknown command id {0}")]
    UnknownCommand(i32),
    /// The declared size does not match the size of the packet's type.
    #[error("packet type {data_type} (command {command:?}) has size {size}, expected {expected}")]
    SizeMismatch {
        /// Data type from the header.
        data_type: i32,
        /// Command id, where the packet has one.
        command: Option<i32>,
        /// Declared size.
        size: usize,
        /// Size expected for the type.
        expected: usize,
    },
    /// The frame is shorter than its fields (only for hand-made frames).
    #[error("frame truncated")]
    Truncated,
}

impl CodecError {
    /// True if the stream is broken beyond this frame (framing lost).
    pub fn is_fatal(&self) -> bool {
        matches!(self, CodecError::BadSize { .. })
    }
    /// Command id carried by the failed frame, if known.
    pub fn command(&self) -> Option<i32> {
        match self {
            CodecError::UnknownCommand(c) => Some(*c),
            CodecError::SizeMismatch { command, .. } => *command,
            _ => None,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Packet types

/// Client → server command packet (`*CT` structs, data type 0).
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// GetSystemStatus (1), CT 12.
    GetSystemStatus,
    /// SetUnits (5), CT 32.
    SetUnits(Units),
    /// GetUnits (6), CT 12.
    GetUnits,
    /// Initialize (7), CT 12.
    Initialize,
    /// SetEnvironmentParams (20), CT 36.
    SetEnvironmentParams(Environment),
    /// GetEnvironmentParams (21), CT 12.
    GetEnvironmentParams,
    /// SetMeasurementMode (24), CT 16; `ES_MeasMode` raw.
    SetMeasurementMode(i32),
    /// SetCoordinateSystemType (26), CT 16; `ES_CoordinateSystemType` raw.
    SetCoordinateSystemType(i32),
    /// SetStationaryModeParams (28), CT 20.
    SetStationaryModeParams {
        /// Measuring time in ms (`lMeasTime`).
        meas_time_ms: i32,
        /// Use the ADM (`bUseADM`).
        use_adm: bool,
    },
    /// GetStationaryModeParams (29), CT 12.
    GetStationaryModeParams,
    /// SetReflector (40), CT 16; internal reflector id.
    SetReflector(i32),
    /// GetReflector (41), CT 12.
    GetReflector,
    /// GetReflectors (42), CT 12; one RT per reflector follows.
    GetReflectors,
    /// SetSystemSettings (47), CT 48.
    SetSystemSettings(SystemSettings),
    /// GetSystemSettings (48), CT 12.
    GetSystemSettings,
    /// StartMeasurement (49), CT 12.
    StartMeasurement,
    /// StopMeasurement (52), CT 12.
    StopMeasurement,
    /// ChangeFace (53), CT 12.
    ChangeFace,
    /// GoBirdBath (54), CT 12.
    GoBirdBath,
    /// GoPosition (55), CT 40: point the beam at X, Y, Z (current units and coordinate system;
    /// the tracker locks on when a reflector is there).
    GoPosition {
        /// X (`dVal1`).
        x: f64,
        /// Y (`dVal2`).
        y: f64,
        /// Z (`dVal3`).
        z: f64,
        /// Measure the distance with the ADM on arrival (`bUseADM`).
        use_adm: bool,
    },
    /// GoLastMeasuredPoint (62), CT 12.
    GoLastMeasuredPoint,
    /// FindReflector (63), CT 20.
    FindReflector {
        /// Approximate distance in the current length unit.
        approx_distance: f64,
    },
    /// SetStatisticMode (80), CT 20; `ES_StatisticMode` raw (0 standard, 1 extended).
    SetStatisticMode {
        /// Mode for stationary measurements (1 → SingleMeasResult2).
        stationary: i32,
        /// Mode for continuous measurements.
        continuous: i32,
    },
    /// GetMeasurementStatusInfo (122), CT 12.
    GetMeasurementStatusInfo,
    /// GetObjectTemperature (127), CT 12.
    GetObjectTemperature,
    /// ClearCommandQueue (130), CT 16; `ES_ClearCommandQueueType` raw.
    ClearCommandQueue(i32),
}

/// Body of a command reply (the part after command id and status).
#[derive(Debug, Clone, PartialEq)]
pub enum ReplyBody {
    /// No payload (16-byte `BasicCommandRT`); also a short reply with non-OK status.
    Basic,
    /// GetSystemStatus payload (RT 56).
    SystemStatus(SystemStatus),
    /// GetUnits payload (RT 36).
    Units(Units),
    /// GetEnvironmentParams payload (RT 40).
    Environment(Environment),
    /// GetStationaryModeParams payload (RT 24).
    StationaryModeParams {
        /// Measuring time in ms.
        meas_time_ms: i32,
        /// ADM in use.
        use_adm: bool,
    },
    /// GetReflector payload (RT 20).
    ReflectorId(i32),
    /// One GetReflectors answer (RT 100).
    Reflector(ReflectorInfo),
    /// GetSystemSettings payload (RT 52).
    SystemSettings(SystemSettings),
    /// GetMeasurementStatusInfo payload (RT 24).
    MeasurementStatusInfo {
        /// Status of the last command.
        last_result_status: i32,
        /// Status bitmask.
        info: MeasurementStatusInfo,
    },
    /// GetObjectTemperature payload (RT 24).
    ObjectTemperature(f64),
    /// Raw payload of a reply to a command this codec does not know.
    Raw(Vec<u8>),
}

/// Server → client command reply (`*RT`, data type 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    /// Echoed command id.
    pub command: i32,
    /// Result status (`ES_ResultStatus`).
    pub status: i32,
    /// Typed payload.
    pub body: ReplyBody,
}

/// `ErrorResponseT` (data type 1), 16 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ErrorResponse {
    /// Command the error refers to.
    pub command: i32,
    /// Result status.
    pub status: i32,
}

/// `SingleMeasResultT` (data type 2), 156 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SingleMeasResult {
    /// Result status.
    pub status: i32,
    /// `ES_MeasMode`.
    pub meas_mode: i32,
    /// Try-mode flag.
    pub is_try_mode: bool,
    /// dVal1..3 (X, Y, Z in RHR).
    pub val: [f64; 3],
    /// dStd1..3.
    pub std: [f64; 3],
    /// dStdTotal.
    pub std_total: f64,
    /// dPointingError1..3.
    pub pointing_error: [f64; 3],
    /// dAprioriStd1..3.
    pub apriori_std: [f64; 3],
    /// dAprioriStdTotal.
    pub apriori_std_total: f64,
    /// dTemperature.
    pub temperature: f64,
    /// dPressure.
    pub pressure: f64,
    /// dHumidity.
    pub humidity: f64,
}

/// `SingleMeasResult2T` (data type 9), 204 bytes, with covariances.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SingleMeasResult2 {
    /// Result status.
    pub status: i32,
    /// `ES_MeasMode`.
    pub meas_mode: i32,
    /// Try-mode flag.
    pub is_try_mode: bool,
    /// dVal1..3.
    pub val: [f64; 3],
    /// dStd1..3.
    pub std: [f64; 3],
    /// dStdTotal.
    pub std_total: f64,
    /// dCovar12, dCovar13, dCovar23.
    pub covar: [f64; 3],
    /// dPointingErrorH/V/D.
    pub pointing_error: [f64; 3],
    /// dAprioriStd1..3.
    pub apriori_std: [f64; 3],
    /// dAprioriStdTotal.
    pub apriori_std_total: f64,
    /// dAprioriCovar12/13/23.
    pub apriori_covar: [f64; 3],
    /// dTemperature.
    pub temperature: f64,
    /// dPressure.
    pub pressure: f64,
    /// dHumidity.
    pub humidity: f64,
}

/// `ReflectorPosResultT` (data type 7), 36 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReflectorPosResult {
    /// Result status.
    pub status: i32,
    /// dVal1..3.
    pub val: [f64; 3],
}

/// `NivelResultT` (data type 6), 40 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NivelResult {
    /// Result status.
    pub status: i32,
    /// `ES_NivelStatus`.
    pub nivel_status: i32,
    /// X tilt.
    pub x_tilt: f64,
    /// Y tilt.
    pub y_tilt: f64,
    /// Nivel temperature.
    pub temperature: f64,
}

/// Any packet a server sends to a client.
#[derive(Debug, Clone, PartialEq)]
pub enum ServerPacket {
    /// Command reply (type 0).
    Reply(Reply),
    /// Error response (type 1).
    Error(ErrorResponse),
    /// Single measurement result (type 2).
    SingleMeasResult(SingleMeasResult),
    /// Nivel result (type 6).
    NivelResult(NivelResult),
    /// Reflector position (type 7).
    ReflectorPos(ReflectorPosResult),
    /// System status change (type 8) with its `ES_SystemStatusChange` code.
    StatusChange(i32),
    /// Single measurement result with extended statistics (type 9).
    SingleMeasResult2(SingleMeasResult2),
}

// ---------------------------------------------------------------------------------------------
// Size tables

/// Total CT size for a known command id, `None` if unknown.
pub fn command_size(command: i32) -> Option<usize> {
    Some(match command {
        cmd::GET_SYSTEM_STATUS
        | cmd::GET_UNITS
        | cmd::INITIALIZE
        | cmd::GET_ENVIRONMENT_PARAMS
        | cmd::GET_STATIONARY_MODE_PARAMS
        | cmd::GET_REFLECTOR
        | cmd::GET_REFLECTORS
        | cmd::GET_SYSTEM_SETTINGS
        | cmd::START_MEASUREMENT
        | cmd::STOP_MEASUREMENT
        | cmd::CHANGE_FACE
        | cmd::GO_BIRD_BATH
        | cmd::GO_LAST_MEASURED_POINT
        | cmd::GET_MEASUREMENT_STATUS_INFO
        | cmd::GET_OBJECT_TEMPERATURE => BASIC_COMMAND_SIZE,
        cmd::SET_UNITS => 32,
        cmd::SET_ENVIRONMENT_PARAMS => 36,
        cmd::SET_MEASUREMENT_MODE
        | cmd::SET_COORDINATE_SYSTEM_TYPE
        | cmd::SET_REFLECTOR
        | cmd::CLEAR_COMMAND_QUEUE => 16,
        cmd::SET_STATIONARY_MODE_PARAMS | cmd::FIND_REFLECTOR | cmd::SET_STATISTIC_MODE => 20,
        cmd::SET_SYSTEM_SETTINGS => 48,
        cmd::GO_POSITION => 40,
        _ => return None,
    })
}

/// Total full-size RT size for a known command id, `None` if unknown.
pub fn reply_size(command: i32) -> Option<usize> {
    Some(match command {
        cmd::GET_SYSTEM_STATUS => 56,
        cmd::GET_UNITS => 36,
        cmd::GET_ENVIRONMENT_PARAMS => 40,
        cmd::GET_STATIONARY_MODE_PARAMS => 24,
        cmd::GET_REFLECTOR => 20,
        cmd::GET_REFLECTORS => 100,
        cmd::GET_SYSTEM_SETTINGS => 52,
        cmd::GET_MEASUREMENT_STATUS_INFO | cmd::GET_OBJECT_TEMPERATURE => 24,
        c if command_size(c).is_some() => BASIC_REPLY_SIZE,
        _ => return None,
    })
}

impl Command {
    /// Command id (`ES_Command`).
    pub fn id(&self) -> i32 {
        match self {
            Command::GetSystemStatus => cmd::GET_SYSTEM_STATUS,
            Command::SetUnits(_) => cmd::SET_UNITS,
            Command::GetUnits => cmd::GET_UNITS,
            Command::Initialize => cmd::INITIALIZE,
            Command::SetEnvironmentParams(_) => cmd::SET_ENVIRONMENT_PARAMS,
            Command::GetEnvironmentParams => cmd::GET_ENVIRONMENT_PARAMS,
            Command::SetMeasurementMode(_) => cmd::SET_MEASUREMENT_MODE,
            Command::SetCoordinateSystemType(_) => cmd::SET_COORDINATE_SYSTEM_TYPE,
            Command::SetStationaryModeParams { .. } => cmd::SET_STATIONARY_MODE_PARAMS,
            Command::GetStationaryModeParams => cmd::GET_STATIONARY_MODE_PARAMS,
            Command::SetReflector(_) => cmd::SET_REFLECTOR,
            Command::GetReflector => cmd::GET_REFLECTOR,
            Command::GetReflectors => cmd::GET_REFLECTORS,
            Command::SetSystemSettings(_) => cmd::SET_SYSTEM_SETTINGS,
            Command::GetSystemSettings => cmd::GET_SYSTEM_SETTINGS,
            Command::StartMeasurement => cmd::START_MEASUREMENT,
            Command::StopMeasurement => cmd::STOP_MEASUREMENT,
            Command::ChangeFace => cmd::CHANGE_FACE,
            Command::GoBirdBath => cmd::GO_BIRD_BATH,
            Command::GoPosition { .. } => cmd::GO_POSITION,
            Command::GoLastMeasuredPoint => cmd::GO_LAST_MEASURED_POINT,
            Command::FindReflector { .. } => cmd::FIND_REFLECTOR,
            Command::SetStatisticMode { .. } => cmd::SET_STATISTIC_MODE,
            Command::GetMeasurementStatusInfo => cmd::GET_MEASUREMENT_STATUS_INFO,
            Command::GetObjectTemperature => cmd::GET_OBJECT_TEMPERATURE,
            Command::ClearCommandQueue(_) => cmd::CLEAR_COMMAND_QUEUE,
        }
    }

    /// Encodes the command into a new buffer.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer::start(data_type::COMMAND);
        w.i32(self.id());
        match self {
            Command::SetUnits(u) => w.units(u),
            Command::SetEnvironmentParams(e) => w.environment(e),
            Command::SetMeasurementMode(v)
            | Command::SetCoordinateSystemType(v)
            | Command::SetReflector(v)
            | Command::ClearCommandQueue(v) => w.i32(*v),
            Command::SetStationaryModeParams {
                meas_time_ms,
                use_adm,
            } => {
                w.i32(*meas_time_ms);
                w.bool(*use_adm);
            }
            Command::SetSystemSettings(s) => w.settings(s),
            Command::FindReflector { approx_distance } => w.f64(*approx_distance),
            Command::GoPosition { x, y, z, use_adm } => {
                w.f64(*x);
                w.f64(*y);
                w.f64(*z);
                w.bool(*use_adm);
            }
            Command::SetStatisticMode {
                stationary,
                continuous,
            } => {
                w.i32(*stationary);
                w.i32(*continuous);
            }
            _ => {}
        }
        w.finish()
    }

    /// Decodes one whole frame (header included) as a command packet.
    pub fn decode(frame: &[u8]) -> Result<Command, CodecError> {
        let mut r = Reader::new(frame);
        let size = r.frame_size()?;
        let ty = r.i32()?;
        if ty != data_type::COMMAND {
            return Err(CodecError::UnknownType(ty));
        }
        if size < BASIC_COMMAND_SIZE {
            return Err(CodecError::SizeMismatch {
                data_type: ty,
                command: None,
                size,
                expected: BASIC_COMMAND_SIZE,
            });
        }
        let id = r.i32()?;
        let expected = command_size(id).ok_or(CodecError::UnknownCommand(id))?;
        if size != expected {
            return Err(CodecError::SizeMismatch {
                data_type: ty,
                command: Some(id),
                size,
                expected,
            });
        }
        Ok(match id {
            cmd::GET_SYSTEM_STATUS => Command::GetSystemStatus,
            cmd::SET_UNITS => Command::SetUnits(r.units()?),
            cmd::GET_UNITS => Command::GetUnits,
            cmd::INITIALIZE => Command::Initialize,
            cmd::SET_ENVIRONMENT_PARAMS => Command::SetEnvironmentParams(r.environment()?),
            cmd::GET_ENVIRONMENT_PARAMS => Command::GetEnvironmentParams,
            cmd::SET_MEASUREMENT_MODE => Command::SetMeasurementMode(r.i32()?),
            cmd::SET_COORDINATE_SYSTEM_TYPE => Command::SetCoordinateSystemType(r.i32()?),
            cmd::SET_STATIONARY_MODE_PARAMS => Command::SetStationaryModeParams {
                meas_time_ms: r.i32()?,
                use_adm: r.bool()?,
            },
            cmd::GET_STATIONARY_MODE_PARAMS => Command::GetStationaryModeParams,
            cmd::SET_REFLECTOR => Command::SetReflector(r.i32()?),
            cmd::GET_REFLECTOR => Command::GetReflector,
            cmd::GET_REFLECTORS => Command::GetReflectors,
            cmd::SET_SYSTEM_SETTINGS => Command::SetSystemSettings(r.settings()?),
            cmd::GET_SYSTEM_SETTINGS => Command::GetSystemSettings,
            cmd::START_MEASUREMENT => Command::StartMeasurement,
            cmd::STOP_MEASUREMENT => Command::StopMeasurement,
            cmd::CHANGE_FACE => Command::ChangeFace,
            cmd::GO_BIRD_BATH => Command::GoBirdBath,
            cmd::GO_POSITION => Command::GoPosition {
                x: r.f64()?,
                y: r.f64()?,
                z: r.f64()?,
                use_adm: r.bool()?,
            },
            cmd::GO_LAST_MEASURED_POINT => Command::GoLastMeasuredPoint,
            cmd::FIND_REFLECTOR => Command::FindReflector {
                approx_distance: r.f64()?,
            },
            cmd::SET_STATISTIC_MODE => Command::SetStatisticMode {
                stationary: r.i32()?,
                continuous: r.i32()?,
            },
            cmd::GET_MEASUREMENT_STATUS_INFO => Command::GetMeasurementStatusInfo,
            cmd::GET_OBJECT_TEMPERATURE => Command::GetObjectTemperature,
            cmd::CLEAR_COMMAND_QUEUE => Command::ClearCommandQueue(r.i32()?),
            other => return Err(CodecError::UnknownCommand(other)),
        })
    }
}

impl ReplyBody {
    /// Zero-filled full-size body for `command` (used for replies with non-OK status).
    pub fn zeroed_for(command: i32) -> ReplyBody {
        match command {
            cmd::GET_SYSTEM_STATUS => ReplyBody::SystemStatus(SystemStatus::default()),
            cmd::GET_UNITS => ReplyBody::Units(Units {
                length: 0,
                angle: 0,
                temperature: 0,
                pressure: 0,
                humidity: 0,
            }),
            cmd::GET_ENVIRONMENT_PARAMS => ReplyBody::Environment(Environment::default()),
            cmd::GET_STATIONARY_MODE_PARAMS => ReplyBody::StationaryModeParams {
                meas_time_ms: 0,
                use_adm: false,
            },
            cmd::GET_REFLECTOR => ReplyBody::ReflectorId(0),
            cmd::GET_REFLECTORS => ReplyBody::Reflector(ReflectorInfo {
                total: 0,
                id: 0,
                target_type: 0,
                surface_offset: 0.0,
                name: String::new(),
            }),
            cmd::GET_SYSTEM_SETTINGS => ReplyBody::SystemSettings(SystemSettings {
                weather_monitor_status: 0,
                apply_transformation: false,
                apply_station_orientation: false,
                keep_last_position: false,
                send_unsolicited_messages: false,
                send_reflector_position_data: false,
                try_measurement_mode: false,
                has_nivel: false,
                has_video_camera: false,
            }),
            cmd::GET_MEASUREMENT_STATUS_INFO => ReplyBody::MeasurementStatusInfo {
                last_result_status: 0,
                info: MeasurementStatusInfo(0),
            },
            cmd::GET_OBJECT_TEMPERATURE => ReplyBody::ObjectTemperature(0.0),
            _ => ReplyBody::Basic,
        }
    }
}

impl Reply {
    /// A reply with a full-size zeroed body (what a server sends with a non-OK status).
    pub fn failed(command: i32, status: i32) -> Reply {
        Reply {
            command,
            status,
            body: ReplyBody::zeroed_for(command),
        }
    }
    /// A reply with OK status and no payload.
    pub fn ok(command: i32) -> Reply {
        Self::ok_with(command, status::ALL_OK)
    }
    /// A 16-byte reply without payload carrying `status`.
    pub fn ok_with(command: i32, status: i32) -> Reply {
        Reply {
            command,
            status,
            body: ReplyBody::Basic,
        }
    }
}

impl ServerPacket {
    /// Data type (`ES_DataType`) of this packet.
    pub fn data_type(&self) -> i32 {
        match self {
            ServerPacket::Reply(_) => data_type::COMMAND,
            ServerPacket::Error(_) => data_type::ERROR,
            ServerPacket::SingleMeasResult(_) => data_type::SINGLE_MEAS_RESULT,
            ServerPacket::NivelResult(_) => data_type::NIVEL_RESULT,
            ServerPacket::ReflectorPos(_) => data_type::REFLECTOR_POS_RESULT,
            ServerPacket::StatusChange(_) => data_type::SYSTEM_STATUS_CHANGE,
            ServerPacket::SingleMeasResult2(_) => data_type::SINGLE_MEAS_RESULT2,
        }
    }

    /// Encodes the packet into a new buffer.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer::start(self.data_type());
        match self {
            ServerPacket::Reply(rep) => {
                w.i32(rep.command);
                w.i32(rep.status);
                match &rep.body {
                    ReplyBody::Basic => {}
                    ReplyBody::SystemStatus(s) => {
                        w.i32(s.last_result_status);
                        w.i32(s.tracker_processor_status);
                        w.i32(s.laser_status);
                        w.i32(s.adm_status);
                        for v in s.version {
                            w.i32(v);
                        }
                        w.i32(s.weather_monitor_status);
                        w.i32(s.flags);
                        w.i32(s.serial_number);
                    }
                    ReplyBody::Units(u) => w.units(u),
                    ReplyBody::Environment(e) => w.environment(e),
                    ReplyBody::StationaryModeParams {
                        meas_time_ms,
                        use_adm,
                    } => {
                        w.i32(*meas_time_ms);
                        w.bool(*use_adm);
                    }
                    ReplyBody::ReflectorId(id) => w.i32(*id),
                    ReplyBody::Reflector(info) => {
                        w.i32(info.total);
                        w.i32(info.id);
                        w.i32(info.target_type);
                        w.f64(info.surface_offset);
                        let mut units: Vec<u16> = info.name.encode_utf16().collect();
                        units.resize(REFLECTOR_NAME_LEN, 0);
                        for u in units {
                            w.buf.extend_from_slice(&u.to_le_bytes());
                        }
                    }
                    ReplyBody::SystemSettings(s) => w.settings(s),
                    ReplyBody::MeasurementStatusInfo {
                        last_result_status,
                        info,
                    } => {
                        w.i32(*last_result_status);
                        w.buf.extend_from_slice(&info.0.to_le_bytes());
                    }
                    ReplyBody::ObjectTemperature(t) => w.f64(*t),
                    ReplyBody::Raw(raw) => w.buf.extend_from_slice(raw),
                }
            }
            ServerPacket::Error(e) => {
                w.i32(e.command);
                w.i32(e.status);
            }
            ServerPacket::SingleMeasResult(m) => {
                w.i32(m.status);
                w.i32(m.meas_mode);
                w.bool(m.is_try_mode);
                w.f64s(&m.val);
                w.f64s(&m.std);
                w.f64(m.std_total);
                w.f64s(&m.pointing_error);
                w.f64s(&m.apriori_std);
                w.f64(m.apriori_std_total);
                w.f64(m.temperature);
                w.f64(m.pressure);
                w.f64(m.humidity);
            }
            ServerPacket::SingleMeasResult2(m) => {
                w.i32(m.status);
                w.i32(m.meas_mode);
                w.bool(m.is_try_mode);
                w.f64s(&m.val);
                w.f64s(&m.std);
                w.f64(m.std_total);
                w.f64s(&m.covar);
                w.f64s(&m.pointing_error);
                w.f64s(&m.apriori_std);
                w.f64(m.apriori_std_total);
                w.f64s(&m.apriori_covar);
                w.f64(m.temperature);
                w.f64(m.pressure);
                w.f64(m.humidity);
            }
            ServerPacket::NivelResult(n) => {
                w.i32(n.status);
                w.i32(n.nivel_status);
                w.f64(n.x_tilt);
                w.f64(n.y_tilt);
                w.f64(n.temperature);
            }
            ServerPacket::ReflectorPos(p) => {
                w.i32(p.status);
                w.f64s(&p.val);
            }
            ServerPacket::StatusChange(code) => w.i32(*code),
        }
        w.finish()
    }

    /// Decodes one whole frame (header included) as a server packet.
    ///
    /// A reply to a known command must have that command's full RT size, except that a
    /// 16-byte reply is tolerated when the status is not OK. A reply to an unknown command is
    /// surfaced as [`ReplyBody::Raw`].
    pub fn decode(frame: &[u8]) -> Result<ServerPacket, CodecError> {
        let mut r = Reader::new(frame);
        let size = r.frame_size()?;
        let ty = r.i32()?;
        let fixed = |expected: usize| -> Result<(), CodecError> {
            if size == expected {
                Ok(())
            } else {
                Err(CodecError::SizeMismatch {
                    data_type: ty,
                    command: None,
                    size,
                    expected,
                })
            }
        };
        match ty {
            data_type::COMMAND => {
                if size < BASIC_REPLY_SIZE {
                    return Err(CodecError::SizeMismatch {
                        data_type: ty,
                        command: None,
                        size,
                        expected: BASIC_REPLY_SIZE,
                    });
                }
                let command = r.i32()?;
                let st = r.i32()?;
                let body = match reply_size(command) {
                    None => {
                        ReplyBody::Raw(frame.get(BASIC_REPLY_SIZE..size).unwrap_or(&[]).to_vec())
                    }
                    Some(_) if size == BASIC_REPLY_SIZE && st != status::ALL_OK => ReplyBody::Basic,
                    Some(expected) if expected != size => {
                        return Err(CodecError::SizeMismatch {
                            data_type: ty,
                            command: Some(command),
                            size,
                            expected,
                        })
                    }
                    Some(_) => r.reply_body(command)?,
                };
                Ok(ServerPacket::Reply(Reply {
                    command,
                    status: st,
                    body,
                }))
            }
            data_type::ERROR => {
                fixed(BASIC_REPLY_SIZE)?;
                Ok(ServerPacket::Error(ErrorResponse {
                    command: r.i32()?,
                    status: r.i32()?,
                }))
            }
            data_type::SINGLE_MEAS_RESULT => {
                fixed(SINGLE_MEAS_RESULT_SIZE)?;
                Ok(ServerPacket::SingleMeasResult(SingleMeasResult {
                    status: r.i32()?,
                    meas_mode: r.i32()?,
                    is_try_mode: r.bool()?,
                    val: r.f64s()?,
                    std: r.f64s()?,
                    std_total: r.f64()?,
                    pointing_error: r.f64s()?,
                    apriori_std: r.f64s()?,
                    apriori_std_total: r.f64()?,
                    temperature: r.f64()?,
                    pressure: r.f64()?,
                    humidity: r.f64()?,
                }))
            }
            data_type::SINGLE_MEAS_RESULT2 => {
                fixed(SINGLE_MEAS_RESULT2_SIZE)?;
                Ok(ServerPacket::SingleMeasResult2(SingleMeasResult2 {
                    status: r.i32()?,
                    meas_mode: r.i32()?,
                    is_try_mode: r.bool()?,
                    val: r.f64s()?,
                    std: r.f64s()?,
                    std_total: r.f64()?,
                    covar: r.f64s()?,
                    pointing_error: r.f64s()?,
                    apriori_std: r.f64s()?,
                    apriori_std_total: r.f64()?,
                    apriori_covar: r.f64s()?,
                    temperature: r.f64()?,
                    pressure: r.f64()?,
                    humidity: r.f64()?,
                }))
            }
            data_type::NIVEL_RESULT => {
                fixed(NIVEL_RESULT_SIZE)?;
                Ok(ServerPacket::NivelResult(NivelResult {
                    status: r.i32()?,
                    nivel_status: r.i32()?,
                    x_tilt: r.f64()?,
                    y_tilt: r.f64()?,
                    temperature: r.f64()?,
                }))
            }
            data_type::REFLECTOR_POS_RESULT => {
                fixed(REFLECTOR_POS_SIZE)?;
                Ok(ServerPacket::ReflectorPos(ReflectorPosResult {
                    status: r.i32()?,
                    val: r.f64s()?,
                }))
            }
            data_type::SYSTEM_STATUS_CHANGE => {
                fixed(STATUS_CHANGE_SIZE)?;
                Ok(ServerPacket::StatusChange(r.i32()?))
            }
            other => Err(CodecError::UnknownType(other)),
        }
    }
}

/// Something that can be decoded from one whole frame.
pub trait Decode: Sized {
    /// Decodes `frame` (header included, length equal to the declared size).
    fn decode_frame(frame: &[u8]) -> Result<Self, CodecError>;
}

impl Decode for Command {
    fn decode_frame(frame: &[u8]) -> Result<Self, CodecError> {
        Command::decode(frame)
    }
}

impl Decode for ServerPacket {
    fn decode_frame(frame: &[u8]) -> Result<Self, CodecError> {
        ServerPacket::decode(frame)
    }
}

// ---------------------------------------------------------------------------------------------
// Frame decoder

/// Incremental frame splitter: feed arbitrary chunks with [`FrameDecoder::push`], take whole
/// frames with [`FrameDecoder::next_frame`] or typed packets with [`FrameDecoder::next_packet`].
///
/// A header with a size outside `8..=max` is fatal: the error is returned once, after which
/// the decoder discards all input and yields nothing.
#[derive(Debug)]
pub struct FrameDecoder {
    buf: Vec<u8>,
    start: usize,
    max: usize,
    failed: bool,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// Decoder with the default 64 KiB size cap.
    pub fn new() -> Self {
        Self::with_max_size(MAX_PACKET_SIZE)
    }

    /// Decoder with a custom size cap (clamped to at least the header size).
    pub fn with_max_size(max: usize) -> Self {
        FrameDecoder {
            buf: Vec::new(),
            start: 0,
            max: max.max(HEADER_SIZE),
            failed: false,
        }
    }

    /// Appends received bytes.
    pub fn push(&mut self, data: &[u8]) {
        if self.failed {
            return;
        }
        if self.start > 0 && self.start >= self.buf.len() / 2 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(data);
    }

    /// Number of buffered bytes not yet returned as frames.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.start
    }

    /// True after a fatal framing error.
    pub fn is_failed(&self) -> bool {
        self.failed
    }

    /// Next whole frame (header included), `Ok(None)` if more bytes are needed.
    pub fn next_frame(&mut self) -> Result<Option<Vec<u8>>, CodecError> {
        if self.failed {
            return Ok(None);
        }
        let avail = &self.buf[self.start..];
        let Some(hdr) = avail.get(0..4) else {
            return Ok(None);
        };
        let size = i32::from_le_bytes([hdr[0], hdr[1], hdr[2], hdr[3]]);
        let size_ok = usize::try_from(size)
            .ok()
            .filter(|s| (HEADER_SIZE..=self.max).contains(s));
        let Some(size) = size_ok else {
            self.failed = true;
            self.buf = Vec::new();
            self.start = 0;
            return Err(CodecError::BadSize {
                size,
                max: self.max,
            });
        };
        let Some(frame) = avail.get(0..size) else {
            return Ok(None);
        };
        let frame = frame.to_vec();
        self.start += size;
        if self.start == self.buf.len() {
            self.buf.clear();
            self.start = 0;
        }
        Ok(Some(frame))
    }

    /// Next whole frame decoded as `T`; a non-fatal error consumes only the bad frame.
    pub fn next_packet<T: Decode>(&mut self) -> Result<Option<T>, CodecError> {
        match self.next_frame()? {
            None => Ok(None),
            Some(frame) => T::decode_frame(&frame).map(Some),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Little-endian helpers

struct Writer {
    buf: Vec<u8>,
}

impl Writer {
    fn start(ty: i32) -> Writer {
        let mut buf = Vec::with_capacity(64);
        buf.extend_from_slice(&0i32.to_le_bytes());
        buf.extend_from_slice(&ty.to_le_bytes());
        Writer { buf }
    }
    fn i32(&mut self, v: i32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn bool(&mut self, v: bool) {
        self.i32(i32::from(v));
    }
    fn f64(&mut self, v: f64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn f64s(&mut self, v: &[f64; 3]) {
        for x in v {
            self.f64(*x);
        }
    }
    fn units(&mut self, u: &Units) {
        self.i32(u.length);
        self.i32(u.angle);
        self.i32(u.temperature);
        self.i32(u.pressure);
        self.i32(u.humidity);
    }
    fn environment(&mut self, e: &Environment) {
        self.f64(e.temperature);
        self.f64(e.pressure);
        self.f64(e.humidity);
    }
    fn settings(&mut self, s: &SystemSettings) {
        self.i32(s.weather_monitor_status);
        self.bool(s.apply_transformation);
        self.bool(s.apply_station_orientation);
        self.bool(s.keep_last_position);
        self.bool(s.send_unsolicited_messages);
        self.bool(s.send_reflector_position_data);
        self.bool(s.try_measurement_mode);
        self.bool(s.has_nivel);
        self.bool(s.has_video_camera);
    }
    fn finish(mut self) -> Vec<u8> {
        let len = i32::try_from(self.buf.len()).unwrap_or(i32::MAX);
        self.buf[0..4].copy_from_slice(&len.to_le_bytes());
        self.buf
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(buf: &'a [u8]) -> Self {
        Reader { buf, pos: 0 }
    }
    fn take<const N: usize>(&mut self) -> Result<[u8; N], CodecError> {
        let end = self.pos.checked_add(N).ok_or(CodecError::Truncated)?;
        let s = self.buf.get(self.pos..end).ok_or(CodecError::Truncated)?;
        self.pos = end;
        <[u8; N]>::try_from(s).map_err(|_| CodecError::Truncated)
    }
    /// Reads the size field and checks it against the frame length.
    fn frame_size(&mut self) -> Result<usize, CodecError> {
        let size = self.i32()?;
        let s = usize::try_from(size)
            .ok()
            .filter(|s| *s >= HEADER_SIZE)
            .ok_or(CodecError::BadSize {
                size,
                max: MAX_PACKET_SIZE,
            })?;
        if s != self.buf.len() {
            return Err(CodecError::Truncated);
        }
        Ok(s)
    }
    fn i32(&mut self) -> Result<i32, CodecError> {
        Ok(i32::from_le_bytes(self.take::<4>()?))
    }
    fn u32(&mut self) -> Result<u32, CodecError> {
        Ok(u32::from_le_bytes(self.take::<4>()?))
    }
    fn bool(&mut self) -> Result<bool, CodecError> {
        Ok(self.i32()? != 0)
    }
    fn f64(&mut self) -> Result<f64, CodecError> {
        Ok(f64::from_le_bytes(self.take::<8>()?))
    }
    fn f64s(&mut self) -> Result<[f64; 3], CodecError> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }
    fn units(&mut self) -> Result<Units, CodecError> {
        Ok(Units {
            length: self.i32()?,
            angle: self.i32()?,
            temperature: self.i32()?,
            pressure: self.i32()?,
            humidity: self.i32()?,
        })
    }
    fn environment(&mut self) -> Result<Environment, CodecError> {
        Ok(Environment {
            temperature: self.f64()?,
            pressure: self.f64()?,
            humidity: self.f64()?,
        })
    }
    fn settings(&mut self) -> Result<SystemSettings, CodecError> {
        Ok(SystemSettings {
            weather_monitor_status: self.i32()?,
            apply_transformation: self.bool()?,
            apply_station_orientation: self.bool()?,
            keep_last_position: self.bool()?,
            send_unsolicited_messages: self.bool()?,
            send_reflector_position_data: self.bool()?,
            try_measurement_mode: self.bool()?,
            has_nivel: self.bool()?,
            has_video_camera: self.bool()?,
        })
    }
    fn reply_body(&mut self, command: i32) -> Result<ReplyBody, CodecError> {
        Ok(match command {
            cmd::GET_SYSTEM_STATUS => ReplyBody::SystemStatus(SystemStatus {
                last_result_status: self.i32()?,
                tracker_processor_status: self.i32()?,
                laser_status: self.i32()?,
                adm_status: self.i32()?,
                version: [self.i32()?, self.i32()?, self.i32()?],
                weather_monitor_status: self.i32()?,
                flags: self.i32()?,
                serial_number: self.i32()?,
            }),
            cmd::GET_UNITS => ReplyBody::Units(self.units()?),
            cmd::GET_ENVIRONMENT_PARAMS => ReplyBody::Environment(self.environment()?),
            cmd::GET_STATIONARY_MODE_PARAMS => ReplyBody::StationaryModeParams {
                meas_time_ms: self.i32()?,
                use_adm: self.bool()?,
            },
            cmd::GET_REFLECTOR => ReplyBody::ReflectorId(self.i32()?),
            cmd::GET_REFLECTORS => {
                let total = self.i32()?;
                let id = self.i32()?;
                let target_type = self.i32()?;
                let surface_offset = self.f64()?;
                let mut units = Vec::with_capacity(REFLECTOR_NAME_LEN);
                for _ in 0..REFLECTOR_NAME_LEN {
                    units.push(u16::from_le_bytes(self.take::<2>()?));
                }
                let end = units.iter().position(|u| *u == 0).unwrap_or(units.len());
                ReplyBody::Reflector(ReflectorInfo {
                    total,
                    id,
                    target_type,
                    surface_offset,
                    name: String::from_utf16_lossy(&units[..end]),
                })
            }
            cmd::GET_SYSTEM_SETTINGS => ReplyBody::SystemSettings(self.settings()?),
            cmd::GET_MEASUREMENT_STATUS_INFO => ReplyBody::MeasurementStatusInfo {
                last_result_status: self.i32()?,
                info: MeasurementStatusInfo(self.u32()?),
            },
            cmd::GET_OBJECT_TEMPERATURE => ReplyBody::ObjectTemperature(self.f64()?),
            _ => ReplyBody::Basic,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_sizes_match_table() {
        let cases: Vec<(Command, usize)> = vec![
            (Command::GetSystemStatus, 12),
            (Command::SetUnits(Units::MM_DEG), 32),
            (Command::Initialize, 12),
            (
                Command::SetEnvironmentParams(Environment {
                    temperature: 20.0,
                    pressure: 1013.0,
                    humidity: 50.0,
                }),
                36,
            ),
            (Command::SetMeasurementMode(0), 16),
            (Command::SetCoordinateSystemType(0), 16),
            (
                Command::SetStationaryModeParams {
                    meas_time_ms: 1000,
                    use_adm: true,
                },
                20,
            ),
            (Command::SetReflector(1), 16),
            (Command::GetReflectors, 12),
            (Command::SetSystemSettings(SystemSettings::default()), 48),
            (Command::StartMeasurement, 12),
            (Command::StopMeasurement, 12),
            (Command::GoLastMeasuredPoint, 12),
            (
                Command::GoPosition {
                    x: 1500.0,
                    y: -250.5,
                    z: 300.25,
                    use_adm: true,
                },
                40,
            ),
            (
                Command::FindReflector {
                    approx_distance: 3000.0,
                },
                20,
            ),
            (Command::GetMeasurementStatusInfo, 12),
            (Command::ClearCommandQueue(0), 16),
        ];
        for (c, size) in cases {
            let b = c.to_bytes();
            assert_eq!(b.len(), size, "{c:?}");
            assert_eq!(command_size(c.id()), Some(size));
            assert_eq!(Command::decode(&b), Ok(c));
        }
    }

    #[test]
    fn decoder_rejects_bad_sizes_once() {
        let mut d = FrameDecoder::new();
        d.push(&4i32.to_le_bytes());
        d.push(&0i32.to_le_bytes());
        assert!(matches!(
            d.next_frame(),
            Err(CodecError::BadSize { size: 4, .. })
        ));
        assert!(d.is_failed());
        assert_eq!(d.next_frame(), Ok(None));
    }

    #[test]
    fn short_failed_reply_is_tolerated() {
        let full = ServerPacket::Reply(Reply::failed(cmd::GET_SYSTEM_STATUS, 39)).to_bytes();
        assert_eq!(full.len(), 56);
        let short = ServerPacket::Reply(Reply {
            command: cmd::GET_SYSTEM_STATUS,
            status: 39,
            body: ReplyBody::Basic,
        })
        .to_bytes();
        assert_eq!(short.len(), 16);
        assert!(ServerPacket::decode(&short).is_ok());
        let mut ok_short = short.clone();
        ok_short[12..16].copy_from_slice(&0i32.to_le_bytes());
        assert!(matches!(
            ServerPacket::decode(&ok_short),
            Err(CodecError::SizeMismatch { .. })
        ));
    }
}
