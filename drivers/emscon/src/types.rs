//! Protocol constants (data types, command ids, status codes) and plain data structs
//! shared by the codec, the client and the server (emScon TPI 3.6 numbering).

/// Packet data types (`ES_DataType`, the `type` field of the header).
pub mod data_type {
    /// `ES_DT_Command`: command (client → server) or command reply (server → client).
    pub const COMMAND: i32 = 0;
    /// `ES_DT_Error`: error response, solicited or unsolicited.
    pub const ERROR: i32 = 1;
    /// `ES_DT_SingleMeasResult`: stationary measurement result.
    pub const SINGLE_MEAS_RESULT: i32 = 2;
    /// `ES_DT_NivelResult`: inclination sensor result.
    pub const NIVEL_RESULT: i32 = 6;
    /// `ES_DT_ReflectorPosResult`: reflector position while locked.
    pub const REFLECTOR_POS_RESULT: i32 = 7;
    /// `ES_DT_SystemStatusChange`: system status change event.
    pub const SYSTEM_STATUS_CHANGE: i32 = 8;
    /// `ES_DT_SingleMeasResult2`: stationary result with extended statistics.
    pub const SINGLE_MEAS_RESULT2: i32 = 9;
}

/// Command ids (`ES_Command`) supported by the codec.
pub mod cmd {
    /// `ES_C_GetSystemStatus`.
    pub const GET_SYSTEM_STATUS: i32 = 1;
    /// `ES_C_SetUnits`.
    pub const SET_UNITS: i32 = 5;
    /// `ES_C_GetUnits`.
    pub const GET_UNITS: i32 = 6;
    /// `ES_C_Initialize`.
    pub const INITIALIZE: i32 = 7;
    /// `ES_C_SetEnvironmentParams`.
    pub const SET_ENVIRONMENT_PARAMS: i32 = 20;
    /// `ES_C_GetEnvironmentParams`.
    pub const GET_ENVIRONMENT_PARAMS: i32 = 21;
    /// `ES_C_SetMeasurementMode`.
    pub const SET_MEASUREMENT_MODE: i32 = 24;
    /// `ES_C_SetCoordinateSystemType`.
    pub const SET_COORDINATE_SYSTEM_TYPE: i32 = 26;
    /// `ES_C_SetStationaryModeParams`.
    pub const SET_STATIONARY_MODE_PARAMS: i32 = 28;
    /// `ES_C_GetStationaryModeParams`.
    pub const GET_STATIONARY_MODE_PARAMS: i32 = 29;
    /// `ES_C_SetReflector`.
    pub const SET_REFLECTOR: i32 = 40;
    /// `ES_C_GetReflector`.
    pub const GET_REFLECTOR: i32 = 41;
    /// `ES_C_GetReflectors`.
    pub const GET_REFLECTORS: i32 = 42;
    /// `ES_C_SetSystemSettings`.
    pub const SET_SYSTEM_SETTINGS: i32 = 47;
    /// `ES_C_GetSystemSettings`.
    pub const GET_SYSTEM_SETTINGS: i32 = 48;
    /// `ES_C_StartMeasurement`.
    pub const START_MEASUREMENT: i32 = 49;
    /// `ES_C_StopMeasurement`.
    pub const STOP_MEASUREMENT: i32 = 52;
    /// `ES_C_ChangeFace`.
    pub const CHANGE_FACE: i32 = 53;
    /// `ES_C_GoBirdBath`.
    pub const GO_BIRD_BATH: i32 = 54;
    /// `ES_C_GoPosition`.
    pub const GO_POSITION: i32 = 55;
    /// `ES_C_GoLastMeasuredPoint`.
    pub const GO_LAST_MEASURED_POINT: i32 = 62;
    /// `ES_C_FindReflector`.
    pub const FIND_REFLECTOR: i32 = 63;
    /// `ES_C_Unknown` (also used by the simulator for connection-level errors).
    pub const UNKNOWN: i32 = 64;
    /// `ES_C_SetStatisticMode`.
    pub const SET_STATISTIC_MODE: i32 = 80;
    /// `ES_C_GetMeasurementStatusInfo`.
    pub const GET_MEASUREMENT_STATUS_INFO: i32 = 122;
    /// `ES_C_GetObjectTemperature`.
    pub const GET_OBJECT_TEMPERATURE: i32 = 127;
    /// `ES_C_ClearCommandQueue`.
    pub const CLEAR_COMMAND_QUEUE: i32 = 130;
}

