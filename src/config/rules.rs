//! The rule checks every configuration section shares: a value outside its key's rule names
//! the key.

/// A value outside its key's rule (the key is dotted from the file's top, e.g.
/// `campaign.ident`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct InvalidKey {
    /// Dotted key.
    pub key: String,
    /// The rule it breaks.
    pub message: String,
}

/// `Err` naming `key` and `rule` unless `ok`.
pub(crate) fn rule(ok: bool, key: &str, rule: impl Into<String>) -> Result<(), InvalidKey> {
    if ok {
        Ok(())
    } else {
        Err(InvalidKey {
            key: key.to_owned(),
            message: rule.into(),
        })
    }
}

/// A length, time or tolerance that must be above zero (a zero or negative one would switch
/// its check off).
pub(crate) fn positive(key: &str, v: f64) -> Result<(), InvalidKey> {
    rule(v > 0.0, key, format!("must be positive, got {v}"))
}
