//! Config pushed from the broker, the pure part: a push read and bounded, what it may change
//! (secrets and trust only with `[remote] security = true`), how far a change reaches (a reload
//! of the buses, the outputs rebuilt, the process started again), and the watch of its grace
//! period (the connection that delivered it up, every device that answered before answering
//! again). The wiring is in `app`.

use std::collections::BTreeSet;

use tokio::time::Instant;

use crate::config::Config;

/// The largest push taken (a config of a few hundred devices; MQTT's packet limit is 64 KiB).
pub const MAX_PUSH: usize = 60 * 1024;

/// The longest `id` of a push.
pub const MAX_ID: usize = 128;

/// A push as it arrived: its id and the config's TOML text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Push {
    pub id: Option<String>,
    pub toml: String,
}

/// Why a push is refused before anything changes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refusal {
    #[error("the push is {0} bytes, more than the {MAX_PUSH} taken")]
    TooLarge(usize),
    #[error("not a push: {0} (send {{\"id\": \"…\", \"toml\": \"…\"}})")]
    BadPayload(String),
    #[error("the config is refused:\n{0}")]
    BadConfig(String),
    #[error(
        "it changes {0}, which holds secrets or trust: allowed only with [remote] security = true"
    )]
    Forbidden(String),
    #[error("a pushed config is being watched (id {0:?}): push again after its result")]
    Busy(String),
    #[error("cannot write the config file: {0}")]
    WriteFailed(String),
}

impl Refusal {
    /// The `error` of the result.
    pub fn code(&self) -> &'static str {
        match self {
            Refusal::TooLarge(_) => "too_large",
            Refusal::BadPayload(_) => "bad_payload",
            Refusal::BadConfig(_) => "bad_config",
            Refusal::Forbidden(_) => "forbidden",
            Refusal::Busy(_) => "busy",
            Refusal::WriteFailed(_) => "write_failed",
        }
    }
}

/// Reads a push: `{"id": "...", "toml": "..."}`, nothing else, bounded. The id is returned with
/// a refusal when it could be read, so the result can echo it.
pub fn parse(payload: &[u8]) -> Result<Push, (Option<String>, Refusal)> {
    if payload.len() > MAX_PUSH {
        return Err((None, Refusal::TooLarge(payload.len())));
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
    if let Some(k) = map.keys().find(|k| !["id", "toml"].contains(&k.as_str())) {
        return Err((id, bad(&format!("unexpected field {k:?}"))));
    }
    match map.get("toml") {
        Some(serde_json::Value::String(toml)) => Ok(Push {
            id,
            toml: toml.clone(),
        }),
        _ => Err((id, bad("\"toml\" must be the config file's text"))),
    }
}

/// The sections holding secrets or trust that `new` changes against `old`: the credentials and
/// TLS of `[mqtt]` and of each output, and `[remote]` itself.
pub fn guarded_changes(old: &Config, new: &Config) -> Vec<String> {
    let mut out = Vec::new();
    let creds = |m: &crate::config::Mqtt| (m.username.clone(), m.password.clone(), m.tls.clone());
    if creds(&old.mqtt) != creds(&new.mqtt) {
        out.push("[mqtt] credentials or [mqtt.tls]".to_string());
    }
    for o in &new.outputs.list {
        let before = old.outputs.list.iter().find(|p| p.name == o.name);
        if before.map(|b| creds(&b.mqtt)) != Some(creds(&o.mqtt)) && before.is_some() {
            out.push(format!("[outputs.{}] credentials or TLS", o.name));
        }
        if before.is_none() && creds(&o.mqtt) != creds(&new.mqtt) {
            out.push(format!("[outputs.{}] credentials or TLS", o.name));
        }
    }
    if old.remote != new.remote {
        out.push("[remote]".to_string());
    }
    out
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

/// The grace period of an applied push: what must hold at its end for the config to stay.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Watch {
    pub id: Option<String>,
    pub until: Instant,
    /// The connection that delivered it (its health loop is `output/<name>`).
    pub connection: String,
    /// Devices that were online before and are still configured, not yet heard again.
    pub waiting: BTreeSet<String>,
}

impl Watch {
    /// A watch of `grace` from `now` for the devices `online_before` that `new` still polls.
    pub fn new(
        id: Option<String>,
        now: Instant,
        grace: std::time::Duration,
        connection: &str,
        online_before: &[String],
        new: &Config,
    ) -> Watch {
        let configured: BTreeSet<String> =
            new.enabled_devices().map(|(_, d)| d.name.clone()).collect();
        Watch {
            id,
            until: now + grace,
            connection: connection.to_string(),
            waiting: online_before
                .iter()
                .filter(|d| configured.contains(*d))
                .cloned()
                .collect(),
        }
    }

    /// Devices online now: each one waited for has answered again.
    pub fn online(&mut self, devices: &[String]) {
        for d in devices {
            self.waiting.remove(d);
        }
    }

    /// At the end of the grace period, whether the config stays: `Ok`, or why it goes.
    /// `None` before the end.
    pub fn verdict(&self, now: Instant, connection_up: bool) -> Option<Result<(), String>> {
        if now < self.until {
            return None;
        }
        if !connection_up {
            return Some(Err(format!(
                "the connection that delivered it ({}) is not up",
                self.connection
            )));
        }
        if !self.waiting.is_empty() {
            let names: Vec<&str> = self.waiting.iter().map(String::as_str).collect();
            return Some(Err(format!(
                "devices online before did not answer again: {}",
                names.join(", ")
            )));
        }
        Some(Ok(()))
    }
}

#[cfg(test)]
#[path = "remote_tests.rs"]
mod tests;
