//! Fault injection for the simulator server: a plain struct with public fields, shared
//! through [`SharedFaults`] so tests can change it between or during exchanges.
//!
//! Counters (`u32`) are one-shot: each affected command or measurement decrements them.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use crate::types::status;

/// Fault configuration shared between a test and the server.
pub type SharedFaults = Arc<Mutex<FaultConfig>>;

/// A malformed packet sent instead of a reply (or, for `NanResult`, as the result).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Malformed {
    /// Header declares a size of 4 (< 8): framing lost.
    SizeTooSmall,
    /// Header declares a size above the 64 KiB cap: framing lost.
    SizeTooLarge,
    /// Reply with 4 extra bytes (size does not match its type).
    SizeMismatch,
    /// A 16-byte packet with unknown data type 5.
    UnknownType,
    /// A reply echoing a different command id.
    WrongCommandEcho,
    /// The next measurement result carries NaN in X.
    NanResult,
}

/// A status forced onto the next replies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForcedStatus {
    /// Only this command id (`None`: any command).
    pub command: Option<i32>,
    /// Status to reply with (e.g. 39, 10012, 1, 57).
    pub status: i32,
    /// How many replies are affected.
    pub count: u32,
}

/// Faults the simulator can inject (see the crate README for the list).
#[derive(Debug, Clone, PartialEq)]
pub struct FaultConfig {
    /// Next N StartMeasurement commands find the beam broken: ReflectorFound is cleared and
    /// the RT carries `beam_break_status`.
    pub beam_break_before_measure: u32,
    /// Next N measurements break mid-way: OK RT, then an unsolicited Error packet
    /// (`beam_break_error_status`) and status change 25, no result.
    pub beam_break_during_measure: u32,
    /// Status of the StartMeasurement RT while the beam is broken (default 10004).
    pub beam_break_status: i32,
    /// Status of the unsolicited Error packet on a mid-measurement break (default 10009).
    pub beam_break_error_status: i32,
    /// A mid-measurement break sends the unsolicited Error packet (else only status 25).
    pub beam_break_sends_error: bool,
    /// After a break the tracker re-locks by itself after this many ms; `None`: only
    /// FindReflector / GoLastMeasuredPoint re-lock.
    pub relock_after_ms: Option<u64>,
    /// Status of FindReflector / GoLastMeasuredPoint when no reflector is visible (10014).
    pub target_not_found_status: i32,
    /// Next N GoLastMeasuredPoint commands answer OK without locking on (the last point was
    /// somewhere the reflector no longer is).
    pub go_last_without_lock: u32,
    /// Next N FindReflector commands fail with `target_not_found_status` (the search pattern
    /// missed the reflector).
    pub find_reflector_fails: u32,
    /// Next N commands (see `no_reply_command`) get no reply at all.
    pub no_reply: u32,
    /// Restricts `no_reply` to this command id.
    pub no_reply_command: Option<i32>,
    /// Next N measurements: OK RT, then no result.
    pub rt_without_result: u32,
    /// Next N measurements: the result without any RT.
    pub result_without_rt: u32,
    /// Next N measurements: the result first, then the RT.
    pub result_before_rt: u32,
    /// Malformed packets, consumed front first (reply kinds by replies, `NanResult` by results).
    pub malformed: VecDeque<Malformed>,
    /// A status forced onto the next matching replies.
    pub forced_status: Option<ForcedStatus>,
    /// Write all packets produced for one command in a single write.
    pub coalesce: bool,
    /// Write every packet one byte at a time.
    pub dribble: bool,
    /// Send status change 26 and a reflector position between RT and result.
    pub interleave_unsolicited: bool,
    /// Next N replies: write half of the packet, then close the connection.
    pub disconnect_mid_packet: u32,
    /// Next N commands: send status change 997 (TPConnectionClosing), then close.
    pub closing_then_close: u32,
    /// Duration of Initialize in ms.
    pub initialize_delay_ms: u64,
}

impl Default for FaultConfig {
    fn default() -> Self {
        FaultConfig {
            beam_break_before_measure: 0,
            beam_break_during_measure: 0,
            beam_break_status: status::MEASUREMENT_STATUS_NOT_READY,
            beam_break_error_status: status::NO_STATIONARY_RESULT,
            beam_break_sends_error: true,
            relock_after_ms: None,
            target_not_found_status: status::SYSTEM_NOT_READY_FOR_MEASUREMENT,
            go_last_without_lock: 0,
            find_reflector_fails: 0,
            no_reply: 0,
            no_reply_command: None,
            rt_without_result: 0,
            result_without_rt: 0,
            result_before_rt: 0,
            malformed: VecDeque::new(),
            forced_status: None,
            coalesce: false,
            dribble: false,
            interleave_unsolicited: false,
            disconnect_mid_packet: 0,
            closing_then_close: 0,
            initialize_delay_ms: 10,
        }
    }
}

impl FaultConfig {
    /// A new shared handle with no faults.
    pub fn shared() -> SharedFaults {
        Arc::new(Mutex::new(FaultConfig::default()))
    }
}

/// Decrements a one-shot counter; true if it was positive.
pub(crate) fn take(counter: &mut u32) -> bool {
    if *counter > 0 {
        *counter -= 1;
        true
    } else {
        false
    }
}
