//! `pulsegate verify`: captured records judged one by one (valid, tampered) and as a sequence
//! (a seq skipped is missing). Lines as `mosquitto_sub -v` prints them (`topic payload`) or
//! plain JSON; the key is given or taken from a captured `<root>/gateway` marker. The judging
//! is a state machine without I/O; [`capture`] is the shell that reads a topic from the broker.

use std::collections::HashMap;
use std::fmt;
use std::time::Duration;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde_json::{Map, Value};

use crate::config::Config;
use crate::publish::session::Event;
use crate::publish::signed::{Verdict, check};

/// What one captured line says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Finding {
    /// A record whose signature and fields hold.
    Valid { what: String },
    /// A record that is not what the gateway signed.
    Tampered { what: String, why: String },
    /// Records of a sequence that were not captured: `from..=to` skipped before `what`.
    Missing { what: String, from: u64, to: u64 },
    /// A record seen before any key: nothing to check it against.
    NoKey { what: String },
    /// The gateway's public key, taken from its marker.
    Key(String),
}

impl Finding {
    /// Whether the capture is not what the gateway signed.
    pub fn is_bad(&self) -> bool {
        !matches!(self, Finding::Valid { .. } | Finding::Key(_))
    }
}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Finding::Valid { what } => write!(f, "valid     {what}"),
            Finding::Tampered { what, why } => write!(f, "tampered  {what}: {why}"),
            Finding::Missing { what, from, to } if from == to => {
                write!(f, "missing   {what}: seq {from} was not captured")
            }
            Finding::Missing { what, from, to } => {
                write!(f, "missing   {what}: seq {from} to {to} were not captured")
            }
            Finding::NoKey { what } => write!(f, "unchecked {what}: no key (give --key)"),
            Finding::Key(k) => write!(f, "key       {k} (from the gateway's marker)"),
        }
    }
}

/// The judge of a capture, line by line.
#[derive(Debug, Default)]
pub struct Verifier {
    key: Option<[u8; 32]>,
    /// The last seq seen of each sequence (record, gateway, device, channel, period).
    last: HashMap<String, u64>,
}

/// A base64 public key of 32 bytes.
pub fn parse_key(text: &str) -> Result<[u8; 32], String> {
    let bytes = STANDARD
        .decode(text.trim())
        .map_err(|e| format!("the key is not base64: {e}"))?;
    bytes
        .try_into()
        .map_err(|b: Vec<u8>| format!("the key has {} bytes, not 32", b.len()))
}

impl Verifier {
    /// A verifier with the gateway's public key, or one that waits for its marker.
    pub fn new(key: Option<[u8; 32]>) -> Verifier {
        Verifier {
            key,
            last: HashMap::new(),
        }
    }

    /// What a captured line says (nothing for lines that are not records).
    pub fn line(&mut self, line: &str) -> Vec<Finding> {
        let Some(brace) = line.find('{') else {
            return Vec::new();
        };
        let topic = Some(line[..brace].trim()).filter(|t| !t.is_empty());
        let Ok(Value::Object(json)) = serde_json::from_str::<Value>(&line[brace..]) else {
            return Vec::new();
        };
        if json.contains_key("boot") {
            return self.marker(&json);
        }
        let is_record = topic.is_some_and(|t| t.ends_with("/billing") || t.contains("/interval/"));
        if !json.contains_key("signed") && !is_record {
            return Vec::new();
        }
        self.record(topic, &json)
    }

    fn marker(&mut self, json: &Map<String, Value>) -> Vec<Finding> {
        let Some(text) = json.get("signing_key").and_then(Value::as_str) else {
            return Vec::new();
        };
        match (self.key, parse_key(text)) {
            (None, Ok(k)) => {
                self.key = Some(k);
                vec![Finding::Key(text.to_string())]
            }
            _ => Vec::new(),
        }
    }

    fn record(&mut self, topic: Option<&str>, json: &Map<String, Value>) -> Vec<Finding> {
        let seq = json.get("seq").and_then(Value::as_u64);
        let Some(key) = self.key else {
            let what = describe(topic, None, seq);
            return vec![Finding::NoKey { what }];
        };
        let checked = check(&key, topic, json);
        let what = describe(topic, checked.origin.as_ref(), seq);
        if let Verdict::Tampered(why) = checked.verdict {
            return vec![Finding::Tampered { what, why }];
        }
        let mut out = Vec::new();
        if let (Some(o), Some(seq)) = (&checked.origin, seq) {
            let stream = [&o.record, &o.gateway, &o.device, &o.channel, &o.period];
            let stream = stream.map(|s| s.as_str()).join("\u{0}");
            match self.last.insert(stream, seq) {
                Some(last) if seq > last + 1 => out.push(Finding::Missing {
                    what: what.clone(),
                    from: last + 1,
                    to: seq - 1,
                }),
                _ => {}
            }
        }
        out.push(Finding::Valid { what });
        out
    }
}

/// What every line of a capture says, the key taken from a marker anywhere in it when none is
/// given (a retained record may come before the retained marker).
pub fn judge_all(key: Option<[u8; 32]>, lines: &[String]) -> Vec<Finding> {
    let mut out = Vec::new();
    let mut v = Verifier::new(key);
    if key.is_none() {
        for line in lines.iter().filter(|l| l.contains("\"boot\"")) {
            out.extend(v.line(line));
        }
    }
    for line in lines.iter().filter(|l| !l.contains("\"boot\"")) {
        out.extend(v.line(line));
    }
    out
}

/// `m1/a0 interval 15min seq 17`, or the topic when the text names nothing.
fn describe(
    topic: Option<&str>,
    origin: Option<&crate::publish::signed::Origin>,
    seq: Option<u64>,
) -> String {
    let seq = seq.map_or("no seq".to_string(), |s| format!("seq {s}"));
    match origin {
        Some(o) => format!("{}/{} {} {} {seq}", o.device, o.channel, o.record, o.period),
        None => format!("{} {seq}", topic.unwrap_or("a record")),
    }
}

/// Why records could not be read from the broker.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("{0}")]
    Tls(#[from] crate::config::tls::TlsError),
    #[error("MQTT broker {broker}: {why}")]
    Broker { broker: String, why: String },
}

/// The messages on `topic` (and the gateway's marker) for `seconds`, as `topic payload` lines.
pub async fn capture(
    config: &Config,
    topic: &str,
    seconds: Duration,
) -> Result<Vec<String>, CaptureError> {
    let m = &config.mqtt;
    let id = format!("{}-verify-{}", m.client_id, std::process::id());
    let options = crate::publish::session::client_options_as(m, &id)?;
    let broker = |why: String| CaptureError::Broker {
        broker: m.broker(),
        why,
    };
    let (client, mut events) = options.connect(None, 16);
    let marker = crate::topics::Topics::new(&m.topic_root).gateway_marker();
    for t in [marker, topic.to_string()] {
        client.subscribe(t).map_err(|e| broker(e.to_string()))?;
    }
    let mut lines = Vec::new();
    let until = tokio::time::Instant::now() + seconds;
    while let Ok(event) = tokio::time::timeout_at(until, events.poll()).await {
        match event {
            Ok(Event::Received(r)) => lines.push(format!(
                "{} {}",
                String::from_utf8_lossy(&r.topic),
                String::from_utf8_lossy(&r.payload)
            )),
            Ok(_) => {}
            Err(e) => return Err(broker(format!("{e:?}"))),
        }
    }
    let _ = client.disconnect();
    Ok(lines)
}

#[cfg(test)]
#[path = "verify_tests.rs"]
mod tests;
