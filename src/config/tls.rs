//! TLS to the broker (rustls, ring): built once from `[mqtt.tls]`, the same way by `check` and by
//! `run`. Security settings fail closed: a CA file that cannot be read or holds no certificate is
//! an error, never a fallback to plaintext.

use std::path::Path;
use std::sync::Arc;

use rustls::ClientConfig;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};

use super::connection::Tls;

/// Why TLS could not be set up; names the file and the cause.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("{path} holds no PEM certificate")]
    NoCertificate { path: String },
    #[error("{path}: {message}")]
    BadPem { path: String, message: String },
    #[error("TLS setup: {0}")]
    Rustls(#[from] rustls::Error),
    /// rumqttc has no TLS over a Unix socket; connecting without it would drop a security
    /// setting the user asked for.
    #[error("mqtt.socket ({socket}) and mqtt.tls cannot be set together: remove one of them")]
    OverSocket { socket: String },
}

fn read(path: &Path) -> Result<Vec<u8>, TlsError> {
    std::fs::read(path).map_err(|source| TlsError::Read {
        path: path.display().to_string(),
        source,
    })
}

fn certificates(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let bytes = read(path)?;
    let certs = CertificateDer::pem_slice_iter(&bytes)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| TlsError::BadPem {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
    if certs.is_empty() {
        return Err(TlsError::NoCertificate {
            path: path.display().to_string(),
        });
    }
    Ok(certs)
}

/// When the first certificate in the PEM file `path` expires (its notAfter), in seconds since
/// the Unix epoch.
pub fn expiry(path: &Path) -> Result<i64, TlsError> {
    use x509_cert::der::Decode;
    let first = certificates(path)?.swap_remove(0);
    let cert = x509_cert::Certificate::from_der(first.as_ref()).map_err(|e| TlsError::BadPem {
        path: path.display().to_string(),
        message: format!("not an X.509 certificate: {e}"),
    })?;
    let not_after = cert
        .tbs_certificate()
        .validity()
        .not_after
        .to_unix_duration();
    Ok(not_after.as_secs() as i64)
}

/// The rustls client configuration for `tls`: the broker's certificate must chain to `ca_file`;
/// the client certificate is presented when configured.
pub fn client_config(tls: &Tls) -> Result<Arc<ClientConfig>, TlsError> {
    let mut roots = rustls::RootCertStore::empty();
    for cert in certificates(&tls.ca_file)? {
        roots.add(cert)?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()?
        .with_root_certificates(roots);
    let config = match (&tls.cert_file, &tls.key_file) {
        (Some(cert), Some(key)) => {
            let chain = certificates(cert)?;
            let key_bytes = read(key)?;
            let key = PrivateKeyDer::from_pem_slice(&key_bytes).map_err(|e| TlsError::BadPem {
                path: key.display().to_string(),
                message: format!("no private key: {e}"),
            })?;
            builder.with_client_auth_cert(chain, key)?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tls(ca: &Path) -> Tls {
        Tls {
            ca_file: ca.to_path_buf(),
            cert_file: None,
            key_file: None,
        }
    }

    #[test]
    fn a_ca_file_that_cannot_be_read_is_an_error_naming_it() {
        let e = client_config(&tls(Path::new("/nonexistent/ca.pem"))).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/ca.pem"), "{e}");
    }

    #[test]
    fn a_ca_file_without_a_certificate_is_an_error() {
        let p = std::env::temp_dir().join(format!("pulsegate-ca-{}.pem", std::process::id()));
        std::fs::write(&p, "not a certificate\n").unwrap();
        let e = client_config(&tls(&p)).unwrap_err();
        std::fs::remove_file(&p).unwrap();
        assert!(e.to_string().contains("no PEM certificate"), "{e}");
    }
}
