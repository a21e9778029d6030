use proptest::prelude::*;
use robotlink::codec::{
    format_event, format_joints, format_reply, format_request, parse_joints, parse_request,
    parse_server_line, parse_state, ErrorCode, Event, EventName, Reply, ReplyBody, Request,
    ServerLine,
};

fn num() -> impl Strategy<Value = f64> {
    -1.0e6f64..1.0e6
}

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        (0u32..1000).prop_map(|v| Request::Hello { proto_ver: v }),
        (any::<[u8; 16]>(), any::<[u8; 32]>()).prop_map(|(n, p)| Request::Auth {
            client_nonce: robotlink::Nonce(n),
            proof: robotlink::Proof(p),
        }),
        Just(Request::Ping),
        Just(Request::State),
        any::<bool>().prop_map(Request::Power),
        num().prop_map(|pct| Request::Speed { pct }),
        (prop::array::uniform6(num()), prop::option::of(num())).prop_map(|(j, v)| {
            Request::MoveJ {
                joints_deg: j,
                vel_pct: v,
            }
        }),
        any::<u32>().prop_map(|t| Request::Wait {
            timeout_ms: t as u64
        }),
        Just(Request::Joints),
        Just(Request::Pose),
        Just(Request::Stop),
    ]
}

fn code() -> impl Strategy<Value = ErrorCode> {
    prop_oneof![
        Just(ErrorCode::Syntax),
        Just(ErrorCode::Args),
        Just(ErrorCode::Busy),
        Just(ErrorCode::Power),
        Just(ErrorCode::EStop),
        Just(ErrorCode::Unreachable),
        Just(ErrorCode::Limit),
        Just(ErrorCode::Timeout),
        Just(ErrorCode::Mode),
        Just(ErrorCode::Stopped),
        Just(ErrorCode::Auth),
        "E_[A-Z0-9_]{1,10}".prop_filter_map("known", |s| {
            match ErrorCode::parse(&s) {
                Ok(ErrorCode::Other(o)) => Some(ErrorCode::Other(o)),
                _ => None,
            }
        }),
    ]
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 5.1e-7
}

proptest! {
    #[test]
    fn request_round_trip(seq in 1u32..=999_999, req in request()) {
        let line = format_request(seq, &req);
        prop_assert!(line.ends_with('\n'));
        let back = parse_request(&line).unwrap();
        prop_assert_eq!(back.seq, seq);
        // Re-formatting the parsed value is a fixed point.
        prop_assert_eq!(format_request(seq, &back.request), line.clone());
        match (&req, &back.request) {
            (Request::MoveJ { joints_deg: a, vel_pct: va }, Request::MoveJ { joints_deg: b, vel_pct: vb }) => {
                for (x, y) in a.iter().zip(b) { prop_assert!(close(*x, *y)); }
                prop_assert_eq!(va.is_some(), vb.is_some());
            }
            (Request::Speed { pct: a }, Request::Speed { pct: b }) => prop_assert!(close(*a, *b)),
            (a, b) => prop_assert_eq!(a, b),
        }
        // CRLF accepted too.
        let crlf = format!("{}\r\n", line.trim_end());
        prop_assert!(parse_request(&crlf).is_ok());
    }

    #[test]
    fn reply_round_trip(seq in 0u32..=999_999,
                        data in prop::collection::vec("[A-Za-z0-9_.=+-]{1,8}", 0..8),
                        code in code(),
                        text in "[ -~]{0,40}",
                        ok in any::<bool>()) {
        let body = if ok { ReplyBody::Ok(data) } else { ReplyBody::Err { code, text } };
        let line = format_reply(&Reply { seq, body: body.clone() });
        let parsed = parse_server_line(&line).unwrap();
        let ServerLine::Reply(r) = parsed else { panic!("not a reply") };
        prop_assert_eq!(r.seq, seq);
        match (body, r.body) {
            (ReplyBody::Ok(a), ReplyBody::Ok(b)) => prop_assert_eq!(a, b),
            (ReplyBody::Err { code: c1, text: t1 }, ReplyBody::Err { code: c2, text: t2 }) => {
                prop_assert_eq!(c1, c2);
                prop_assert_eq!(t1.split_whitespace().collect::<Vec<_>>().join(" "), t2);
            }
            _ => prop_assert!(false, "kind changed"),
        }
    }

    #[test]
    fn event_round_trip(name in "[A-Z][A-Z0-9_]{0,12}", data in "[ -~]{0,30}") {
        let ev = Event { name: match name.as_str() {
            "ESTOP" => EventName::EStop, "POWER_LOST" => EventName::PowerLost,
            "REFUSED" => EventName::Refused, _ => EventName::Other(name.clone()) }, data: data.clone() };
        let line = format_event(&ev);
        let ServerLine::Event(back) = parse_server_line(&line).unwrap() else { panic!("not event") };
        prop_assert_eq!(back.name, ev.name);
        prop_assert_eq!(back.data, data.split_whitespace().collect::<Vec<_>>().join(" "));
    }

    #[test]
    fn joints_round_trip(j in prop::array::uniform6(num())) {
        let back = parse_joints(&format_joints(&j)).unwrap();
        for (a, b) in j.iter().zip(back) { prop_assert!(close(*a, b)); }
    }

    #[test]
    fn garbage_never_panics(s in ".{0,200}", bytes in prop::collection::vec(any::<u8>(), 0..200)) {
        let _ = parse_request(&s);
        let _ = parse_server_line(&s);
        let lossy = String::from_utf8_lossy(&bytes).into_owned();
        let _ = parse_request(&lossy);
        let _ = parse_server_line(&lossy);
        let fields: Vec<String> = s.split_whitespace().map(str::to_string).collect();
        let _ = parse_joints(&fields);
        let _ = parse_state(&fields);
        let _ = robotlink::codec::parse_challenge(&fields);
        let _ = robotlink::codec::parse_auth_reply(&fields);
    }

    #[test]
    fn structured_garbage_never_panics(seq in "[0-9]{0,8}", verb in "(HELLO|AUTH|PING|MOVEJ|WAIT|POWER|SPEED|OK|ERR|\\*|EVT)",
                                        args in prop::collection::vec("[-+0-9.eEa-z_=]{0,6}", 0..9)) {
        let line = format!("{seq} {verb} {}", args.join(" "));
        let _ = parse_request(&line);
        let _ = parse_server_line(&line);
    }
}
