//! Identification results: one row per identification of a campaign (`results` table), the
//! latest one counts. A calibration campaign stores its typed result
//! (`calibrate::CalibrationResult`, whose JSON leads with the `cellcal identify` contract's
//! fields), an ISO 9283 campaign its figures; this module keeps them as JSON and gives them back
//! typed ([`Store::latest_result_as`]) without knowing either type.

use rusqlite::{params, OptionalExtension, TransactionBehavior};
use serde::de::DeserializeOwned;
use serde::Serialize;

use super::error::{Ctx, StoreError};
use super::Store;

impl Store {
    /// The verdict (`quality`: `ok`, `warning`, `poor`) of the campaign's latest result, if it
    /// has a result that carries one (without reading the rest of it).
    pub fn result_quality(&self, id: i64) -> Result<Option<String>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        let q: Option<Option<String>> = self
            .conn
            .query_row(
                "SELECT json_extract(json, '$.quality') FROM results WHERE campaign_id = ?1 \
                 ORDER BY id DESC LIMIT 1",
                [id],
                |r| r.get(0),
            )
            .optional()
            .ctx("read the result quality")?;
        Ok(q.flatten())
    }

    /// Store an identification result (`json` must be valid JSON; `model` names the
    /// observation model). The row is time-stamped by SQLite with the wall clock.
    pub fn save_result(&mut self, id: i64, model: &str, json: &str) -> Result<(), StoreError> {
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .ctx("begin save result")?;
        Store::ensure_campaign(&tx, id)?;
        let valid: bool = tx
            .query_row("SELECT json_valid(?1)", [json], |r| r.get(0))
            .ctx("check the result JSON")?;
        if !valid {
            return Err(StoreError::Invalid("the result is not valid JSON".into()));
        }
        tx.execute(
            "INSERT INTO results (campaign_id, model, json) VALUES (?1, ?2, ?3)",
            params![id, model, json],
        )
        .ctx("save a result")?;
        tx.commit().ctx("commit save result")
    }

    /// Store `result` as the campaign's latest result (its JSON, pretty; `model` names the
    /// observation model or the campaign kind). One write per identification.
    pub fn save_result_as<T: Serialize>(
        &mut self,
        id: i64,
        model: &str,
        result: &T,
    ) -> Result<(), StoreError> {
        let json = serde_json::to_string_pretty(result)
            .map_err(|e| StoreError::Invalid(format!("the result does not serialise: {e}")))?;
        self.save_result(id, model, &json)
    }

    /// The JSON of the campaign's most recently saved result, if any.
    pub fn latest_result(&self, id: i64) -> Result<Option<String>, StoreError> {
        Store::ensure_campaign(&self.conn, id)?;
        self.conn
            .query_row(
                "SELECT json FROM results WHERE campaign_id = ?1 ORDER BY id DESC LIMIT 1",
                [id],
                |r| r.get(0),
            )
            .optional()
            .ctx("read the latest result")
    }

    /// The campaign's latest result read as `T`, if it has one (a stored text that does not
    /// read as `T` is a corrupt store).
    pub fn latest_result_as<T: DeserializeOwned>(&self, id: i64) -> Result<Option<T>, StoreError> {
        let Some(text) = self.latest_result(id)? else {
            return Ok(None);
        };
        serde_json::from_str(&text)
            .map(Some)
            .map_err(|e| StoreError::Corrupt(format!("campaign {id}: its stored result: {e}")))
    }
}

#[cfg(test)]
mod tests {
    use serde::{Deserialize, Serialize};

    use super::super::tests::setup;
    use super::*;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Figures {
        quality: String,
        values: Vec<f64>,
    }

    #[test]
    fn a_typed_result_reads_back_bit_for_bit_and_a_foreign_one_is_corrupt() {
        let mut s = Store::open_in_memory().unwrap();
        let id = setup(&mut s);
        assert_eq!(s.latest_result_as::<Figures>(id).unwrap(), None);
        // 17 significant digits: a parser that rounds loses the last bit of some of them
        let values: Vec<f64> = (1..200)
            .map(|i| (i as f64).sqrt() * 0.047940324251990164)
            .collect();
        let r = Figures {
            quality: "warning".into(),
            values,
        };
        s.save_result_as(id, "op", &r).unwrap();
        let back: Figures = s.latest_result_as(id).unwrap().unwrap();
        for (a, b) in back.values.iter().zip(&r.values) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        assert_eq!(s.result_quality(id).unwrap().as_deref(), Some("warning"));
        s.save_result(id, "op", "{\"rms\": 1}").unwrap();
        let e = s.latest_result_as::<Figures>(id).unwrap_err().to_string();
        assert!(e.contains("its stored result"), "{e}");
    }
}
