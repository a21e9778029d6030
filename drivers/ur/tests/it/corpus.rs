//! Runs every file in `tests/corpus/` (controller-to-client RTDE byte streams) through the
//! frame decoder in 7-byte chunks; the file name prefix (`ok_`, `partial_`, `bad_`,
//! `fatal_`) states the expected outcome class.

use std::path::PathBuf;

use ur::rtde::FrameDecoder;

#[derive(Debug, Default)]
struct Summary {
    ok: usize,
    bad: usize,
    fatal: usize,
    leftover: usize,
}

fn run(bytes: &[u8]) -> Summary {
    let mut s = Summary::default();
    let mut d = FrameDecoder::new();
    'feed: for chunk in bytes.chunks(7) {
        d.push(chunk);
        loop {
            match d.next_server() {
                Ok(Some(_)) => s.ok += 1,
                Ok(None) => break,
                Err(e) if e.is_fatal() => {
                    s.fatal += 1;
                    break 'feed;
                }
                Err(_) => s.bad += 1,
            }
        }
    }
    s.leftover = d.buffered();
    s
}

#[test]
fn corpus_files_decode_to_their_class() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/corpus");
    let mut entries: Vec<_> = std::fs::read_dir(&dir)
        .expect("corpus dir")
        .map(|e| e.expect("entry").path())
        .collect();
    entries.sort();
    let mut seen = 0;
    for path in entries {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let s = run(&std::fs::read(&path).expect("read"));
        match name.split('_').next().unwrap_or("") {
            "ok" => assert!(
                s.ok >= 1 && s.bad == 0 && s.fatal == 0 && s.leftover == 0,
                "{name}: {s:?}"
            ),
            "partial" => assert!(
                s.bad == 0 && s.fatal == 0 && s.leftover > 0,
                "{name}: {s:?}"
            ),
            "bad" => assert!(
                s.bad >= 1 && s.fatal == 0 && s.leftover == 0,
                "{name}: {s:?}"
            ),
            "fatal" => assert!(s.fatal == 1, "{name}: {s:?}"),
            other => panic!("unknown corpus class {other} in {name}"),
        }
        seen += 1;
    }
    assert!(seen >= 12, "corpus has only {seen} files");
}
