//! Feeds every file in `tests/corpus/` through the parser named by its prefix.
//! File name `<parser>_<class>_<label>.txt`, one case per non-empty line.
//! parser: `msg` (parse_message), `cmd` (parse_command), `gauge` (parse_reading).
//! class: `ok`, `checksum` (checksum error), `err` (any other error), and for gauges
//! `unit` (WrongUnit), `status` (DeviceStatus).

use zaber::ascii::{parse_command, parse_message, CodecError};
use zaber::gauge::{parse_reading, GaugeError};

#[derive(Debug, PartialEq)]
enum Class {
    Ok,
    Checksum,
    Unit,
    Status,
    Err,
}

fn codec_class<T>(r: Result<T, CodecError>) -> Class {
    match r {
        Ok(_) => Class::Ok,
        Err(CodecError::Checksum { .. }) => Class::Checksum,
        Err(_) => Class::Err,
    }
}

#[test]
fn corpus_files_parse_as_expected() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let Some(stem) = name.strip_suffix(".txt") else {
            continue;
        };
        let mut parts = stem.splitn(3, '_');
        let parser = parts.next().unwrap().to_string();
        let expect = match parts.next().unwrap_or("") {
            "ok" => Class::Ok,
            "checksum" => Class::Checksum,
            "unit" => Class::Unit,
            "status" => Class::Status,
            "err" => Class::Err,
            c => panic!("{name}: unknown class {c}"),
        };
        let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()).into_owned();
        for line in text.split('\n').filter(|l| !l.trim().is_empty()) {
            n += 1;
            let got = match parser.as_str() {
                "msg" => codec_class(parse_message(line)),
                "cmd" => codec_class(parse_command(line)),
                "gauge" => match parse_reading(line) {
                    Ok(_) => Class::Ok,
                    Err(GaugeError::WrongUnit(_)) => Class::Unit,
                    Err(GaugeError::DeviceStatus(_)) => Class::Status,
                    Err(_) => Class::Err,
                },
                p => panic!("{name}: unknown parser {p}"),
            };
            assert_eq!(got, expect, "{name}: line {line:?}");
        }
    }
    assert!(n > 20, "corpus too small ({n} cases)");
}
