use proptest::prelude::*;
use zaber::ascii::{
    append_checksum, format_command, format_reply, lrc, parse_command, parse_message,
    verify_checksum, Command, Message, Reply, ReplyFlag, Status, Warning,
};
use zaber::gauge::parse_reading;

fn warning() -> impl Strategy<Value = Warning> {
    "(--|[FWN][A-Z])".prop_map(|s| Warning::parse(&s).unwrap())
}

proptest! {
    #[test]
    fn command_round_trip(device in 0u8..=99, axis in 0u8..=9, id in prop::option::of(0u8..=99),
                          words in prop::collection::vec("[a-z]{1,8}", 1..4),
                          data in prop::option::of(-100_000_000i64..100_000_000),
                          cs in any::<bool>()) {
        let mut text = words.join(" ");
        if let Some(d) = data { text.push_str(&format!(" {d}")); }
        let cmd = Command { device, axis, id, text };
        let line = format_command(&cmd, cs);
        let (back, had_cs) = parse_command(&line).unwrap();
        prop_assert_eq!(had_cs, cs);
        prop_assert_eq!(back, cmd);
    }

    #[test]
    fn reply_round_trip(device in 0u8..=99, axis in 0u8..=9, id in prop::option::of(0u8..=99),
                        ok in any::<bool>(), busy in any::<bool>(), w in warning(),
                        data in "[A-Za-z0-9.-]{1,12}", cs in any::<bool>()) {
        let r = Reply { device, axis, id,
            flag: if ok { ReplyFlag::Ok } else { ReplyFlag::Rejected },
            status: if busy { Status::Busy } else { Status::Idle },
            warning: w, data };
        let line = format_reply(&r, cs);
        prop_assert_eq!(parse_message(&line).unwrap(), Message::Reply(r));
    }

    #[test]
    fn checksum_verifies_and_detects_single_byte_change(msg in "@[ -9;-~]{1,40}", pos in 1usize..40, delta in 1u8..=255) {
        let with = append_checksum(&msg);
        let (body, had) = verify_checksum(&with).unwrap();
        prop_assert!(had);
        prop_assert_eq!(body, msg.as_str());
        // sum(body after type) + lrc == 0 mod 256
        let s = msg.as_bytes()[1..].iter().fold(0u8, |a, b| a.wrapping_add(*b));
        prop_assert_eq!(s.wrapping_add(lrc(&msg.as_bytes()[1..])), 0);
        let mut bytes = msg.clone().into_bytes();
        let p = 1 + (pos - 1) % (bytes.len().max(2) - 1);
        if p < bytes.len() {
            bytes[p] = bytes[p].wrapping_add(delta);
            if let Ok(changed) = String::from_utf8(bytes) {
                let tampered = format!("{changed}{}", &with[msg.len()..]);
                prop_assert!(verify_checksum(&tampered).is_err());
            }
        }
    }

    #[test]
    fn garbage_never_panics(s in ".{0,300}", bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = parse_message(&s);
        let _ = parse_command(&s);
        let _ = parse_reading(&s);
        let lossy = String::from_utf8_lossy(&bytes).into_owned();
        let _ = parse_message(&lossy);
        let _ = parse_command(&lossy);
        let _ = parse_reading(&lossy);
    }

    #[test]
    fn structured_garbage_never_panics(t in "[@#!/]", f in prop::collection::vec("[0-9A-Z:-]{0,6}", 0..8)) {
        let line = format!("{t}{}", f.join(" "));
        let _ = parse_message(&line);
        let _ = parse_command(&line);
    }

    #[test]
    fn gauge_reading_round_trip(v in -1000.0f64..1000.0) {
        let line = format!("{v:+.4} mm\r");
        let r = parse_reading(&line).unwrap();
        prop_assert!((r.value_mm - v).abs() <= 5.1e-5);
    }
}
