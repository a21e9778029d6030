#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let s = String::from_utf8_lossy(data);
    if let Ok(zaber::ascii::Message::Reply(r)) = zaber::ascii::parse_message(&s) {
        let _ = zaber::ascii::parse_steps(&r.data);
        let _ = r.warning.class();
    }
});
