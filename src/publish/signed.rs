//! Signed records: the exact text an interval or billing record's signature covers, the
//! signature added to its JSON (`"signed"`, `"sig"`), and the check of one captured record.
//! Pure. The text is documented in docs/metering.md so that openssl alone can check it.
//!
//! The text is `key=value` lines, each ended by one `\n` (0x0A): the version line, then who
//! (`record`, `gateway`, `device`, `channel`, `period`), then the fixed fields (`start`, `end`,
//! `seq`, `total_start`, `total_end`, `delta`, `unit`, `status`, `tariff`; empty when the
//! record has none), then every other field of the JSON in the order of its name, objects
//! flattened with dots (`by_tariff.peak=…`, `demand.value=…`), lists as their JSON text.

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde_json::{Map, Value};

use std::sync::Arc;

use crate::config::Config;
use crate::metering::billing::Cycle;
use crate::reading::IntervalRecord;
use crate::signing::SigningKey;

/// The first line of the text: the version of this format.
pub const DOMAIN: &str = "pulsegate-record-v1";

/// The fields every text names, in this order, after who the record is of.
const FIXED: [&str; 9] = [
    "start",
    "end",
    "seq",
    "total_start",
    "total_end",
    "delta",
    "unit",
    "status",
    "tariff",
];

/// The fields of the JSON that are the signature itself.
const PROOF: [&str; 2] = ["signed", "sig"];

/// Whose record it is: what the topic says and the JSON does not.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Origin {
    /// `interval` or `billing`.
    pub record: String,
    pub gateway: String,
    pub device: String,
    pub channel: String,
    /// The interval (`15min`) or the billing cycle (`daily`, `monthly`).
    pub period: String,
}

impl Origin {
    fn lines(&self) -> [(&'static str, &str); 5] {
        [
            ("record", &self.record),
            ("gateway", &self.gateway),
            ("device", &self.device),
            ("channel", &self.channel),
            ("period", &self.period),
        ]
    }

    /// The origin a text names (the second to sixth lines).
    fn of_text(text: &str) -> Option<Origin> {
        let mut lines = text.lines();
        if lines.next()? != DOMAIN {
            return None;
        }
        let mut take = |key: &str| {
            let line = lines.next()?;
            line.strip_prefix(key)?.strip_prefix('=').map(unescape)
        };
        Some(Origin {
            record: take("record")?,
            gateway: take("gateway")?,
            device: take("device")?,
            channel: take("channel")?,
            period: take("period")?,
        })
    }
}

/// A line break or a backslash in a value is written `\n` or `\\`, so every field is one line.
fn escape(v: &str) -> String {
    v.replace('\\', "\\\\").replace('\n', "\\n")
}

fn unescape(v: &str) -> String {
    v.replace("\\n", "\n").replace("\\\\", "\\")
}

/// A value as its line writes it: a string as it is, a number as its JSON text, nothing as "".
fn scalar(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Null => String::new(),
        other => other.to_string(),
    }
}

/// The fields of `map` in the order of their names (whatever order the map keeps), inner
/// objects' fields under `prefix.`.
fn flatten(prefix: &str, map: &Map<String, Value>, out: &mut Vec<(String, String)>) {
    let mut fields: Vec<(&String, &Value)> = map.iter().collect();
    fields.sort_by(|a, b| a.0.cmp(b.0));
    for (k, v) in fields {
        let top = prefix.is_empty();
        if top && (FIXED.contains(&k.as_str()) || PROOF.contains(&k.as_str())) {
            continue;
        }
        let key = if top {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            Value::Object(inner) => flatten(&key, inner, out),
            other => out.push((key, scalar(other))),
        }
    }
}

/// The signed text of a record of `origin` whose JSON object is `json`.
pub fn text(origin: &Origin, json: &Map<String, Value>) -> String {
    let mut out = format!("{DOMAIN}\n");
    let mut line = |k: &str, v: &str| out.push_str(&format!("{k}={}\n", escape(v)));
    for (k, v) in origin.lines() {
        line(k, v);
    }
    for k in FIXED {
        line(k, &json.get(k).map(scalar).unwrap_or_default());
    }
    let mut rest = Vec::new();
    flatten("", json, &mut rest);
    for (k, v) in rest {
        line(&k, &v);
    }
    out
}