/// Result status codes (`ES_ResultStatus`) used by this crate.
pub mod status {
    /// `ES_RS_AllOK`.
    pub const ALL_OK: i32 = 0;
    /// `ES_RS_ServerBusy` (a pending command).
    pub const SERVER_BUSY: i32 = 1;
    /// `ES_RS_NotImplemented`.
    pub const NOT_IMPLEMENTED: i32 = 2;
    /// `ES_RS_WrongParameter`.
    pub const WRONG_PARAMETER: i32 = 3;
    /// `ES_RS_WrongParameter1` (further parameters count up to 10).
    pub const WRONG_PARAMETER1: i32 = 4;
    /// `ES_RS_WrongCurrentReflector`.
    pub const WRONG_CURRENT_REFLECTOR: i32 = 23;
    /// `ES_RS_NoTPFound`.
    pub const NO_TP_FOUND: i32 = 26;
    /// `ES_RS_NoLastMeasuredPoint`.
    pub const NO_LAST_MEASURED_POINT: i32 = 28;
    /// `ES_RS_NoTrackerConnected`.
    pub const NO_TRACKER_CONNECTED: i32 = 38;
    /// `ES_RS_TrackerNotInitialized`.
    pub const TRACKER_NOT_INITIALIZED: i32 = 39;
    /// `ES_RS_ModuleTimedOut`.
    pub const MODULE_TIMED_OUT: i32 = 41;
    /// `ES_RS_MeteoDataOutOfRange`.
    pub const METEO_DATA_OUT_OF_RANGE: i32 = 57;
    /// `ES_RS_MeasurementStatusNotReady`.
    pub const MEASUREMENT_STATUS_NOT_READY: i32 = 10004;
    /// `ES_RS_NoStationaryResult`.
    pub const NO_STATIONARY_RESULT: i32 = 10009;
    /// `ES_RS_SensorNotLeveled`.
    pub const SENSOR_NOT_LEVELED: i32 = 10010;
    /// `ES_RS_MultiConnectionsNotAllowed`.
    pub const MULTI_CONNECTIONS_NOT_ALLOWED: i32 = 10011;
    /// `ES_RS_SensorNotWarmedUp`.
    pub const SENSOR_NOT_WARMED_UP: i32 = 10012;
    /// `ES_RS_SensorNotStable`.
    pub const SENSOR_NOT_STABLE: i32 = 10013;
    /// `ES_RS_SystemNotReadyForMeasurement`.
    pub const SYSTEM_NOT_READY_FOR_MEASUREMENT: i32 = 10014;
    /// `ES_RS_CommunicationWithSensorFailed`.
    pub const COMMUNICATION_WITH_SENSOR_FAILED: i32 = 10015;
}

