//! Property tests: RTDE packages and values round trip through any chunking; garbage never
//! panics the decoders or the text parsers; formatted URScript parses back to its values.

use proptest::prelude::*;
use ur::rtde::{
    decode_values, encode_values, ClientPackage, FrameDecoder, MessageLevel, ServerPackage,
    TextMessage, Value,
};
use ur::script::{self, Statement};

fn name() -> impl Strategy<Value = String> {
    "[a-z_][a-z0-9_]{0,20}"
}

fn value() -> impl Strategy<Value = Value> {
    let d = -1.0e6f64..1.0e6;
    prop_oneof![
        any::<bool>().prop_map(Value::Bool),
        any::<u8>().prop_map(Value::Uint8),
        any::<u32>().prop_map(Value::Uint32),
        any::<u64>().prop_map(Value::Uint64),
        any::<i32>().prop_map(Value::Int32),
        d.clone().prop_map(Value::Double),
        [d.clone(), d.clone(), d.clone()].prop_map(Value::Vector3d),
        proptest::array::uniform6(d).prop_map(Value::Vector6d),
        any::<[i32; 6]>().prop_map(Value::Vector6Int32),
        any::<[u32; 6]>().prop_map(Value::Vector6Uint32),
    ]
}

fn text() -> impl Strategy<Value = TextMessage> {
    ("[ -~]{0,40}", "[ -~]{0,10}", 0u8..4).prop_map(|(message, source, l)| TextMessage {
        message,
        source,
        level: MessageLevel::from_code(l).unwrap(),
    })
}

fn client() -> impl Strategy<Value = ClientPackage> {
    prop_oneof![
        any::<u16>().prop_map(ClientPackage::RequestProtocolVersion),
        Just(ClientPackage::GetUrcontrolVersion),
        (0.1f64..1000.0, prop::collection::vec(name(), 1..10))
            .prop_map(|(frequency, names)| ClientPackage::SetupOutputs { frequency, names }),
        prop::collection::vec(name(), 1..10).prop_map(ClientPackage::SetupInputs),
        Just(ClientPackage::Start),
        Just(ClientPackage::Pause),
        (any::<u8>(), prop::collection::vec(any::<u8>(), 0..100))
            .prop_map(|(recipe, values)| ClientPackage::Data { recipe, values }),
        text().prop_map(ClientPackage::Text),
    ]
}

fn server() -> impl Strategy<Value = ServerPackage> {
    let types = prop::collection::vec("[A-Z0-9_]{1,14}", 1..10);
    prop_oneof![
        any::<bool>().prop_map(ServerPackage::ProtocolVersion),
        any::<[u32; 4]>().prop_map(|[major, minor, bugfix, build]| {
            ServerPackage::UrcontrolVersion {
                major,
                minor,
                bugfix,
                build,
            }
        }),
        (any::<u8>(), types.clone())
            .prop_map(|(recipe, types)| ServerPackage::SetupOutputs { recipe, types }),
        (any::<u8>(), types)
            .prop_map(|(recipe, types)| ServerPackage::SetupInputs { recipe, types }),
        any::<bool>().prop_map(ServerPackage::Start),
        any::<bool>().prop_map(ServerPackage::Pause),
        (any::<u8>(), prop::collection::vec(value(), 0..20)).prop_map(|(recipe, v)| {
            ServerPackage::Data {
                recipe,
                values: encode_values(&v),
            }
        }),
        text().prop_map(ServerPackage::Text),
    ]
}

proptest! {
    #[test]
    fn packages_round_trip_through_any_chunking(
        c in prop::collection::vec(client(), 1..8),
        s in prop::collection::vec(server(), 1..8),
        chunk in 1usize..40,
    ) {
        let bytes: Vec<u8> = c.iter().flat_map(|p| p.encode().unwrap()).collect();
        let mut d = FrameDecoder::new();
        let mut got = Vec::new();
        for part in bytes.chunks(chunk) {
            d.push(part);
            while let Some(p) = d.next_client().unwrap() {
                got.push(p);
            }
        }
        prop_assert_eq!(got, c);
        let bytes: Vec<u8> = s.iter().flat_map(|p| p.encode().unwrap()).collect();
        let mut d = FrameDecoder::new();
        let mut got = Vec::new();
        for part in bytes.chunks(chunk) {
            d.push(part);
            while let Some(p) = d.next_server().unwrap() {
                got.push(p);
            }
        }
        prop_assert_eq!(got, s);
        prop_assert_eq!(d.buffered(), 0);
    }

    #[test]
    fn values_round_trip_with_their_types(v in prop::collection::vec(value(), 0..30)) {
        let types: Vec<_> = v.iter().map(Value::ty).collect();
        prop_assert_eq!(decode_values(&types, &encode_values(&v)).unwrap(), v.clone());
        // one byte more or less is refused
        let mut long = encode_values(&v);
        long.push(0);
        prop_assert!(decode_values(&types, &long).is_err());
    }

    #[test]
    fn garbage_never_panics(data in prop::collection::vec(any::<u8>(), 0..300)) {
        let mut d = FrameDecoder::new();
        d.push(&data);
        for _ in 0..300 {
            match d.next_server() {
                Ok(Some(_)) | Err(_) if d.is_failed() => break,
                Ok(None) => break,
                _ => {}
            }
        }
        let t = String::from_utf8_lossy(&data);
        let _ = ur::dashboard::Command::parse(&t);
        let _ = script::parse_program(&t);
    }

    #[test]
    fn formatted_movej_parses_back_to_its_values(
        q in proptest::array::uniform6(-6.3f64..6.3),
        a in 0.001f64..40.0,
        v in 0.001f64..4.0,
    ) {
        let p = script::program("cellcal_move", &[script::movej(&q, a, v).unwrap()]).unwrap();
        let parsed = script::parse_program(&p).unwrap();
        prop_assert_eq!(parsed, vec![Statement::MoveJ { q, a, v, t: 0.0, r: 0.0 }]);
    }
}
