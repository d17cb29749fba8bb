//! Config pushed from the broker, the pure part: a push read and bounded, its signature
//! ([`signature`]), what it may change ([`guard`]), how far a change reaches (a reload of the
//! buses, the outputs rebuilt, the process started again), and the watch of its grace period
//! (the connection that delivered it up, every device that answered before answering again),
//! kept on disk so that it outlives the process ([`watch`]). The wiring is in `app`.

use crate::config::Config;

pub mod guard;
pub mod signature;
pub mod watch;
pub mod writable;

/// The largest push taken (a config of a few hundred devices). Larger ones, up to the MQTT
/// packet size the gateway takes, are answered `too_large` with their id.
pub const MAX_PUSH: usize = 60 * 1024;

/// The largest payload read for its `id` only, to answer it `too_large`.
const MAX_READ_FOR_ID: usize = 1024 * 1024;

/// The longest `id` of a push.
pub const MAX_ID: usize = 128;

/// A push as it arrived: its id, the config's TOML text, and its signature if signed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Push {
    pub id: Option<String>,
    pub toml: String,
    pub signed: Option<Signature>,
}

/// A push's `serial` and `signature`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Signature {
    pub serial: u64,
    /// Base64 of the Ed25519 signature.
    pub value: String,
}

/// Why a push is refused before anything changes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    #[error("the push is {0} bytes, more than the {MAX_PUSH} taken")]
    TooLarge(usize),
    #[error("not a push: {0} (send {{\"id\": \"…\", \"toml\": \"…\"}})")]
    BadPayload(String),
    #[error(
        "published retained: a push is taken only as it is sent (a retained one would be applied again at every start); publish it without retain, and clear the retained message"
    )]
    Retained,
    #[error(
        "not signed: this gateway takes only pushes signed by a key in [remote] trusted_keys (\"serial\" and \"signature\")"
    )]
    Unsigned,
    #[error(
        "signed, but this gateway trusts no key ([remote] trusted_keys is empty): send it unsigned, or add the key on site"
    )]
    NoTrustedKeys,
    #[error("{0}")]
    BadSignature(signature::SignatureError),
    #[error(
        "serial {serial} is not greater than {last}, the last one taken: a replay, or sign it with a new serial"
    )]
    Replayed { serial: u64, last: u64 },
    #[error("the config is refused:\n{0}")]
    BadConfig(String),
    #[error("it changes what only a signed push may change: {0}")]
    Forbidden(String),
    #[error("a pushed config is being watched (id {0:?}): push again after its result")]
    Busy(String),
    #[error("the gateway is starting again for an earlier push: push again after its result")]
    Restarting,
    #[error("cannot write: {0}")]
    WriteFailed(String),
}

impl Refusal {
    /// The `error` of the result.
    pub fn code(&self) -> &'static str {
        match self {
            Refusal::TooLarge(_) => "too_large",
            Refusal::BadPayload(_) => "bad_payload",
            Refusal::Retained => "retained",
            Refusal::Unsigned => "unsigned",
            Refusal::NoTrustedKeys => "no_trusted_keys",
            Refusal::BadSignature(_) => "bad_signature",
            Refusal::Replayed { .. } => "replayed",
            Refusal::BadConfig(_) => "bad_config",
            Refusal::Forbidden(_) => "forbidden",
            Refusal::Busy(_) | Refusal::Restarting => "busy",
            Refusal::WriteFailed(_) => "write_failed",
        }
    }
}

/// Reads a push: `{"id": "...", "toml": "..."}`, and `"serial"` and `"signature"` when signed,
/// nothing else, bounded. The id is returned with a refusal when it could be read, so the
/// result can echo it (also for a push too large to take).
pub fn parse(payload: &[u8]) -> Result<Push, (Option<String>, Refusal)> {
    if payload.len() > MAX_PUSH {
        return Err((id_of(payload), Refusal::TooLarge(payload.len())));
    }
    let bad = |why: &str| Refusal::BadPayload(why.to_string());
    let value: serde_json::Value =
        serde_json::from_slice(payload).map_err(|e| (None, bad(&e.to_string())))?;
    let Some(map) = value.as_object() else {
        return Err((None, bad("not a JSON object")));
    };
    let id = match map.get("id") {
        None => None,
        Some(serde_json::Value::String(s)) if s.len() <= MAX_ID => Some(s.clone()),
        Some(_) => return Err((None, bad("\"id\" must be a string of at most 128 bytes"))),
    };
    let known = ["id", "toml", "serial", "signature"];
    if let Some(k) = map.keys().find(|k| !known.contains(&k.as_str())) {
        return Err((id, bad(&format!("unexpected field {k:?}"))));
    }
    let signed = match signature_of(map) {
        Ok(s) => s,
        Err(why) => return Err((id, bad(why))),
    };
    if signed.is_some() && id.is_none() {
        return Err((None, bad("a signed push needs an \"id\" (it is signed)")));
    }
    match map.get("toml") {
        Some(serde_json::Value::String(toml)) => Ok(Push {
            id,
            toml: toml.clone(),
            signed,
        }),
        _ => Err((id, bad("\"toml\" must be the config file's text"))),
    }
}

type JsonMap = serde_json::Map<String, serde_json::Value>;

/// `"serial"` and `"signature"`: both or neither.
fn signature_of(map: &JsonMap) -> Result<Option<Signature>, &'static str> {
    match (map.get("serial"), map.get("signature")) {
        (None, None) => Ok(None),
        (Some(serial), Some(serde_json::Value::String(value))) if value.len() <= 128 => {
            let serial = serial
                .as_u64()
                .ok_or("\"serial\" must be a non-negative integer")?;
            Ok(Some(Signature {
                serial,
                value: value.clone(),
            }))
        }
        (Some(_), Some(_)) => Err("\"signature\" must be a base64 string"),
        _ => Err("a signed push carries both \"serial\" and \"signature\""),
    }
}

/// The `id` of a payload too large to take, when it is JSON with one.
fn id_of(payload: &[u8]) -> Option<String> {
    if payload.len() > MAX_READ_FOR_ID {
        return None;
    }
    #[derive(serde::Deserialize)]
    struct IdOnly {
        id: Option<String>,
    }
    serde_json::from_slice::<IdOnly>(payload)
        .ok()?
        .id
        .filter(|id| id.len() <= MAX_ID)
}

/// Whether a signed push's `serial` may be taken after `last` (the last one taken, if any): it
/// must be greater, so a push captured on the broker cannot be sent again.
pub fn admit_serial(last: Option<u64>, serial: u64) -> Result<(), Refusal> {
    match last {
        Some(last) if serial <= last => Err(Refusal::Replayed { serial, last }),
        _ => Ok(()),
    }
}

/// How far a new config reaches into the running gateway.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Reach {
    /// Buses, devices, channels: a reload applies them.
    Reload,
    /// `[mqtt]`, `[outputs]` and the formats' settings: the outputs are rebuilt (their spools
    /// carry what they hold over).
    Outputs,
    /// `[gateway]`, `[metrics]`: the process starts again (the watch goes on after).
    Restart,
}

/// How far `new` reaches against `old`.
pub fn reach(old: &Config, new: &Config) -> Reach {
    if old.gateway != new.gateway || old.metrics != new.metrics {
        Reach::Restart
    } else if old.mqtt != new.mqtt || old.outputs != new.outputs {
        Reach::Outputs
    } else {
        Reach::Reload
    }
}

pub use watch::{Record, Resume, Watch};

#[cfg(test)]
mod tests;
