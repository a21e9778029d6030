//! Feeds every file in `tests/corpus/` through the parser named by its prefix.
//! File name: `<parser>_<class>_<label>.txt`; every non-empty line is one case.
//! parser: `req` (parse_request), `srv` (parse_server_line), `joints` / `state` / `challenge` /
//! `authreply` (typed reply data).
//! class: `ok`, `args` (request error that is E_ARGS), `syntax` (request error that is E_SYNTAX), `err`.

use robotlink::codec::{
    parse_auth_reply, parse_challenge, parse_joints, parse_request, parse_server_line, parse_state,
};

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
        let class = parts.next().unwrap_or("").to_string();
        let text = String::from_utf8_lossy(&std::fs::read(&path).unwrap()).into_owned();
        for line in text.split('\n').filter(|l| !l.trim().is_empty()) {
            n += 1;
            let fields = || {
                line.split_whitespace()
                    .map(str::to_string)
                    .collect::<Vec<_>>()
            };
            let res: Result<(), robotlink::codec::CodecError> = match parser.as_str() {
                "req" => parse_request(line).map(drop),
                "srv" => parse_server_line(line).map(drop),
                "joints" => parse_joints(&fields()).map(drop),
                "state" => parse_state(&fields()).map(drop),
                "challenge" => parse_challenge(&fields()).map(drop),
                "authreply" => parse_auth_reply(&fields()).map(drop),
                p => panic!("{name}: unknown parser {p}"),
            };
            match (class.as_str(), &res) {
                ("ok", Ok(())) => {}
                ("err", Err(_)) => {}
                ("args", Err(e)) if e.is_args_error() => {}
                ("syntax", Err(e)) if !e.is_args_error() => {}
                _ => panic!("{name}: line {line:?} gave {res:?}, expected class {class}"),
            }
        }
    }
    assert!(n > 20, "corpus too small ({n} cases)");
}