/// `json` (a record's JSON object) with `"signed"` and `"sig"` added: the text of it and its
/// signature by `key`, both base64.
pub fn sign(key: &SigningKey, origin: &Origin, json: String) -> String {
    let Ok(Value::Object(map)) = serde_json::from_str::<Value>(&json) else {
        return json;
    };
    let text = text(origin, &map);
    let sig = key.sign(text.as_bytes());
    let Some(body) = json.trim_end().strip_suffix('}') else {
        return json;
    };
    let sep = if map.is_empty() { "" } else { "," };
    format!(
        "{body}{sep}\"signed\":\"{}\",\"sig\":\"{sig}\"}}",
        STANDARD.encode(&text)
    )
}

/// The gateway's signer of records (`[billing] signing_key`): the key read when the config was
/// checked, the gateway id and the billing cycle the texts name.
#[derive(Debug, Clone)]
pub struct Signer {
    key: Arc<SigningKey>,
    gateway: String,
    cycle: &'static str,
}

impl Signer {
    /// The signer `config` asks for, if any.
    pub fn of(config: &Config) -> Option<Signer> {
        let billing = config.gateway.billing.as_deref()?;
        Some(Signer {
            key: billing.signer.clone()?,
            gateway: config.gateway.id.clone(),
            cycle: match billing.cycle {
                Cycle::Daily => "daily",
                Cycle::Monthly { .. } => "monthly",
            },
        })
    }

    fn origin(&self, record: &str, i: &IntervalRecord, period: &str) -> Origin {
        Origin {
            record: record.into(),
            gateway: self.gateway.clone(),
            device: i.device.to_string(),
            channel: i.channel.to_string(),
            period: period.into(),
        }
    }

    /// Interval record `i`'s JSON, signed.
    pub fn interval(&self, i: &IntervalRecord, json: String) -> String {
        sign(&self.key, &self.origin("interval", i, &i.period), json)
    }

    /// A billing record's JSON of `i`'s channel, signed.
    pub fn billing(&self, i: &IntervalRecord, json: String) -> String {
        sign(&self.key, &self.origin("billing", i, self.cycle), json)
    }
}

/// What a captured record is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Its signature verifies and its fields are the ones signed.
    Valid,
    /// Why it is not what was signed.
    Tampered(String),
}

/// A captured record judged: whose it is (when its text says) and its verdict.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Checked {
    pub origin: Option<Origin>,
    pub seq: Option<u64>,
    pub verdict: Verdict,
}

/// Checks `json` (a record as captured, on `topic` when known) against the raw `public` key.
pub fn check(public: &[u8; 32], topic: Option<&str>, json: &Map<String, Value>) -> Checked {
    let seq = json.get("seq").and_then(Value::as_u64);
    let text = json
        .get("signed")
        .and_then(Value::as_str)
        .and_then(|s| STANDARD.decode(s).ok())
        .and_then(|b| String::from_utf8(b).ok());
    let origin = text.as_deref().and_then(Origin::of_text);
    let verdict = judge(public, topic, json, text.as_deref(), origin.as_ref());
    Checked {
        origin,
        seq,
        verdict,
    }
}

fn judge(
    public: &[u8; 32],
    topic: Option<&str>,
    json: &Map<String, Value>,
    text: Option<&str>,
    origin: Option<&Origin>,
) -> Verdict {
    let tampered = |why: &str| Verdict::Tampered(why.to_string());
    let (Some(text), Some(sig)) = (text, json.get("sig").and_then(Value::as_str)) else {
        return tampered("not signed (no \"signed\" and \"sig\")");
    };
    if !crate::signing::verifies(public, text.as_bytes(), sig) {
        return tampered("the signature does not verify with the gateway's key");
    }
    let Some(origin) = origin else {
        return tampered("the signed text is not a pulsegate-record-v1 text");
    };
    let again = self::text(origin, json);
    if let Some((want, got)) = text.lines().zip(again.lines()).find(|(a, b)| a != b) {
        return Verdict::Tampered(format!("signed {want:?}, the record says {got:?}"));
    }
    if again != text {
        return tampered("the record has fields the signed text does not, or lacks some");
    }
    if let Some(topic) = topic.filter(|t| !on_its_topic(t, origin)) {
        return Verdict::Tampered(format!(
            "signed for {}/{}, found on {topic}",
            origin.device, origin.channel
        ));
    }
    Verdict::Valid
}

/// Whether `topic` is where a record of `origin` is published.
fn on_its_topic(topic: &str, o: &Origin) -> bool {
    let tail = match o.record.as_str() {
        "billing" => format!("/{}/{}/billing", o.device, o.channel),
        _ => format!("/{}/{}/interval/{}", o.device, o.channel, o.period),
    };
    topic.ends_with(&tail)
}

#[cfg(test)]
#[path = "signed_tests.rs"]
mod tests;
