//! What the host sends the node: NCMD (rebirth), DCMD writes (`<c>/Clear`, `<c>/Preset`), the
//! primary host's STATE. Pure: bytes in, a checked meaning or an error naming its cause out. A
//! DCMD with one bad write is refused whole: a host must not half-apply what it sent.

use bytes::Bytes;

use super::proto::{Metric, Payload, Value};
use crate::command::{Via, Written};
use crate::dispatch::Incoming;

/// The NBIRTH metric a host writes to ask for a rebirth.
pub const REBIRTH: &str = "Node Control/Rebirth";
/// The NBIRTH metric a host writes to have the node stop and start again.
pub const REBOOT: &str = "Node Control/Reboot";
/// The NBIRTH metric a host writes to move the node to its next MQTT server.
pub const NEXT_SERVER: &str = "Node Control/Next Server";

/// The node controls of the spec the node takes, as its NBIRTH lists them.
pub const NODE_CONTROLS: [&str; 3] = [REBIRTH, REBOOT, NEXT_SERVER];

/// What an NCMD asks of the node (each a `Node Control/…` written `true`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NodeCommand {
    pub rebirth: bool,
    pub reboot: bool,
    pub next_server: bool,
}

/// The most metrics one command may carry (a host writes one or a few at a time).
pub const MAX_METRICS: usize = 64;

/// Why a command from the host is refused before it becomes a command of the gateway.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum HostCommandError {
    #[error("not a Sparkplug B payload: {0}")]
    Undecodable(String),
    #[error("{0} metrics in one command (at most {MAX_METRICS})")]
    TooMany(usize),
    #[error(
        "metric {0:?} is not a writable metric of this device (<channel>/Clear, <channel>/Preset)"
    )]
    NotWritable(String),
    #[error("metric alias {0} was not declared in this device's birth")]
    UnknownAlias(u64),
    #[error("a metric without name or alias")]
    Anonymous,
    #[error("{metric}: {why}")]
    BadValue { metric: String, why: &'static str },
    #[error("{0:?} is not a device of this node")]
    UnknownDevice(String),
}

/// One write of a DCMD.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Write {
    Clear { channel: String },
    Preset { channel: String, value: i64 },
}

impl Write {
    /// The metric the host wrote.
    pub fn metric(&self) -> String {
        match self {
            Write::Clear { channel } => format!("{channel}/Clear"),
            Write::Preset { channel, .. } => format!("{channel}/Preset"),
        }
    }

    /// The same request as a JSON command on the device's channel command topic, so it goes
    /// through the router's checks and admission like any other; its answer comes back to
    /// `output` ([`Via`]).
    pub fn incoming(
        &self,
        topics: &crate::topics::Topics,
        device: &str,
        output: &std::sync::Arc<str>,
    ) -> Incoming {
        let (channel, body) = match self {
            Write::Clear { channel } => (channel, serde_json::json!({"op": "clear"})),
            Write::Preset { channel, value } => {
                (channel, serde_json::json!({"op": "preset", "value": value}))
            }
        };
        Incoming {
            topic: topics.channel_command(device, channel),
            payload: Bytes::from(body.to_string()),
            retain: false,
            response_topic: None,
            correlation: None,
            via: Some(Via {
                output: output.clone(),
                wrote: Some(Written {
                    device: device.to_string(),
                    metric: self.metric(),
                }),
            }),
        }
    }
}

impl HostCommandError {
    /// The code of the answer the host sees.
    pub fn code(&self) -> &'static str {
        match self {
            HostCommandError::Undecodable(_) | HostCommandError::TooMany(_) => "bad_payload",
            HostCommandError::Anonymous => "bad_payload",
            HostCommandError::NotWritable(_) => "not_writable",
            HostCommandError::UnknownAlias(_) => "unknown_alias",
            HostCommandError::BadValue { .. } => "bad_value",
            HostCommandError::UnknownDevice(_) => "unknown_device",
        }
    }
}

