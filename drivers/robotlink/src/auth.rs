//! Authentication of a robotlink v3 session (`PROTOCOL.md` §3a): a shared secret, fresh nonces
//! from the OS RNG and HMAC-SHA256 proofs both ways, compared in constant time.
//!
//! ```text
//! C: <seq> HELLO 3
//! S: <seq> OK <server_nonce>                         32 hex digits, fresh per connection
//! C: <seq> AUTH <client_nonce> <client_proof>        proof: 64 hex digits
//! S: <seq> OK <ctrl> <arm> <sw> <server_proof>       only after the client's proof verified
//! ```
//!
//! `client_proof = HMAC-SHA256(K, "robotlink3 client " ‖ Ns ‖ Nc)` and
//! `server_proof = HMAC-SHA256(K, "robotlink3 server " ‖ Ns ‖ Nc)` over the raw 16-byte nonces.
//! The labels keep one side's proof from passing for the other's; the server's fresh nonce makes
//! a recorded proof worthless on the next connection, the client's makes the server's proof
//! fresh for the client (mutual authentication).

use std::fmt;
use std::path::Path;

use hmac::{Hmac, Mac};
use sha2::Sha256;
use zeroize::Zeroize;

/// Bytes of the shared secret (written as 64 hex digits).
pub const SECRET_LEN: usize = 32;
/// Bytes of a nonce (written as 32 hex digits).
pub const NONCE_LEN: usize = 16;
/// Bytes of a proof, an HMAC-SHA256 (written as 64 hex digits).
pub const PROOF_LEN: usize = 32;
/// Prefix of the message a client's proof is computed over.
pub const CLIENT_LABEL: &[u8] = b"robotlink3 client ";
/// Prefix of the message a server's proof is computed over.
pub const SERVER_LABEL: &[u8] = b"robotlink3 server ";

type HmacSha256 = Hmac<Sha256>;

/// Why a secret could not be had.
#[derive(Debug, thiserror::Error)]
pub enum SecretError {
    /// The file could not be read.
    #[error("{path}: cannot read the shared secret: {cause}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        cause: std::io::Error,
    },
    /// The file is readable (or writable) by every user of the machine.
    #[error(
        "{path}: the shared secret is open to every user of this machine (mode {mode:o}); \
         make it readable by its owner (and group) only, e.g. `chmod 600 {path}`"
    )]
    WorldAccessible {
        /// The file.
        path: String,
        /// Its permission bits.
        mode: u32,
    },
    /// The text is not 64 hex digits (the content itself is never quoted).
    #[error(
        "{what}: the shared secret must be {} hex digits (32 random bytes, e.g. from \
         `openssl rand -hex 32`), found {found}",
        SECRET_LEN * 2
    )]
    Malformed {
        /// Where the text came from.
        what: String,
        /// What was found instead (a length or a character class, never the text).
        found: String,
    },
    /// The OS random number generator failed.
    #[error("the OS random number generator failed: {0}")]
    Rng(String),
}

/// The secret cellcal and the robot controller share. Its bytes never leave this type except
/// into the MAC: `Debug` prints `SharedSecret(..)`, there is no `Display`, no serde, and the
/// memory is zeroed on drop.
#[derive(Clone)]
pub struct SharedSecret {
    key: Box<[u8; SECRET_LEN]>,
}

impl fmt::Debug for SharedSecret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("SharedSecret(..)")
    }
}

impl Drop for SharedSecret {
    fn drop(&mut self) {
        self.key.zeroize();
    }
}

impl PartialEq for SharedSecret {
    /// Constant-time comparison.
    fn eq(&self, other: &Self) -> bool {
        use subtle::ConstantTimeEq;
        self.key.ct_eq(other.key.as_slice()).into()
    }
}

impl SharedSecret {
    /// A new random secret from the OS RNG (the simulated cell's, or for a new installation).
    pub fn generate() -> Result<SharedSecret, SecretError> {
        let mut key = Box::new([0u8; SECRET_LEN]);
        getrandom::fill(key.as_mut_slice()).map_err(|e| SecretError::Rng(e.to_string()))?;
        Ok(SharedSecret { key })
    }

