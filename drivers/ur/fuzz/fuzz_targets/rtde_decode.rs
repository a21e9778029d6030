//! Fuzz target: arbitrary bytes, split at a data-driven point, through the RTDE frame decoder
//! in both directions, and data package values against a fixed recipe.
#![no_main]

use libfuzzer_sys::fuzz_target;
use ur::rtde::{decode_values, ClientPackage, FrameDecoder, RtdeType, ServerPackage};

fuzz_target!(|data: &[u8]| {
    let split = data.first().map(|b| usize::from(*b)).unwrap_or(0) % (data.len() + 1);
    let (a, b) = data.split_at(split);
    let mut d = FrameDecoder::new();
    for part in [a, b] {
        d.push(part);
        for _ in 0..256 {
            match d.next_server() {
                Ok(Some(p)) => {
                    if let Ok(bytes) = p.encode() {
                        let _ = ServerPackage::decode(bytes[2], &bytes[3..]);
                    }
                }
                Ok(None) => break,
                Err(e) if e.is_fatal() => break,
                Err(_) => {}
            }
        }
    }
    let mut d = FrameDecoder::new();
    d.push(data);
    for _ in 0..256 {
        match d.next_client() {
            Ok(Some(p)) => {
                if let Ok(bytes) = p.encode() {
                    let _ = ClientPackage::decode(bytes[2], &bytes[3..]);
                }
            }
            Ok(None) => break,
            Err(e) if e.is_fatal() => break,
            Err(_) => {}
        }
    }
    let types = [RtdeType::Vector6d, RtdeType::Int32, RtdeType::Uint32, RtdeType::Bool];
    let _ = decode_values(&types, data);
});
