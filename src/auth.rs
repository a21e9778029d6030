//! Who may do what over the REST API: roles, the actions they allow, and API tokens known only
//! by their SHA-256 digests (compared in constant time). Pure except [`new_token`], which reads
//! the operating system's random number generator.

use std::fmt;

use rand::TryRngCore;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use subtle::ConstantTimeEq;

/// What a token holder may do: each role includes the one before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Reads campaigns, events, results; may abort (stopping the robot is never refused).
    Viewer,
    /// A viewer who also answers technician questions and pauses.
    Technician,
    /// Everything: create, arm, disarm, start, resume.
    Operator,
}

impl Role {
    /// The role named `s` (`viewer`, `technician`, `operator`), if any.
    pub fn parse(s: &str) -> Option<Role> {
        match s {
            "viewer" => Some(Role::Viewer),
            "technician" => Some(Role::Technician),
            "operator" => Some(Role::Operator),
            _ => None,
        }
    }

    /// The lowest role allowed to do `action`.
    fn least_for(action: Action) -> Role {
        match action {
            Action::Read | Action::Abort => Role::Viewer,
            Action::Answer | Action::Pause => Role::Technician,
            Action::Create | Action::Arm | Action::Disarm | Action::Start | Action::Resume => {
                Role::Operator
            }
        }
    }

    /// Whether this role may do `action`.
    pub fn may(self, action: Action) -> bool {
        self >= Role::least_for(action)
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Role::Viewer => "viewer",
            Role::Technician => "technician",
            Role::Operator => "operator",
        })
    }
}

/// A thing a client asks the API to do, as far as permissions go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Any read (campaigns, journal, stream, result).
    Read,
    /// Plan and store a new campaign.
    Create,
    /// Allow motion.
    Arm,
    /// Disallow motion.
    Disarm,
    /// Start or resume a stored campaign.
    Start,
    /// Pause after the current pose.
    Pause,
    /// Resume a paused campaign.
    Resume,
    /// Stop the robot now.
    Abort,
    /// Answer a technician question.
    Answer,
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Action::Read => "read",
            Action::Create => "create a campaign",
            Action::Arm => "arm",
            Action::Disarm => "disarm",
            Action::Start => "start",
            Action::Pause => "pause",
            Action::Resume => "resume",
            Action::Abort => "abort",
            Action::Answer => "answer",
        })
    }
}

/// Why a token could not be made or a digest not read.
#[derive(Debug, thiserror::Error)]
pub enum AuthError {
    /// The operating system's random number generator failed.
    #[error("no random bytes from the operating system: {0}")]
    Rng(String),
    /// A configured digest is not 64 hexadecimal digits.
    #[error("`{0}` is not a SHA-256 digest (64 hexadecimal digits)")]
    BadDigest(String),
}

/// The SHA-256 digest of a token: what the configuration stores instead of the token.
#[derive(Clone, PartialEq, Eq)]
pub struct TokenDigest([u8; 32]);

impl TokenDigest {
    /// The digest of `token`.
    pub fn of_token(token: &str) -> TokenDigest {
        TokenDigest(Sha256::digest(token.as_bytes()).into())
    }

    /// A digest written as 64 hexadecimal digits (either case).
    pub fn from_hex(s: &str) -> Result<TokenDigest, AuthError> {
        let bad = || AuthError::BadDigest(s.to_owned());
        if s.len() != 64 || !s.is_ascii() {
            return Err(bad());
        }
        let mut out = [0u8; 32];
        for (byte, pair) in out.iter_mut().zip(s.as_bytes().chunks(2)) {
            let pair = std::str::from_utf8(pair).map_err(|_| bad())?;
            *byte = u8::from_str_radix(pair, 16).map_err(|_| bad())?;
        }
        Ok(TokenDigest(out))
    }

    /// The digest as 64 lowercase hexadecimal digits (the configuration's form).
    pub fn to_hex(&self) -> String {
        hex(&self.0)
    }

    /// Constant-time equality (no early exit on the first differing byte).
    fn ct_eq(&self, other: &TokenDigest) -> bool {
        self.0.ct_eq(&other.0).into()
    }
}

impl fmt::Debug for TokenDigest {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "TokenDigest({})", self.to_hex())
    }
}