    /// Parse 64 hex digits (either case; surrounding whitespace ignored). `what` names the
    /// source in the error, which never quotes the text.
    pub fn from_hex(text: &str, what: &str) -> Result<SharedSecret, SecretError> {
        let t = text.trim();
        let malformed = |found: String| SecretError::Malformed {
            what: what.to_owned(),
            found,
        };
        if t.len() != SECRET_LEN * 2 {
            return Err(malformed(format!("{} characters", t.len())));
        }
        let mut key = Box::new([0u8; SECRET_LEN]);
        if !decode_hex(t.as_bytes(), key.as_mut_slice()) {
            key.zeroize();
            return Err(malformed("a character that is not a hex digit".into()));
        }
        Ok(SharedSecret { key })
    }

    /// Read a secret file: 64 hex digits (a trailing newline is fine). Refused when every user
    /// of the machine may read or write it (any "other" permission bit, Unix).
    pub fn read_file(path: &Path) -> Result<SharedSecret, SecretError> {
        let shown = path.display().to_string();
        let read = |cause| SecretError::Read {
            path: shown.clone(),
            cause,
        };
        let meta = std::fs::metadata(path).map_err(read)?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = meta.permissions().mode() & 0o7777;
            if mode & 0o007 != 0 {
                return Err(SecretError::WorldAccessible {
                    path: shown.clone(),
                    mode,
                });
            }
        }
        if !meta.is_file() {
            return Err(read(std::io::Error::other("not a regular file")));
        }
        let mut text = std::fs::read_to_string(path).map_err(read)?;
        let secret = SharedSecret::from_hex(&text, &shown);
        text.zeroize();
        secret
    }

    fn mac(&self, label: &[u8], server: &Nonce, client: &Nonce) -> HmacSha256 {
        let mut m = HmacSha256::new_from_slice(self.key.as_slice())
            .expect("HMAC takes a key of any length");
        m.update(label);
        m.update(&server.0);
        m.update(&client.0);
        m
    }

    /// The client's proof for this pair of nonces.
    pub fn client_proof(&self, server: &Nonce, client: &Nonce) -> Proof {
        Proof(
            self.mac(CLIENT_LABEL, server, client)
                .finalize()
                .into_bytes()
                .into(),
        )
    }

    /// The server's proof for this pair of nonces.
    pub fn server_proof(&self, server: &Nonce, client: &Nonce) -> Proof {
        Proof(
            self.mac(SERVER_LABEL, server, client)
                .finalize()
                .into_bytes()
                .into(),
        )
    }

    /// Whether `proof` is the client's proof for these nonces (constant time).
    pub fn verify_client(&self, server: &Nonce, client: &Nonce, proof: &Proof) -> bool {
        self.mac(CLIENT_LABEL, server, client)
            .verify_slice(&proof.0)
            .is_ok()
    }

    /// Whether `proof` is the server's proof for these nonces (constant time).
    pub fn verify_server(&self, server: &Nonce, client: &Nonce, proof: &Proof) -> bool {
        self.mac(SERVER_LABEL, server, client)
            .verify_slice(&proof.0)
            .is_ok()
    }
}

/// A fresh random value of one handshake (16 bytes, 32 hex digits on the wire).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Nonce(pub [u8; NONCE_LEN]);

impl fmt::Debug for Nonce {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Nonce({})", self.to_hex())
    }
}

impl Nonce {
    /// A new nonce from the OS RNG.
    pub fn generate() -> Result<Nonce, SecretError> {
        let mut n = [0u8; NONCE_LEN];
        getrandom::fill(&mut n).map_err(|e| SecretError::Rng(e.to_string()))?;
        Ok(Nonce(n))
    }

    /// Lower-case hex, as sent.
    pub fn to_hex(&self) -> String {
        encode_hex(&self.0)
    }

    /// Parse exactly 32 hex digits (either case).
    pub fn from_hex(t: &str) -> Option<Nonce> {
        let mut n = [0u8; NONCE_LEN];
        (t.len() == NONCE_LEN * 2 && decode_hex(t.as_bytes(), &mut n)).then_some(Nonce(n))
    }
}

