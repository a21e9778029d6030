//! Fuzz target: arbitrary bytes, split at a data-driven point, through the frame decoder
//! (both directions) and the single-frame decoders.
#![no_main]

use emscon::codec::{Command, FrameDecoder, ServerPacket};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let split = data.first().map(|b| usize::from(*b)).unwrap_or(0) % (data.len() + 1);
    let (a, b) = data.split_at(split);
    let mut d = FrameDecoder::new();
    for part in [a, b] {
        d.push(part);
        while let Ok(Some(_)) | Err(_) = d.next_packet::<ServerPacket>() {
            if d.is_failed() {
                break;
            }
        }
    }
    let mut d = FrameDecoder::new();
    d.push(data);
    for _ in 0..64 {
        match d.next_packet::<Command>() {
            Ok(None) => break,
            Ok(Some(c)) => {
                let _ = Command::decode(&c.to_bytes());
            }
            Err(_) => {}
        }
    }
    let _ = ServerPacket::decode(data);
    let _ = Command::decode(data);
});