/// Lowercase hexadecimal digits of `bytes`.
fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// An authenticated client: the token's configured name and role.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Principal {
    /// The token's name (who holds it).
    pub name: String,
    /// What the holder may do.
    pub role: Role,
}

impl Principal {
    /// `Ok` when this principal may do `action`, else the refusal naming role and action.
    pub fn check(&self, action: Action) -> Result<(), String> {
        if self.role.may(action) {
            Ok(())
        } else {
            Err(format!(
                "role {} ({}) may not {action}",
                self.role, self.name
            ))
        }
    }
}

/// The tokens the API accepts, by digest.
#[derive(Debug, Clone, Default)]
pub struct TokenTable {
    entries: Vec<(TokenDigest, Principal)>,
}

impl TokenTable {
    /// Accept the token whose digest is `digest` as `name` with `role`.
    pub fn add(&mut self, digest: TokenDigest, name: &str, role: Role) {
        self.entries.push((
            digest,
            Principal {
                name: name.to_owned(),
                role,
            },
        ));
    }

    /// Whether no token is accepted.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The principal whose token is `presented`: every entry is compared in constant time,
    /// and all of them are compared whatever matches.
    pub fn authenticate(&self, presented: &str) -> Option<&Principal> {
        let digest = TokenDigest::of_token(presented);
        let mut found = None;
        for (d, p) in &self.entries {
            if d.ct_eq(&digest) && found.is_none() {
                found = Some(p);
            }
        }
        found
    }
}

/// A new random token: 256 bits from the operating system's generator as 64 hexadecimal
/// digits (URL-safe).
pub fn new_token() -> Result<String, AuthError> {
    let mut bytes = [0u8; 32];
    rand::rngs::OsRng
        .try_fill_bytes(&mut bytes)
        .map_err(|e| AuthError::Rng(e.to_string()))?;
    Ok(hex(&bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digest_is_sha256_and_round_trips_through_hex() {
        // FIPS 180-2 test vector
        let d = TokenDigest::of_token("abc");
        assert_eq!(
            d.to_hex(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(TokenDigest::from_hex(&d.to_hex()).unwrap(), d);
        assert_eq!(
            TokenDigest::from_hex(&d.to_hex().to_uppercase()).unwrap(),
            d
        );
        for bad in ["", "abc", &"g".repeat(64), &"a".repeat(63), &"é".repeat(32)] {
            assert!(TokenDigest::from_hex(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn only_configured_tokens_authenticate() {
        let mut t = TokenTable::default();
        assert!(t.is_empty());
        t.add(TokenDigest::of_token("secret-a"), "alice", Role::Operator);
        t.add(TokenDigest::of_token("secret-b"), "bob", Role::Viewer);
        assert_eq!(t.authenticate("secret-a").unwrap().name, "alice");
        assert_eq!(t.authenticate("secret-b").unwrap().role, Role::Viewer);
        assert!(t.authenticate("secret-c").is_none());
        assert!(t.authenticate("").is_none());
        // the digest itself is not a token
        assert!(t
            .authenticate(&TokenDigest::of_token("secret-a").to_hex())
            .is_none());
    }

    #[test]
    fn roles_allow_what_the_contract_says() {
        use Action::*;
        let all = [
            Read, Create, Arm, Disarm, Start, Pause, Resume, Abort, Answer,
        ];
        let allowed = |r: Role| {
            all.iter()
                .copied()
                .filter(|a| r.may(*a))
                .collect::<Vec<_>>()
        };
        assert_eq!(allowed(Role::Viewer), vec![Read, Abort]);
        assert_eq!(allowed(Role::Technician), vec![Read, Pause, Abort, Answer]);
        assert_eq!(allowed(Role::Operator), all.to_vec());
        let p = Principal {
            name: "v".into(),
            role: Role::Viewer,
        };
        let e = p.check(Arm).unwrap_err();
        assert!(e.contains("viewer") && e.contains("arm"), "{e}");
        assert_eq!(Role::parse("technician"), Some(Role::Technician));
        assert_eq!(Role::parse("admin"), None);
    }

    #[test]
    fn new_tokens_are_long_url_safe_and_distinct() {
        let a = new_token().unwrap();
        let b = new_token().unwrap();
        assert_eq!(a.len(), 64);
        assert!(a.bytes().all(|c| c.is_ascii_hexdigit()), "{a}");
        assert_ne!(a, b);
    }
}
