//! Dashboard server (TCP 29999) text protocol: one `\n`-terminated command, one reply line.
//!
//! Replies as UR's "Dashboard Server e-Series, port 29999" document gives them (and as
//! ur_rtde's `dashboard_client.cpp` and UR's client library check them): banner
//! `Connected: Universal Robots Dashboard Server`, `Powering on`, `Brake releasing`,
//! `Robotmode: RUNNING`, `Safetymode: NORMAL`, `Safetystatus: NORMAL`, `Stopped`, `true`,
//! `Protective stop releasing`, `closing popup`, `Disconnected`.

/// The line a controller sends when a client connects.
pub const BANNER: &str = "Connected: Universal Robots Dashboard Server";
/// Reply to `power on`.
pub const POWERING_ON: &str = "Powering on";
/// Reply to `power off`.
pub const POWERING_OFF: &str = "Powering off";
/// Reply to `brake release`.
pub const BRAKE_RELEASING: &str = "Brake releasing";
/// Reply to `stop` when it worked.
pub const STOPPED: &str = "Stopped";
/// Reply to `stop` when it did not.
pub const STOP_FAILED: &str = "Failed to execute: stop";
/// Reply to `unlock protective stop` when it worked.
pub const PROTECTIVE_STOP_RELEASING: &str = "Protective stop releasing";
/// Reply to `unlock protective stop` within 5 s of the stop.
pub const CANNOT_UNLOCK_YET: &str = "Cannot unlock protective stop until 5s after occurrence. \
     Always inspect cause of protective stop before unlocking";
/// Reply to `close popup`.
pub const CLOSING_POPUP: &str = "closing popup";
/// Reply to `close safety popup`.
pub const CLOSING_SAFETY_POPUP: &str = "closing safety popup";
/// Reply to `quit` (then the controller closes the connection).
pub const DISCONNECTED: &str = "Disconnected";
/// Reply to a remote-only command while the pendant is in local control.
pub const LOCAL_CONTROL: &str = "Command is not allowed in Local Control";

/// Robot mode (RTDE `robot_mode` INT32, Dashboard `Robotmode: NAME`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RobotMode {
    /// -1.
    NoController,
    /// 0.
    Disconnected,
    /// 1.
    ConfirmSafety,
    /// 2.
    Booting,
    /// 3: arm not powered.
    PowerOff,
    /// 4: powering on.
    PowerOn,
    /// 5: powered, brakes engaged.
    Idle,
    /// 6.
    Backdrive,
    /// 7: powered, brakes released: ready to move.
    Running,
    /// 8.
    UpdatingFirmware,
}

const ROBOT_MODES: [(RobotMode, i32, &str); 10] = [
    (RobotMode::NoController, -1, "NO_CONTROLLER"),
    (RobotMode::Disconnected, 0, "DISCONNECTED"),
    (RobotMode::ConfirmSafety, 1, "CONFIRM_SAFETY"),
    (RobotMode::Booting, 2, "BOOTING"),
    (RobotMode::PowerOff, 3, "POWER_OFF"),
    (RobotMode::PowerOn, 4, "POWER_ON"),
    (RobotMode::Idle, 5, "IDLE"),
    (RobotMode::Backdrive, 6, "BACKDRIVE"),
    (RobotMode::Running, 7, "RUNNING"),
    (RobotMode::UpdatingFirmware, 8, "UPDATING_FIRMWARE"),
];

impl RobotMode {
    /// The RTDE integer.
    pub fn code(self) -> i32 {
        ROBOT_MODES.iter().find(|m| m.0 == self).map_or(-1, |m| m.1)
    }
    /// The Dashboard name (`RUNNING`).
    pub fn name(self) -> &'static str {
        ROBOT_MODES.iter().find(|m| m.0 == self).map_or("", |m| m.2)
    }
    /// The mode of RTDE integer `c`.
    pub fn from_code(c: i32) -> Option<Self> {
        ROBOT_MODES.iter().find(|m| m.1 == c).map(|m| m.0)
    }
    /// The mode named `n`.
    pub fn from_name(n: &str) -> Option<Self> {
        ROBOT_MODES.iter().find(|m| m.2 == n).map(|m| m.0)
    }
}

