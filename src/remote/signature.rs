//! Signed pushes: the exact bytes a push's signature covers, its check against the trusted
//! keys, and the signer's side (`pulsegate config keygen` / `config sign`) so that the same
//! byte string is written in one place. Ed25519 (RFC 8032) through `ring`; keys as the
//! PKCS#8 PEM that `openssl genpkey -algorithm ed25519` writes, public keys as the raw 32 bytes
//! in base64 (what `[remote] trusted_keys` lists).
//!
//! The signed bytes are, with `\n` one 0x0A byte and the TOML text exactly as sent:
//!
//! ```text
//! pulsegate-config-v1\n<gateway id>\n<push id>\n<serial in decimal>\n<toml>
//! ```
//!
//! The gateway id binds a push to one gateway (a push signed for another is refused), the push
//! id to its result, the serial to its place in the sequence (a replay is refused).

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use ring::signature::{ED25519, Ed25519KeyPair, KeyPair as _, UnparsedPublicKey};

pub use crate::config::remote::TrustedKey;

/// The first line of the signed bytes: the version of this format.
pub const DOMAIN: &str = "pulsegate-config-v1";

/// The bytes a push's signature covers (see the module's documentation).
pub fn signed_bytes(gateway: &str, id: &str, serial: u64, toml: &str) -> Vec<u8> {
    format!("{DOMAIN}\n{gateway}\n{id}\n{serial}\n{toml}").into_bytes()
}

/// Why a signature is not taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SignatureError {
    #[error("the signature is not base64 of 64 bytes")]
    Malformed,
    #[error(
        "the signature does not verify with any trusted key for this gateway, push id, serial and text"
    )]
    NotTrusted,
}

/// Whether `signature` (base64) over `bytes` verifies with one of `keys`.
pub fn verify(keys: &[TrustedKey], bytes: &[u8], signature: &str) -> Result<(), SignatureError> {
    let sig = STANDARD
        .decode(signature.trim())
        .ok()
        .filter(|s| s.len() == 64)
        .ok_or(SignatureError::Malformed)?;
    let good = keys.iter().any(|k| {
        UnparsedPublicKey::new(&ED25519, k.0)
            .verify(bytes, &sig)
            .is_ok()
    });
    if good {
        Ok(())
    } else {
        Err(SignatureError::NotTrusted)
    }
}

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
const PKCS8_V1_PREFIX: [u8; 16] = [
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

    /// The public key, as `[remote] trusted_keys` lists it.
    pub fn public(&self) -> TrustedKey {
        let mut raw = [0u8; 32];
        raw.copy_from_slice(self.0.public_key().as_ref());
        TrustedKey(raw)
    }

    /// The signature of `bytes`, base64.
    pub fn sign(&self, bytes: &[u8]) -> String {
        STANDARD.encode(self.0.sign(bytes).as_ref())
    }
}

/// A push ready to publish on `<root>/config/set`: the JSON `config sign` prints.
pub fn signed_push(key: &SigningKey, gateway: &str, id: &str, serial: u64, toml: &str) -> String {
    let signature = key.sign(&signed_bytes(gateway, id, serial, toml));
    serde_json::json!({"id": id, "serial": serial, "toml": toml, "signature": signature})
        .to_string()
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

fn pem(label: &str, der: &[u8]) -> String {
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

    /// RFC 8032 section 7.1, TEST 2: a published key, message and signature.
    const RFC8032_SEED: &str = "4ccd089b28ff96da9db6c346ec114e0f5b8a319f35aba624da8cf6ed4fb8a6fb";
    const RFC8032_PUBLIC: &str = "3d4017c3e843895a92b70aa74d1b7ebc9c982ccf2ec4968cc0cd55f12af4660c";
    const RFC8032_SIG: &str = "92a009a9f0d4cab8720e820b5f642540a2b27b5416503f8fb3762223ebdb69da085ac1e43e15996e458f3613d0f11d8c387b2eaeb4302aeeb00d291612bb0c00";

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    fn rfc_key() -> SigningKey {
        let mut der = PKCS8_V1_PREFIX.to_vec();
        der.extend(hex(RFC8032_SEED));
        SigningKey::from_pem(&pem("PRIVATE KEY", &der)).unwrap()
    }

    #[test]
    fn the_rfc_8032_test_vector_signs_and_verifies() {
        let key = rfc_key();
        assert_eq!(key.public().0.to_vec(), hex(RFC8032_PUBLIC));
        let sig = key.sign(&[0x72]);
        assert_eq!(STANDARD.decode(&sig).unwrap(), hex(RFC8032_SIG));
        assert_eq!(verify(&[key.public()], &[0x72], &sig), Ok(()));
    }

    #[test]
    fn the_signed_bytes_are_the_documented_lines() {
        assert_eq!(
            signed_bytes("plant-7", "p1", 42, "[gateway]\nid = \"plant-7\"\n"),
            b"pulsegate-config-v1\nplant-7\np1\n42\n[gateway]\nid = \"plant-7\"\n"
        );
    }

    #[test]
    fn a_signature_for_other_bytes_or_by_another_key_does_not_verify() {
        let key = rfc_key();
        let other = SigningKey::from_pem(&SigningKey::generate_pem().unwrap()).unwrap();
        let bytes = signed_bytes("g", "p", 1, "x");
        let sig = key.sign(&bytes);
        let untrusted = [other.public()];
        assert_eq!(
            verify(&untrusted, &bytes, &sig),
            Err(SignatureError::NotTrusted)
        );
        let changed = signed_bytes("g", "p", 2, "x");
        assert_eq!(
            verify(&[key.public()], &changed, &sig),
            Err(SignatureError::NotTrusted)
        );
        assert_eq!(
            verify(&[key.public()], &bytes, "abc"),
            Err(SignatureError::Malformed)
        );
        assert_eq!(
            verify(&[other.public(), key.public()], &bytes, &sig),
            Ok(())
        );
    }

    #[test]
    fn a_trusted_key_is_base64_of_32_bytes() {
        let k: TrustedKey = STANDARD.encode([7u8; 32]).parse().unwrap();
        assert_eq!(k.0, [7u8; 32]);
        assert!("not base64!".parse::<TrustedKey>().is_err());
        let short = STANDARD
            .encode([7u8; 31])
            .parse::<TrustedKey>()
            .unwrap_err();
        assert!(short.contains("31 bytes"), "{short}");
    }

    #[test]
    fn a_key_that_is_not_pem_is_refused_by_name() {
        assert!(matches!(
            SigningKey::from_pem("hello"),
            Err(KeyError::NotPem)
        ));
        let rsa_like = pem("PRIVATE KEY", &[0x30, 0x03, 0x02, 0x01, 0x00]);
        assert!(matches!(
            SigningKey::from_pem(&rsa_like),
            Err(KeyError::NotEd25519(_))
        ));
    }
}