/// System status change codes (`ES_SystemStatusChange`) used by this crate.
pub mod status_change {
    /// `ES_SSC_LaserWarmedUp` (as listed in DEVICES.md; not in the 3.6 header extract).
    pub const LASER_WARMED_UP: i32 = 1;
    /// `ES_SSC_EnvironmentParamsChanged`.
    pub const ENVIRONMENT_PARAMS_CHANGED: i32 = 2;
    /// `ES_SSC_UnitsChanged`.
    pub const UNITS_CHANGED: i32 = 6;
    /// `ES_SSC_ReflectorChanged`.
    pub const REFLECTOR_CHANGED: i32 = 7;
    /// `ES_SSC_SystemSettingsChanged`.
    pub const SYSTEM_SETTINGS_CHANGED: i32 = 8;
    /// `ES_SSC_CoordinateSystemTypeChanged`.
    pub const COORDINATE_SYSTEM_TYPE_CHANGED: i32 = 12;
    /// `ES_SSC_MeasurementModeChanged`.
    pub const MEASUREMENT_MODE_CHANGED: i32 = 17;
    /// `ES_SSC_StationaryModeParamsChanged`.
    pub const STATIONARY_MODE_PARAMS_CHANGED: i32 = 18;
    /// `ES_SSC_MeasStatus_NotReady` (also emitted on a beam break).
    pub const MEAS_STATUS_NOT_READY: i32 = 25;
    /// `ES_SSC_MeasStatus_Busy`.
    pub const MEAS_STATUS_BUSY: i32 = 26;
    /// `ES_SSC_MeasStatus_Ready`.
    pub const MEAS_STATUS_READY: i32 = 27;
    /// `ES_SSC_IsFace1`.
    pub const IS_FACE1: i32 = 30;
    /// `ES_SSC_IsFace2`.
    pub const IS_FACE2: i32 = 31;
    /// `ES_SCC_InitializationStatusChanged` (header spelling `ES_SCC_`).
    pub const INITIALIZATION_STATUS_CHANGED: i32 = 151;
    /// `ES_SSC_TPConnectionClosing`.
    pub const TP_CONNECTION_CLOSING: i32 = 997;
    /// `ES_SSC_ServerClosing`.
    pub const SERVER_CLOSING: i32 = 998;
    /// `ES_SSC_ServerStarted`.
    pub const SERVER_STARTED: i32 = 999;
}

/// `ES_TrackerProcessorStatus` value meaning the tracker is initialised.
pub const TPS_INITIALIZED: i32 = 5;
/// `ES_TrackerProcessorStatus` value meaning a compensation is set (booted, not initialised).
pub const TPS_COMPENSATION_SET: i32 = 4;
/// `ES_MM_Stationary` measurement mode.
pub const MEAS_MODE_STATIONARY: i32 = 0;
/// `ES_CS_RHR` coordinate system type (Cartesian, right-handed).
pub const COORD_SYS_RHR: i32 = 0;
/// `ES_WMS_ReadAndCalculateRefractions` weather monitor status.
pub const WEATHER_READ_AND_CALCULATE: i32 = 2;

/// Length unit (`ES_LengthUnit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(i32)]
pub enum LengthUnit {
    /// Metre.
    Meter = 0,
    /// Millimetre.
    Millimeter = 1,
    /// Micrometre.
    Micron = 2,
    /// Foot.
    Foot = 3,
    /// Yard.
    Yard = 4,
    /// Inch.
    Inch = 5,
}

/// Angle unit (`ES_AngleUnit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(i32)]
pub enum AngleUnit {
    /// Radian.
    Radian = 0,
    /// Degree.
    Degree = 1,
    /// Gon.
    Gon = 2,
}

/// Unit settings (`SystemUnitsDataT`, 5 × i32); enum fields kept raw for forward compatibility.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Units {
    /// `ES_LengthUnit` (1 = mm).
    pub length: i32,
    /// `ES_AngleUnit` (1 = degree).
    pub angle: i32,
    /// `ES_TemperatureUnit` (0 = °C).
    pub temperature: i32,
    /// `ES_PressureUnit` (0 = mbar).
    pub pressure: i32,
    /// `ES_HumidityUnit` (0 = %RH).
    pub humidity: i32,
}

impl Units {
    /// Millimetre, degree, °C, mbar, %RH — the units this crate assumes.
    pub const MM_DEG: Units = Units {
        length: LengthUnit::Millimeter as i32,
        angle: AngleUnit::Degree as i32,
        temperature: 0,
        pressure: 0,
        humidity: 0,
    };
}

impl Default for Units {
    fn default() -> Self {
        Units::MM_DEG
    }
}

/// Environment parameters (`EnvironmentDataT`, 3 × f64).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Environment {
    /// Temperature in the current unit (°C).
    pub temperature: f64,
    /// Pressure in the current unit (mbar).
    pub pressure: f64,
    /// Relative humidity in %.
    pub humidity: f64,
}

