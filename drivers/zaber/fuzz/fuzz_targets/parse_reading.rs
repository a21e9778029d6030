#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = zaber::gauge::parse_reading(&String::from_utf8_lossy(data));
});
