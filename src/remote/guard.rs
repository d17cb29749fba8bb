//! What a push may change. An unsigned push may change what a site's operation needs (buses,
//! devices, channels, publish policy, intervals, the outputs' formats on the same brokers) and
//! nothing that moves trust; a signed one may change everything but where the state lives.
//!
//! What moves trust is whatever decides where the gateway's credentials are sent, who it is to
//! a broker, what it obeys and what it listens on: the destination of every connection (`host`,
//! `port`, `hosts`, `socket`; a destination compares as a whole, so a password read from a
//! file can never follow a pushed `port` to another listener), credentials and TLS, `client_id`
//! (another gateway's session), `topic_root`, `mqtt.commands` (a read-only site made writable),
//! `[metrics]` (a listener and its token), `gateway.id` and `[remote]` itself. `state_dir` is
//! never pushed: moving a gateway's counters is an on-site operation.

use std::path::PathBuf;

use crate::config::{Config, Mqtt};

/// Whether the push carried a signature that verified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signed {
    No,
    Yes,
}

/// The changes of `new` against `old` that this push may not make, each naming its keys.
pub fn forbidden_changes(old: &Config, new: &Config, signed: Signed) -> Vec<String> {
    let mut out = Vec::new();
    if old.gateway.state_dir != new.gateway.state_dir {
        out.push("gateway.state_dir (never pushed: move the state on site)".to_string());
    }
    if signed == Signed::Yes {
        return out;
    }
    if old.gateway.id != new.gateway.id {
        out.push("gateway.id".to_string());
    }
    if old.metrics != new.metrics {
        out.push("[metrics]".to_string());
    }
    if old.remote != new.remote {
        out.push("[remote]".to_string());
    }
    out.extend(crate::config::buses::server_changes(old, new));
    out.extend(connection_changes("mqtt", &old.mqtt, &new.mqtt));
    for o in &new.outputs.list {
        let path = format!("outputs.{}", o.name);
        match old.outputs.list.iter().find(|p| p.name == o.name) {
            Some(before) => out.extend(connection_changes(&path, &before.mqtt, &o.mqtt)),
            None => out.extend(new_connection(&path, &new.mqtt, &o.mqtt)),
        }
    }
    out
}

/// Where a connection sends what it has: its brokers, in order, and its local socket.
fn destination(m: &Mqtt) -> (Vec<(String, u16)>, Option<PathBuf>) {
    (m.servers(), m.socket.clone())
}

/// The trust-moving keys `new` changes against `old`, for one connection.
fn connection_changes(path: &str, old: &Mqtt, new: &Mqtt) -> Vec<String> {
    let mut out = Vec::new();
    let mut note = |changed: bool, keys: &str| {
        if changed {
            out.push(format!("{path}: {keys}"));
        }
    };
    note(
        destination(old) != destination(new),
        "host, port, hosts or socket (where its credentials go)",
    );
    note(
        (&old.username, &old.password) != (&new.username, &new.password),
        "credentials",
    );
    note(old.tls != new.tls, "tls");
    note(old.client_id != new.client_id, "client_id");
    note(old.topic_root != new.topic_root, "topic_root");
    note(old.commands != new.commands, "commands");
    out
}

/// A new output may only be another connection like the gateway's own: the same destination,
/// credentials, TLS, topic root and commands as `[mqtt]`, and a client id derived from it.
fn new_connection(path: &str, base: &Mqtt, new: &Mqtt) -> Vec<String> {
    let mut like_base = new.clone();
    let derived = new.client_id == base.client_id
        || new
            .client_id
            .strip_prefix(base.client_id.as_str())
            .is_some_and(|rest| rest.starts_with('-'));
    if derived {
        like_base.client_id = base.client_id.clone();
    }
    connection_changes(path, base, &like_base)
        .into_iter()
        .map(|c| format!("{c} (a new output with its own)"))
        .collect()
}
