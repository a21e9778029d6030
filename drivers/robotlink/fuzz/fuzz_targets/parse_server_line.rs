#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let s = String::from_utf8_lossy(data);
    if let Ok(robotlink::codec::ServerLine::Reply(r)) = robotlink::codec::parse_server_line(&s) {
        if let robotlink::codec::ReplyBody::Ok(d) = &r.body {
            let _ = robotlink::codec::parse_joints(d);
            let _ = robotlink::codec::parse_state(d);
            let _ = robotlink::codec::parse_pose(d);
            let _ = robotlink::codec::parse_challenge(d);
            let _ = robotlink::codec::parse_auth_reply(d);
        }
    }
});