fn decode(payload: &[u8]) -> Result<Payload, HostCommandError> {
    let p = Payload::decode(payload).map_err(|e| HostCommandError::Undecodable(e.to_string()))?;
    if p.metrics.len() > MAX_METRICS {
        return Err(HostCommandError::TooMany(p.metrics.len()));
    }
    Ok(p)
}

/// NCMD: which node controls it writes `true` (`Node Control/Rebirth`, `…/Reboot`,
/// `…/Next Server`). Other node metrics are not writable and are ignored.
pub fn node(payload: &[u8]) -> Result<NodeCommand, HostCommandError> {
    let p = decode(payload)?;
    let set = |name: &str| {
        p.metrics
            .iter()
            .any(|m| m.name.as_deref() == Some(name) && m.value == Some(Value::Boolean(true)))
    };
    Ok(NodeCommand {
        rebirth: set(REBIRTH),
        reboot: set(REBOOT),
        next_server: set(NEXT_SERVER),
    })
}

/// DCMD: the writes it asks for; `name_of` reads an alias the device's birth declared.
pub fn device(
    payload: &[u8],
    name_of: impl Fn(u64) -> Option<String>,
) -> Result<Vec<Write>, HostCommandError> {
    let p = decode(payload)?;
    let mut writes = Vec::new();
    for m in &p.metrics {
        let name = match (&m.name, m.alias) {
            (Some(n), _) if !n.is_empty() => n.clone(),
            (_, Some(a)) => name_of(a).ok_or(HostCommandError::UnknownAlias(a))?,
            _ => return Err(HostCommandError::Anonymous),
        };
        if let Some(w) = write(&name, m)? {
            writes.push(w);
        }
    }
    Ok(writes)
}

/// One metric of a DCMD: a clear (true; false asks for nothing) or a preset.
fn write(name: &str, m: &Metric) -> Result<Option<Write>, HostCommandError> {
    let bad = |why| HostCommandError::BadValue {
        metric: name.to_string(),
        why,
    };
    // A channel is one topic level of a name the gateway gave it: `a0/x/Clear` or
    // `../m2/enc0/Clear` name nothing writable.
    let (channel, what) = name
        .rsplit_once('/')
        .filter(|(c, _)| crate::topics::is_topic_safe(c))
        .ok_or_else(|| HostCommandError::NotWritable(name.to_string()))?;
    let channel = channel.to_string();
    match what {
        "Clear" => match m.value {
            Some(Value::Boolean(true)) => Ok(Some(Write::Clear { channel })),
            Some(Value::Boolean(false)) => Ok(None),
            _ => Err(bad("a clear is the Boolean true")),
        },
        "Preset" => {
            let value = preset_value(m).ok_or_else(|| bad("a preset is a whole number"))?;
            Ok(Some(Write::Preset { channel, value }))
        }
        _ => Err(HostCommandError::NotWritable(name.to_string())),
    }
}

/// A preset's value by the datatype the host wrote it with (Int64 as the birth says; the
/// smaller integer types a host may use instead).
fn preset_value(m: &Metric) -> Option<i64> {
    let signed = matches!(m.datatype, Some(1..=4));
    match m.value {
        Some(Value::Long(v)) if signed || m.datatype.is_none() => Some(v as i64),
        Some(Value::Long(v)) => i64::try_from(v).ok(),
        Some(Value::Int(v)) if signed => Some(i64::from(v as i32)),
        Some(Value::Int(v)) => Some(i64::from(v)),
        _ => None,
    }
}

/// A STATE payload: 3.0's JSON `{"online": bool, "timestamp": ms}`, or 2.2's `ONLINE` /
/// `OFFLINE`. `None` for anything else.
pub fn host_online(payload: &[u8]) -> Option<bool> {
    match payload {
        b"ONLINE" => return Some(true),
        b"OFFLINE" => return Some(false),
        _ => {}
    }
    if payload.len() > 1024 {
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(payload).ok()?;
    v.get("online")?.as_bool()
}

/// A command payload carrying `metrics` (for tests).
#[cfg(test)]
pub fn dcmd(metrics: Vec<Metric>) -> Vec<u8> {
    Payload {
        timestamp: Some(0),
        metrics,
        ..Payload::default()
    }
    .encode()
}
