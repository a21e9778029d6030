//! The reader connection: it reads while another connection holds a write transaction, sees
//! only committed rows, cannot write, and refuses a schema it does not know exactly.

use std::time::{Duration, Instant};

use rusqlite::{params, TransactionBehavior};

use super::tests::setup;
use super::*;

/// A journal event that is its stored text (the store's own tests know no campaign events).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Raw {
    kind: String,
    text: String,
}

impl JournalEvent for Raw {
    fn kind(&self) -> &str {
        &self.kind
    }
    fn to_text(&self) -> Result<String, StoreError> {
        Ok(self.text.clone())
    }
    fn from_stored(kind: String, text: String) -> Raw {
        Raw { kind, text }
    }
}

fn note(text: &str) -> Raw {
    Raw {
        kind: "note".into(),
        text: text.into(),
    }
}

#[test]
fn a_held_write_transaction_does_not_block_the_reader() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let mut writer = Store::open(&db).unwrap();
    let id = setup(&mut writer);
    let first = writer.add_event(id, 1, &note("committed")).unwrap();
    // another writer holds the write lock with an uncommitted event
    let mut other = Store::open(&db).unwrap();
    let tx = other
        .raw()
        .transaction_with_behavior(TransactionBehavior::Immediate)
        .unwrap();
    tx.execute(
        "INSERT INTO events (campaign_id, at_ms, kind, message) VALUES (?1, 2, 'note', 'pending')",
        params![id],
    )
    .unwrap();
    let t0 = Instant::now();
    let reader = Store::open_reader(&db).unwrap();
    let seen = reader.events_after::<Raw>(id, 0, 100).unwrap();
    assert_eq!(reader.campaign(id).unwrap().state, INITIAL_STATE);
    assert_eq!(reader.pose_counts(id).unwrap(), (0, 3));
    assert!(!reader.has_result(id).unwrap());
    assert_eq!(reader.last_event_seq(id).unwrap(), first);
    // a reader that waited for the lock would take the busy timeout (5 s)
    let took = t0.elapsed();
    assert!(took < Duration::from_secs(2), "reads took {took:?}");
    assert_eq!(seen.len(), 1);
    assert_eq!(
        (seen[0].seq, seen[0].event.text.as_str()),
        (first, "committed")
    );
    tx.commit().unwrap();
    let seen = reader.events_after::<Raw>(id, first, 100).unwrap();
    assert_eq!(seen.len(), 1, "{seen:?}");
    assert!(seen[0].seq > first);
    assert_eq!(seen[0].event.text, "pending");
}

#[test]
fn journal_sequence_numbers_increase_and_page() {
    let mut s = Store::open_in_memory().unwrap();
    let id = setup(&mut s);
    let seqs: Vec<i64> = (0..5)
        .map(|i| s.add_event(id, 1, &note(&i.to_string())).unwrap())
        .collect();
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{seqs:?}");
    let page = s.events_after::<Raw>(id, seqs[1], 2).unwrap();
    let got: Vec<i64> = page.iter().map(|e| e.seq).collect();
    assert_eq!(got, &seqs[2..4]);
    assert_eq!(s.last_event_seq(id).unwrap(), seqs[4]);
    assert!(matches!(
        s.events_after::<Raw>(id + 1, 0, 10),
        Err(StoreError::NoCampaign(_))
    ));
}

#[test]
fn the_reader_cannot_write() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let mut writer = Store::open(&db).unwrap();
    let id = setup(&mut writer);
    let reader = Store::open_reader(&db).unwrap();
    let r = reader.0.conn.execute(
        "INSERT INTO events (campaign_id, at_ms, kind, message) VALUES (?1, 2, 'note', 'x')",
        params![id],
    );
    assert!(r.is_err(), "a reader wrote: {r:?}");
    assert_eq!(writer.last_event_seq(id).unwrap(), 0);
}

#[test]
fn the_reader_refuses_an_unknown_schema_and_a_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("none.db");
    assert!(Store::open_reader(&missing).is_err());
    assert!(!missing.exists(), "a reader created a database");
    let known = schema_version();
    for (version, old) in [(known - 1, true), (known + 1, false)] {
        let db = dir.path().join(format!("v{version}.db"));
        {
            let mut s = Store::open(&db).unwrap();
            s.raw()
                .pragma_update(None, "user_version", version)
                .unwrap();
        }
        match Store::open_reader(&db) {
            Err(StoreError::SchemaTooOld { found, .. }) if old => assert_eq!(found, version),
            Err(StoreError::SchemaTooNew { found, .. }) if !old => assert_eq!(found, version),
            other => panic!("schema {version}: {other:?}"),
        }
    }
}