/// Safety mode (RTDE `safety_mode` INT32, Dashboard `Safetymode:`/`Safetystatus: NAME`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SafetyMode {
    /// 1.
    Normal,
    /// 2.
    Reduced,
    /// 3: stopped by the safety system (collision, limit); released by a person.
    ProtectiveStop,
    /// 4.
    Recovery,
    /// 5.
    SafeguardStop,
    /// 6: emergency stop from the system (external) input.
    SystemEmergencyStop,
    /// 7: emergency stop button on the pendant or robot.
    RobotEmergencyStop,
    /// 8.
    Violation,
    /// 9.
    Fault,
    /// 10.
    ValidateJointId,
    /// 11.
    UndefinedSafetyMode,
    /// 12.
    AutomaticModeSafeguardStop,
    /// 13.
    SystemThreePositionEnablingStop,
}

const SAFETY_MODES: [(SafetyMode, i32, &str); 13] = [
    (SafetyMode::Normal, 1, "NORMAL"),
    (SafetyMode::Reduced, 2, "REDUCED"),
    (SafetyMode::ProtectiveStop, 3, "PROTECTIVE_STOP"),
    (SafetyMode::Recovery, 4, "RECOVERY"),
    (SafetyMode::SafeguardStop, 5, "SAFEGUARD_STOP"),
    (SafetyMode::SystemEmergencyStop, 6, "SYSTEM_EMERGENCY_STOP"),
    (SafetyMode::RobotEmergencyStop, 7, "ROBOT_EMERGENCY_STOP"),
    (SafetyMode::Violation, 8, "VIOLATION"),
    (SafetyMode::Fault, 9, "FAULT"),
    (SafetyMode::ValidateJointId, 10, "VALIDATE_JOINT_ID"),
    (SafetyMode::UndefinedSafetyMode, 11, "UNDEFINED_SAFETY_MODE"),
    (
        SafetyMode::AutomaticModeSafeguardStop,
        12,
        "AUTOMATIC_MODE_SAFEGUARD_STOP",
    ),
    (
        SafetyMode::SystemThreePositionEnablingStop,
        13,
        "SYSTEM_THREE_POSITION_ENABLING_STOP",
    ),
];

impl SafetyMode {
    /// The RTDE integer.
    pub fn code(self) -> i32 {
        SAFETY_MODES
            .iter()
            .find(|m| m.0 == self)
            .map_or(11, |m| m.1)
    }
    /// The Dashboard name (`PROTECTIVE_STOP`).
    pub fn name(self) -> &'static str {
        SAFETY_MODES
            .iter()
            .find(|m| m.0 == self)
            .map_or("", |m| m.2)
    }
    /// The mode of RTDE integer `c`.
    pub fn from_code(c: i32) -> Option<Self> {
        SAFETY_MODES.iter().find(|m| m.1 == c).map(|m| m.0)
    }
    /// The mode named `n`.
    pub fn from_name(n: &str) -> Option<Self> {
        SAFETY_MODES.iter().find(|m| m.2 == n).map(|m| m.0)
    }
    /// Whether this is an emergency stop (system or robot).
    pub fn is_emergency_stop(self) -> bool {
        matches!(
            self,
            SafetyMode::SystemEmergencyStop | SafetyMode::RobotEmergencyStop
        )
    }
}

/// Program runtime state (RTDE `runtime_state` UINT32).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RuntimeState {
    /// 0.
    Stopping,
    /// 1.
    Stopped,
    /// 2: a program runs.
    Playing,
    /// 3.
    Pausing,
    /// 4.
    Paused,
    /// 5.
    Resuming,
}

impl RuntimeState {
    /// The RTDE integer.
    pub fn code(self) -> u32 {
        match self {
            RuntimeState::Stopping => 0,
            RuntimeState::Stopped => 1,
            RuntimeState::Playing => 2,
            RuntimeState::Pausing => 3,
            RuntimeState::Paused => 4,
            RuntimeState::Resuming => 5,
        }
    }
    /// The state of RTDE integer `c`.
    pub fn from_code(c: u32) -> Option<Self> {
        Some(match c {
            0 => RuntimeState::Stopping,
            1 => RuntimeState::Stopped,
            2 => RuntimeState::Playing,
            3 => RuntimeState::Pausing,
            4 => RuntimeState::Paused,
            5 => RuntimeState::Resuming,
            _ => return None,
        })
    }
}

