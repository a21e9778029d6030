//! The stop rule's checks of a campaign (`ident_checks` table): after a block of measured
//! identification poses, what the engine predicted and whether it stopped measuring them. One
//! row per count of measured identification poses, append-only; the engine's type is kept as
//! JSON ([`Store::add_ident_check`], [`Store::ident_checks`]) without this module knowing it.
//! A stored check that stopped the identification poses is what keeps them skipped on resume.

use rusqlite::{params, TransactionBehavior};
use serde::de::DeserializeOwned;
use serde::Serialize;

use super::error::{Ctx, StoreError};
use super::Store;

impl Store {
    /// Store the check made after `after_poses` measured identification poses of campaign `id`
    /// (its JSON must be an object). A second check at the same count is ignored: the first
    /// one stands (a check is made once; a resume that repeats one changes nothing).
    pub fn add_ident_check<T: Serialize>(
        &mut self,
        id: i64,
        after_poses: usize,
        check: &T,
    ) -> Result<(), StoreError> {
        let json = serde_json::to_string(check)
            .map_err(|e| StoreError::Invalid(format!("the check does not serialise: {e}")))?;
        let after = i64::try_from(after_poses)
            .map_err(|_| StoreError::Invalid(format!("{after_poses} poses")))?;
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin save an identification check")?;
        Store::ensure_campaign(&tx, id)?;
        let object: bool = tx
            .query_row(
                "SELECT json_valid(?1) AND json_type(?1) = 'object'",
                [&json],
                |r| r.get(0),
            )
            .ctx("check the identification check's JSON")?;
        if !object {
            return Err(StoreError::Invalid(
                "an identification check is a JSON object".into(),
            ));
        }
        tx.execute(
            "INSERT INTO ident_checks (campaign_id, after_poses, json) VALUES (?1, ?2, ?3) \
             ON CONFLICT (campaign_id, after_poses) DO NOTHING",
            params![id, after, json],
        )
        .ctx("save an identification check")?;
        tx.commit().ctx("commit an identification check")
    }

    /// The stored checks of campaign `id`, by increasing count of identification poses.
    pub fn ident_checks<T: DeserializeOwned>(&self, id: i64) -> Result<Vec<T>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let mut st = self
            .conn
            .prepare_cached(
                "SELECT json FROM ident_checks WHERE campaign_id = ?1 ORDER BY after_poses",
            )
            .ctx("read the identification checks")?;
        let texts = st
            .query_map([id], |r| r.get::<_, String>(0))
            .ctx("read the identification checks")?
            .collect::<Result<Vec<String>, _>>()
            .ctx("read an identification check")?;
        texts
            .iter()
            .map(|t| {
                serde_json::from_str(t).map_err(|e| {
                    StoreError::Corrupt(format!("campaign {id}: an identification check: {e}"))
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::setup;
    use super::*;

    #[derive(Debug, PartialEq, Serialize, serde::Deserialize)]
    struct Check {
        after: usize,
        stop: bool,
    }

    #[test]
    fn checks_come_back_in_pose_order_and_a_repeated_count_keeps_the_first() {
        let mut s = Store::open_in_memory().unwrap();
        let id = setup(&mut s);
        for (after, stop) in [(30, true), (15, false), (30, false)] {
            s.add_ident_check(id, after, &Check { after, stop })
                .unwrap();
        }
        let got: Vec<Check> = s.ident_checks(id).unwrap();
        assert_eq!(
            got,
            [
                Check {
                    after: 15,
                    stop: false
                },
                Check {
                    after: 30,
                    stop: true
                }
            ]
        );
        assert!(s.add_ident_check(id, 45, &[1, 2]).is_err(), "not an object");
        assert!(matches!(
            s.ident_checks::<Check>(id + 1),
            Err(StoreError::NoCampaign(_))
        ));
    }
}