/// System settings (`SystemSettingsDataT`, 9 × i32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SystemSettings {
    /// `ES_WeatherMonitorStatus` (2 = read and compute refraction).
    pub weather_monitor_status: i32,
    /// Apply transformation parameters.
    pub apply_transformation: bool,
    /// Apply station orientation parameters.
    pub apply_station_orientation: bool,
    /// Keep last position.
    pub keep_last_position: bool,
    /// Send unsolicited messages (errors, status changes).
    pub send_unsolicited_messages: bool,
    /// Send reflector position data while locked.
    pub send_reflector_position_data: bool,
    /// Try-measurement mode.
    pub try_measurement_mode: bool,
    /// A nivel sensor is present.
    pub has_nivel: bool,
    /// A video camera is present.
    pub has_video_camera: bool,
}

impl Default for SystemSettings {
    fn default() -> Self {
        SystemSettings {
            weather_monitor_status: WEATHER_READ_AND_CALCULATE,
            apply_transformation: false,
            apply_station_orientation: false,
            keep_last_position: true,
            send_unsolicited_messages: true,
            send_reflector_position_data: false,
            try_measurement_mode: false,
            has_nivel: false,
            has_video_camera: false,
        }
    }
}

/// Payload of the GetSystemStatus reply (after command and status).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SystemStatus {
    /// Status of the last command.
    pub last_result_status: i32,
    /// `ES_TrackerProcessorStatus` (5 = initialised).
    pub tracker_processor_status: i32,
    /// `ES_LaserProcessorStatus`.
    pub laser_status: i32,
    /// `ES_ADMStatus`.
    pub adm_status: i32,
    /// emScon version (major, minor, build).
    pub version: [i32; 3],
    /// `ES_WeatherMonitorStatus`.
    pub weather_monitor_status: i32,
    /// Flags (always 0 on AT4xx).
    pub flags: i32,
    /// Tracker serial number.
    pub serial_number: i32,
}

impl SystemStatus {
    /// True when `tracker_processor_status` is `ES_TPS_Initialized`.
    pub fn is_initialized(&self) -> bool {
        self.tracker_processor_status == TPS_INITIALIZED
    }
}

/// Measurement status bitmask (`ES_MeasurementStatusInfo`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MeasurementStatusInfo(pub u32);

impl MeasurementStatusInfo {
    /// `ES_MSI_TrackerFound`.
    pub const TRACKER_FOUND: u32 = 1;
    /// `ES_MSI_TrackerCompensationFound`.
    pub const TRACKER_COMPENSATION_FOUND: u32 = 2;
    /// `ES_MSI_ADMFound`.
    pub const ADM_FOUND: u32 = 4;
    /// `ES_MSI_ADMCompensationFound`.
    pub const ADM_COMPENSATION_FOUND: u32 = 8;
    /// `ES_MSI_ReflectorFound`.
    pub const REFLECTOR_FOUND: u32 = 2048;
    /// `ES_MSI_InFace1`.
    pub const IN_FACE1: u32 = 4096;
    /// `ES_MSI_NivelInWorkingRange`.
    pub const NIVEL_IN_WORKING_RANGE: u32 = 32768;
    /// `ES_MSI_Initialized`.
    pub const INITIALIZED: u32 = 65536;

    /// True if every bit of `mask` is set.
    pub fn has(&self, mask: u32) -> bool {
        self.0 & mask == mask
    }
    /// The tracker is locked onto a reflector.
    pub fn reflector_found(&self) -> bool {
        self.has(Self::REFLECTOR_FOUND)
    }
    /// The tracker is initialised.
    pub fn initialized(&self) -> bool {
        self.has(Self::INITIALIZED)
    }
    /// The tracker is in face 1.
    pub fn in_face1(&self) -> bool {
        self.has(Self::IN_FACE1)
    }
    /// The nivel is within its working range.
    pub fn nivel_in_working_range(&self) -> bool {
        self.has(Self::NIVEL_IN_WORKING_RANGE)
    }
}

/// One reflector as listed by GetReflectors.
#[derive(Debug, Clone, PartialEq)]
pub struct ReflectorInfo {
    /// Total number of reflectors in the list.
    pub total: i32,
    /// Internal reflector id (use with SetReflector).
    pub id: i32,
    /// `ES_TargetType` (5 = RRR 1.5").
    pub target_type: i32,
    /// Surface offset in the current length unit.
    pub surface_offset: f64,
    /// Reflector name (UTF-16 on the wire, at most 32 code units).
    pub name: String,
}
