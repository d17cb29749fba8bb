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
use ring::signature::{ED25519, UnparsedPublicKey};

pub use crate::config::remote::TrustedKey;
pub use crate::signing::{KeyError, SigningKey};

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

/// A push ready to publish on `<root>/config/set`: the JSON `config sign` prints.
pub fn signed_push(key: &SigningKey, gateway: &str, id: &str, serial: u64, toml: &str) -> String {
    let signature = key.sign(&signed_bytes(gateway, id, serial, toml));
    serde_json::json!({"id": id, "serial": serial, "toml": toml, "signature": signature})
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signing::{PKCS8_V1_PREFIX, pem};

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
        assert_eq!(key.public().to_vec(), hex(RFC8032_PUBLIC));
        let sig = key.sign(&[0x72]);
        assert_eq!(STANDARD.decode(&sig).unwrap(), hex(RFC8032_SIG));
        assert_eq!(verify(&[TrustedKey(key.public())], &[0x72], &sig), Ok(()));
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
        let untrusted = [TrustedKey(other.public())];
        assert_eq!(
            verify(&untrusted, &bytes, &sig),
            Err(SignatureError::NotTrusted)
        );
        let changed = signed_bytes("g", "p", 2, "x");
        assert_eq!(
            verify(&[TrustedKey(key.public())], &changed, &sig),
            Err(SignatureError::NotTrusted)
        );
        assert_eq!(
            verify(&[TrustedKey(key.public())], &bytes, "abc"),
            Err(SignatureError::Malformed)
        );
        assert_eq!(
            verify(
                &[TrustedKey(other.public()), TrustedKey(key.public())],
                &bytes,
                &sig
            ),
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
