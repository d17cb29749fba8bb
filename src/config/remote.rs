//! `[remote]`: config pushed from the broker (off by default). `config = true` takes a new
//! config on `<root>/config/set`, checks it as `pulsegate check` does, applies it and watches it
//! for `grace`. `trusted_keys` lists the Ed25519 public keys whose signed pushes may change what
//! moves trust (where credentials go, who may connect, what the gateway listens on); without
//! them a push may change only what a site's operation needs (see `crate::remote::guard`).

use std::time::Duration;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;

use super::walk::{Errors, Table, join};

/// `[remote]`, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Remote {
    pub config: bool,
    /// How long a pushed config is watched before it is kept (or rolled back).
    pub grace: Duration,
    /// `trusted_keys`: with one or more, every push must be signed by one of them.
    pub trusted_keys: Vec<TrustedKey>,
}

/// The default grace period of a pushed config.
pub const DEFAULT_GRACE: Duration = Duration::from_secs(60);

/// The most keys trusted at once (a few signers and a key being rotated in).
pub const MAX_TRUSTED_KEYS: usize = 16;

impl Default for Remote {
    fn default() -> Remote {
        Remote {
            config: false,
            grace: DEFAULT_GRACE,
            trusted_keys: Vec::new(),
        }
    }
}

/// Reads `[remote]`.
pub(crate) fn read(table: Option<Table<'_>>, errs: &mut Errors) -> Remote {
    let mut r = Remote::default();
    let Some(mut t) = table else { return r };
    if let Some(v) = t.opt("config", errs) {
        r.config = v;
    }
    if let Some(v) = t.duration_within(
        "grace",
        Duration::from_secs(5),
        Duration::from_secs(3600),
        errs,
    ) {
        r.grace = v;
    }
    if t.has("security") {
        let _ = t.raw("security");
        let why = "removed: a push that changes credentials, destinations, listeners or [remote] must be signed by a key in [remote] trusted_keys (docs/operations.md)";
        errs.push(&join(&t.path, "security"), t.origin(), why);
    }
    r.trusted_keys = trusted_keys(&mut t, errs);
    t.finish(errs);
    r
}

fn trusted_keys(t: &mut Table<'_>, errs: &mut Errors) -> Vec<TrustedKey> {
    let Some(list) = t.opt::<Vec<String>>("trusted_keys", errs) else {
        return Vec::new();
    };
    let path = join(&t.path, "trusted_keys");
    if list.len() > MAX_TRUSTED_KEYS {
        let why = format!("{} keys, at most {MAX_TRUSTED_KEYS}", list.len());
        errs.push(&path, t.origin(), why);
    }
    let mut keys = Vec::new();
    for (i, text) in list.iter().enumerate() {
        match text.parse::<TrustedKey>() {
            Ok(k) if !keys.contains(&k) => keys.push(k),
            Ok(_) => errs.push(&format!("{path}[{i}]"), t.origin(), "listed twice"),
            Err(why) => errs.push(&format!("{path}[{i}]"), t.origin(), why),
        }
    }
    keys
}

/// A trusted Ed25519 public key: its 32 raw bytes.
#[derive(Clone, PartialEq, Eq, Hash)]
pub struct TrustedKey(pub [u8; 32]);

impl std::fmt::Debug for TrustedKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "TrustedKey({})", STANDARD.encode(self.0))
    }
}

impl std::str::FromStr for TrustedKey {
    type Err = String;

    /// Base64 of the raw 32-byte public key.
    fn from_str(s: &str) -> Result<TrustedKey, String> {
        let bytes = STANDARD
            .decode(s.trim())
            .map_err(|e| format!("not base64: {e}"))?;
        let raw: [u8; 32] = bytes.try_into().map_err(|b: Vec<u8>| {
            format!(
                "{} bytes, where an Ed25519 public key is 32 (the raw key in base64)",
                b.len()
            )
        })?;
        Ok(TrustedKey(raw))
    }
}

impl std::fmt::Display for TrustedKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&STANDARD.encode(self.0))
    }
}