/// An HMAC-SHA256 proof (32 bytes, 64 hex digits on the wire).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Proof(pub [u8; PROOF_LEN]);

impl fmt::Debug for Proof {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Proof(..)")
    }
}

impl Proof {
    /// Lower-case hex, as sent.
    pub fn to_hex(&self) -> String {
        encode_hex(&self.0)
    }

    /// Parse exactly 64 hex digits (either case).
    pub fn from_hex(t: &str) -> Option<Proof> {
        let mut p = [0u8; PROOF_LEN];
        (t.len() == PROOF_LEN * 2 && decode_hex(t.as_bytes(), &mut p)).then_some(Proof(p))
    }
}

fn encode_hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        s.push(char::from(DIGITS[usize::from(b >> 4)]));
        s.push(char::from(DIGITS[usize::from(b & 15)]));
    }
    s
}

/// Decode `hex` (exactly twice `out`'s length) into `out`; false on any non-hex byte.
fn decode_hex(hex: &[u8], out: &mut [u8]) -> bool {
    if hex.len() != out.len() * 2 {
        return false;
    }
    let digit = |c: u8| match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    };
    for (o, pair) in out.iter_mut().zip(hex.chunks_exact(2)) {
        match (digit(pair[0]), digit(pair[1])) {
            (Some(h), Some(l)) => *o = (h << 4) | l,
            _ => return false,
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: &str = "000102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f";

    #[test]
    fn proofs_are_hmac_sha256_of_label_and_nonces() {
        // Golden values, computed independently (Python's hmac module; PROTOCOL.md §3a example).
        let k = SharedSecret::from_hex(KEY, "test").unwrap();
        let ns = Nonce::from_hex("00112233445566778899aabbccddeeff").unwrap();
        let nc = Nonce::from_hex("0f0e0d0c0b0a09080706050403020100").unwrap();
        let c = k.client_proof(&ns, &nc);
        let s = k.server_proof(&ns, &nc);
        assert_ne!(c, s, "the labels separate the two proofs");
        assert!(k.verify_client(&ns, &nc, &c));
        assert!(!k.verify_client(&ns, &nc, &s));
        assert!(k.verify_server(&ns, &nc, &s));
        let other = Nonce::from_hex("00112233445566778899aabbccddeefe").unwrap();
        assert!(
            !k.verify_client(&other, &nc, &c),
            "bound to the server nonce"
        );
        assert!(
            !k.verify_client(&ns, &other, &c),
            "bound to the client nonce"
        );
        assert_eq!(c.to_hex(), GOLDEN_CLIENT);
        assert_eq!(s.to_hex(), GOLDEN_SERVER);
    }

    const GOLDEN_CLIENT: &str = "4ec766f0727bc30b25adf756b618a2c0e144ae5264ce98c49f27cf6557f13cb2";
    const GOLDEN_SERVER: &str = "37719446d95386f3d2945a059f0b2c06a0a29f965a826f65eda2f6dab93cbfcf";

    #[test]
    fn secrets_parse_strictly_and_never_show() {
        let k = SharedSecret::from_hex(&format!("  {}\n", KEY.to_uppercase()), "t").unwrap();
        assert_eq!(k, SharedSecret::from_hex(KEY, "t").unwrap());
        assert_eq!(format!("{k:?}"), "SharedSecret(..)");
        for bad in ["", "00", &KEY[1..], &format!("{}g", &KEY[1..])] {
            let e = SharedSecret::from_hex(bad, "file.key")
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("file.key: "), "{e}");
            assert!(
                bad.len() < 8 || !e.contains(&bad[..8]),
                "quotes the text: {e}"
            );
        }
        let a = SharedSecret::generate().unwrap();
        let b = SharedSecret::generate().unwrap();
        assert_ne!(a, b);
        assert_ne!(Nonce::generate().unwrap(), Nonce::generate().unwrap());
        assert!(Nonce::from_hex("00112233445566778899aabbccddeef").is_none());
        assert!(Proof::from_hex(&"x".repeat(64)).is_none());
    }
}
