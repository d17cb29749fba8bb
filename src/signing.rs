//! Ed25519 keys (RFC 8032, through `ring`): a signer's key pair read from the PKCS#8 PEM that
//! `openssl genpkey -algorithm ed25519` writes, its raw 32-byte public key, and the check of a
//! signature against one public key. Pure vocabulary: what is signed is said by its users
//! (`remote/signature.rs` for pushes, `publish/signed.rs` for records).

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use ring::signature::{ED25519, Ed25519KeyPair, KeyPair as _, UnparsedPublicKey};

/// Why a signing key cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    #[error(
        "not a PEM private key (-----BEGIN PRIVATE KEY-----, as `openssl genpkey -algorithm ed25519` writes)"
    )]
    NotPem,
    #[error("not an Ed25519 PKCS#8 private key: {0}")]
    NotEd25519(String),
    #[error("cannot make a key: {0}")]
    Random(String),
}

/// A signer's key pair.
pub struct SigningKey(Ed25519KeyPair);

/// The PKCS#8 v1 (RFC 8410) prefix of an Ed25519 private key, before its 32-byte seed: the form
/// openssl writes and reads.
pub(crate) const PKCS8_V1_PREFIX: [u8; 16] = [
    0x30, 0x2e, 0x02, 0x01, 0x00, 0x30, 0x05, 0x06, 0x03, 0x2b, 0x65, 0x70, 0x04, 0x22, 0x04, 0x20,
];

impl SigningKey {
    /// Reads a PKCS#8 PEM private key.
    pub fn from_pem(text: &str) -> Result<SigningKey, KeyError> {
        let der = pem_body(text, "PRIVATE KEY").ok_or(KeyError::NotPem)?;
        Ed25519KeyPair::from_pkcs8_maybe_unchecked(&der)
            .map(SigningKey)
            .map_err(|e| KeyError::NotEd25519(e.to_string()))
    }

    /// A new key, as PKCS#8 PEM (the v1 form openssl writes).
    pub fn generate_pem() -> Result<String, KeyError> {
        use ring::rand::SecureRandom as _;
        let mut seed = [0u8; 32];
        ring::rand::SystemRandom::new()
            .fill(&mut seed)
            .map_err(|e| KeyError::Random(e.to_string()))?;
        let mut der = PKCS8_V1_PREFIX.to_vec();
        der.extend_from_slice(&seed);
        Ok(pem("PRIVATE KEY", &der))
    }

    /// The raw 32-byte public key.
    pub fn public(&self) -> [u8; 32] {
        let mut raw = [0u8; 32];
        raw.copy_from_slice(self.0.public_key().as_ref());
        raw
    }

    /// The public key in base64 (what `[remote] trusted_keys` lists and `<root>/gateway` says).
    pub fn public_base64(&self) -> String {
        STANDARD.encode(self.public())
    }

    /// The signature of `bytes`, base64.
    pub fn sign(&self, bytes: &[u8]) -> String {
        STANDARD.encode(self.0.sign(bytes).as_ref())
    }
}

/// Two keys are the same key when their public halves are.
impl PartialEq for SigningKey {
    fn eq(&self, other: &SigningKey) -> bool {
        self.public() == other.public()
    }
}

impl Eq for SigningKey {}

/// The public half only: a private key is never printed.
impl std::fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SigningKey(public {})", self.public_base64())
    }
}

/// Whether `signature` (base64 of 64 bytes) over `bytes` verifies with the raw `public` key.
pub fn verifies(public: &[u8; 32], bytes: &[u8], signature: &str) -> bool {
    let Some(sig) = STANDARD
        .decode(signature.trim())
        .ok()
        .filter(|s| s.len() == 64)
    else {
        return false;
    };
    UnparsedPublicKey::new(&ED25519, public)
        .verify(bytes, &sig)
        .is_ok()
}

/// The DER inside a PEM block labelled `label`.
fn pem_body(text: &str, label: &str) -> Option<Vec<u8>> {
    let begin = format!("-----BEGIN {label}-----");
    let end = format!("-----END {label}-----");
    let start = text.find(&begin)? + begin.len();
    let stop = start + text[start..].find(&end)?;
    let b64: String = text[start..stop]
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect();
    STANDARD.decode(b64).ok()
}

/// `der` as a PEM block labelled `label`.
pub(crate) fn pem(label: &str, der: &[u8]) -> String {
    let b64 = STANDARD.encode(der);
    let mut out = format!("-----BEGIN {label}-----\n");
    for line in b64.as_bytes().chunks(64) {
        out.push_str(std::str::from_utf8(line).unwrap_or_default());
        out.push('\n');
    }
    out.push_str(&format!("-----END {label}-----\n"));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_signature_verifies_with_its_public_key_and_not_over_other_bytes() {
        let key = SigningKey::from_pem(&SigningKey::generate_pem().unwrap()).unwrap();
        let sig = key.sign(b"abc");
        assert!(verifies(&key.public(), b"abc", &sig));
        assert!(!verifies(&key.public(), b"abd", &sig));
        assert!(!verifies(&key.public(), b"abc", "not base64"));
        assert_eq!(STANDARD.decode(key.public_base64()).unwrap().len(), 32);
    }
}