/// A Dashboard command this crate sends or the simulated server understands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// `power on`.
    PowerOn,
    /// `power off`.
    PowerOff,
    /// `brake release`.
    BrakeRelease,
    /// `robotmode`.
    RobotMode,
    /// `safetymode`.
    SafetyMode,
    /// `safetystatus`.
    SafetyStatus,
    /// `is in remote control`.
    IsInRemoteControl,
    /// `running`.
    Running,
    /// `programState`.
    ProgramState,
    /// `stop`.
    Stop,
    /// `pause`.
    Pause,
    /// `play`.
    Play,
    /// `unlock protective stop`.
    UnlockProtectiveStop,
    /// `close popup`.
    ClosePopup,
    /// `close safety popup`.
    CloseSafetyPopup,
    /// `popup <text>`.
    Popup(String),
    /// `PolyscopeVersion`.
    PolyscopeVersion,
    /// `version`.
    Version,
    /// `get robot model`.
    GetRobotModel,
    /// `get serial number`.
    GetSerialNumber,
    /// `get loaded program`.
    GetLoadedProgram,
    /// `quit`.
    Quit,
}

const FIXED: [(Command, &str); 21] = [
    (Command::PowerOn, "power on"),
    (Command::PowerOff, "power off"),
    (Command::BrakeRelease, "brake release"),
    (Command::RobotMode, "robotmode"),
    (Command::SafetyMode, "safetymode"),
    (Command::SafetyStatus, "safetystatus"),
    (Command::IsInRemoteControl, "is in remote control"),
    (Command::Running, "running"),
    (Command::ProgramState, "programState"),
    (Command::Stop, "stop"),
    (Command::Pause, "pause"),
    (Command::Play, "play"),
    (Command::UnlockProtectiveStop, "unlock protective stop"),
    (Command::ClosePopup, "close popup"),
    (Command::CloseSafetyPopup, "close safety popup"),
    (Command::PolyscopeVersion, "PolyscopeVersion"),
    (Command::Version, "version"),
    (Command::GetRobotModel, "get robot model"),
    (Command::GetSerialNumber, "get serial number"),
    (Command::GetLoadedProgram, "get loaded program"),
    (Command::Quit, "quit"),
];

impl Command {
    /// The command text, without the newline.
    pub fn text(&self) -> String {
        match self {
            Command::Popup(t) => format!("popup {t}"),
            c => FIXED
                .iter()
                .find(|(k, _)| k == c)
                .map(|(_, s)| (*s).to_owned())
                .unwrap_or_default(),
        }
    }

    /// Parses one received line (case-insensitive, surrounding blanks ignored, as a
    /// controller does); `None` for a command this crate does not know.
    pub fn parse(line: &str) -> Option<Self> {
        let t = line.trim();
        let lower = t.to_ascii_lowercase();
        if lower.starts_with("popup ") {
            return Some(Command::Popup(t["popup ".len()..].trim().to_owned()));
        }
        let words: Vec<&str> = lower.split_whitespace().collect();
        let joined = words.join(" ");
        FIXED
            .iter()
            .find(|(_, s)| s.to_ascii_lowercase() == joined)
            .map(|(c, _)| c.clone())
    }

    /// Whether a controller refuses it in local control (UR's table, "Remote-only").
    pub fn needs_remote_control(&self) -> bool {
        matches!(
            self,
            Command::PowerOn
                | Command::PowerOff
                | Command::BrakeRelease
                | Command::UnlockProtectiveStop
                | Command::Stop
                | Command::Pause
                | Command::Play
        )
    }
}

/// The reply to an unknown command (`could not understand: '<line>'`).
pub fn not_understood(line: &str) -> String {
    format!("could not understand: '{}'", line.trim())
}

/// Parses `Robotmode: RUNNING`.
pub fn parse_robot_mode(reply: &str) -> Option<RobotMode> {
    RobotMode::from_name(reply.trim().strip_prefix("Robotmode: ")?.trim())
}

/// Parses `Safetymode: NORMAL` or `Safetystatus: NORMAL`.
pub fn parse_safety_mode(reply: &str) -> Option<SafetyMode> {
    let t = reply.trim();
    let name = t
        .strip_prefix("Safetymode: ")
        .or_else(|| t.strip_prefix("Safetystatus: "))?;
    SafetyMode::from_name(name.trim())
}

/// Parses the reply to `is in remote control` (`true` / `false`).
pub fn parse_remote_control(reply: &str) -> Option<bool> {
    match reply.trim().to_ascii_lowercase().as_str() {
        "true" => Some(true),
        "false" => Some(false),
        _ => None,
    }
}
