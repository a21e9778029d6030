#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = std::str::from_utf8(data) {
        if let Ok(r) = robotlink::codec::parse_request(s) {
            let line = robotlink::codec::format_request(r.seq, &r.request);
            assert!(robotlink::codec::parse_request(&line).is_ok());
        }
    }
});
