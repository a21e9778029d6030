//! Fuzz target: arbitrary text through the Dashboard command and reply parsers and the
//! URScript subset parser (what the simulated controller reads from clients).
#![no_main]

use libfuzzer_sys::fuzz_target;
use ur::{dashboard, script};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let _ = dashboard::Command::parse(&text);
    let _ = dashboard::parse_robot_mode(&text);
    let _ = dashboard::parse_safety_mode(&text);
    let _ = dashboard::parse_remote_control(&text);
    let _ = script::parse_program(&text);
});
