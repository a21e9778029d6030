#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let s = String::from_utf8_lossy(data);
    if let Ok((cmd, cs)) = zaber::ascii::parse_command(&s) {
        let line = zaber::ascii::format_command(&cmd, cs);
        assert!(zaber::ascii::parse_command(&line).is_ok());
    }
});
