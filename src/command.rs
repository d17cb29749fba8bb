//! Clear and preset commands from MQTT. Pure: topic and payload in, a checked request or an error
//! result out; results as JSON. (The memory of recent ids is `dedupe.rs`.)
//!
//! Nothing here writes to a module: a request reaches a bus only after every check passed.

use serde_json::{Map, Value, json};

/// What the operator asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op {
    Clear,
    Preset(i64),
    ClearAll,
    /// Moves the channel's published meter reading to the meter's display; touches neither the
    /// module nor the total.
    SetReading(crate::decimal::Decimal),
}

impl Op {
    pub fn name(&self) -> &'static str {
        match self {
            Op::Clear => "clear",
            Op::Preset(_) => "preset",
            Op::ClearAll => "clear_all",
            Op::SetReading(_) => "set_reading",
        }
    }
}

/// A checked command, on its way to a bus.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    pub device: String,
    /// `None` for device-wide commands.
    pub channel: Option<String>,
    pub op: Op,
    pub id: Option<String>,
    /// Where the result goes: the result topic, plus the MQTT v5 response topic if given.
    pub reply: Reply,
    /// When the gateway received it.
    pub received: tokio::time::Instant,
    /// Give up (error `offline`) if the device has not answered by then.
    pub expires: tokio::time::Instant,
}

/// Where and how to answer.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Reply {
    /// The gateway's result topics (said by its own voice): the command topic's `/result`,
    /// then the MQTT v5 response topic, if any.
    pub topics: Vec<String>,
    pub correlation: Option<bytes::Bytes>,
    /// The connection the command came in on: its answer is said there.
    pub via: Option<Via>,
}

/// The connection (an output's, or the gateway's own) a command came in on, and, for a command
/// of an output's own protocol, what it wrote there: that output answers it in its own terms.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Via {
    pub output: std::sync::Arc<str>,
    pub wrote: Option<Written>,
}

/// What a command of an output's own protocol wrote: a device's metric (Sparkplug: `a0/Clear`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Written {
    pub device: String,
    pub metric: String,
}

/// Why a command was refused or failed; `code` goes in the result, the text is for people.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    #[error("payload is not a JSON object: {0}")]
    NotJson(String),
    #[error("missing \"op\"")]
    MissingOp,
    #[error(
        "unknown op {0:?}: use clear, preset or set_reading on a channel, clear_all on a device"
    )]
    UnknownOp(String),
    #[error("{0} needs \"value\"")]
    MissingValue(&'static str),
    #[error("\"value\" must be an integer, got {0}")]
    NotInteger(String),
    #[error("\"value\" {0} is outside the range of any counter (a 64-bit integer)")]
    ValueOutOfRange(String),
    #[error("\"value\" must be a decimal number such as \"12345.678\": {0}")]
    NotDecimal(String),
    #[error("channel {channel} has no scale: a meter reading is in its unit (set `scale`)")]
    NoScale { channel: String },
    #[error("{value} is outside the range of channel {channel}")]
    OutOfRange { channel: String, value: i64 },
    #[error("unexpected field {0:?}")]
    UnexpectedField(String),
    #[error("\"id\" must be a string")]
    BadId,
    #[error("no device {0}")]
    UnknownDevice(String),
    #[error("device {device} has no channel {channel}")]
    UnknownChannel { device: String, channel: String },
    #[error("commands are disabled for device {0}")]
    Disabled(String),
    #[error("device {0} did not answer before the command expired")]
    Offline(String),
    #[error("the write failed: {0}")]
    WriteFailed(String),
    #[error("read back {got} after the write, expected {expected}")]
    ReadBack { expected: i64, got: i64 },
    #[error("{what} is {size} bytes, more than the {limit} allowed")]
    TooLarge {
        what: &'static str,
        size: usize,
        limit: usize,
    },
    #[error("response topic refused: {0}")]
    BadResponseTopic(&'static str),
    #[error("device {device} is busy: {why}; try again later")]
    Busy { device: String, why: &'static str },
    /// The device's counts cannot be written (an M-Bus meter's registers).
    #[error("device {device} cannot be cleared or preset: {why}")]
    NotWritable { device: String, why: &'static str },
    /// Refused by the protocol it came in with before it became a command (a Sparkplug
    /// DCMD that cannot be read, a metric that cannot be written).
    #[error("{message}")]
    Protocol { code: &'static str, message: String },
}

impl CommandError {
    /// The machine-readable code in the result.
    pub fn code(&self) -> &'static str {
        match self {
            CommandError::NotJson(_) => "bad_json",
            CommandError::MissingOp => "missing_op",
            CommandError::UnknownOp(_) => "unknown_op",
            CommandError::MissingValue(_) => "missing_value",
            CommandError::NotInteger(_) => "bad_value",
            CommandError::ValueOutOfRange(_) => "out_of_range",
            CommandError::NotDecimal(_) => "bad_value",
            CommandError::NoScale { .. } => "no_scale",
            CommandError::OutOfRange { .. } => "out_of_range",
            CommandError::UnexpectedField(_) => "unexpected_field",
            CommandError::BadId => "bad_id",
            CommandError::UnknownDevice(_) => "unknown_device",
            CommandError::UnknownChannel { .. } => "unknown_channel",
            CommandError::Disabled(_) => "disabled",
            CommandError::Offline(_) => "offline",
            CommandError::WriteFailed(_) => "write_failed",
            CommandError::ReadBack { .. } => "readback_mismatch",
            CommandError::TooLarge { .. } => "too_large",
            CommandError::BadResponseTopic(_) => "bad_response_topic",
            CommandError::Busy { .. } => "busy",
            CommandError::NotWritable { .. } => "not_writable",
            CommandError::Protocol { code, .. } => code,
        }
    }
}

/// Longest command payload taken (a command is a few dozen bytes of JSON).
pub const MAX_PAYLOAD: usize = 1024;
/// Longest command `id` (bytes), so the dedupe memory and the echoed results stay small.
pub const MAX_ID: usize = 128;
/// Longest MQTT v5 response topic and correlation data taken (bytes).
pub const MAX_RESPONSE_TOPIC: usize = 256;
pub const MAX_CORRELATION: usize = 256;

/// Checks an MQTT v5 response topic before anything is published to it: a topic the gateway
/// could not publish to (a wildcard, empty, too long) would otherwise sit in the spool.
pub fn check_response_topic(topic: &str) -> Result<(), CommandError> {
    let bad = |why| Err(CommandError::BadResponseTopic(why));
    crate::topics::publishable(topic).map_err(CommandError::BadResponseTopic)?;
    if topic.len() > MAX_RESPONSE_TOPIC {
        return bad("it is longer than 256 bytes");
    }
    if topic.starts_with('$') {
        return bad("it starts with '$' (reserved for the broker)");
    }
    Ok(())
}

/// The parts of a payload before the device is known: op, id.
#[derive(Debug, Clone, PartialEq)]
pub struct Parsed {
    pub op: Op,
    pub id: Option<String>,
}

/// Parses a payload strictly: a JSON object with `op`, `value` for preset, optional string `id`,
/// nothing else. `channel` says whether it came on a channel or a device topic. On error the id,
/// when it could be read, is returned too so the result can echo it.
pub fn parse_payload(
    payload: &[u8],
    channel: bool,
) -> Result<Parsed, (Option<String>, CommandError)> {
    if payload.len() > MAX_PAYLOAD {
        return Err((
            None,
            CommandError::TooLarge {
                what: "the payload",
                size: payload.len(),
                limit: MAX_PAYLOAD,
            },
        ));
    }
    let value: Value = serde_json::from_slice(payload)
        .map_err(|e| (None, CommandError::NotJson(e.to_string())))?;
    let Value::Object(map) = value else {
        return Err((None, CommandError::NotJson("not an object".into())));
    };
    let id = match map.get("id") {
        None => None,
        Some(Value::String(s)) if s.len() <= MAX_ID => Some(s.clone()),
        Some(Value::String(s)) => {
            return Err((
                None,
                CommandError::TooLarge {
                    what: "\"id\"",
                    size: s.len(),
                    limit: MAX_ID,
                },
            ));
        }
        Some(_) => return Err((None, CommandError::BadId)),
    };
    let fail = |e| Err((id.clone(), e));
    let allowed: &[&str] = match map.get("op") {
        Some(Value::String(op)) if op == "preset" || op == "set_reading" => &["op", "id", "value"],
        _ => &["op", "id"],
    };
    if let Some(k) = map.keys().find(|k| !allowed.contains(&k.as_str())) {
        return fail(CommandError::UnexpectedField(k.clone()));
    }
    let op = match map.get("op") {
        None => return fail(CommandError::MissingOp),
        Some(Value::String(op)) => match (op.as_str(), channel) {
            ("clear", true) => Op::Clear,
            ("preset", true) => {
                Op::Preset(preset_value(&map, payload).map_err(|e| (id.clone(), e))?)
            }
            ("clear_all", false) => Op::ClearAll,
            ("set_reading", true) => {
                Op::SetReading(reading_value(&map).map_err(|e| (id.clone(), e))?)
            }
            _ => return fail(CommandError::UnknownOp(op.clone())),
        },
        Some(other) => return fail(CommandError::UnknownOp(other.to_string())),
    };
    Ok(Parsed { op, id })
}

fn preset_value(map: &Map<String, Value>, payload: &[u8]) -> Result<i64, CommandError> {
    match map.get("value") {
        None | Some(Value::Null) => Err(CommandError::MissingValue("preset")),
        Some(Value::Number(n)) => n.as_i64().ok_or_else(|| not_an_i64(n, payload)),
        Some(other) => Err(CommandError::NotInteger(other.to_string())),
    }
}

/// Why a JSON number is no count: an integer written out in digits that 64 bits cannot hold
/// (JSON keeps it only as a float, `1e+23`) is out of range; `1.5` or `1e30` is not an integer.
fn not_an_i64(n: &serde_json::Number, payload: &[u8]) -> CommandError {
    let raw: Option<std::collections::BTreeMap<String, Box<serde_json::value::RawValue>>> =
        serde_json::from_slice(payload).ok();
    let written = raw
        .as_ref()
        .and_then(|m| m.get("value"))
        .map(|v| v.get().trim().to_string());
    let digits = written.as_deref().is_some_and(|w| {
        let w = w.strip_prefix('-').unwrap_or(w);
        !w.is_empty() && w.bytes().all(|b| b.is_ascii_digit())
    });
    match written {
        Some(w) if digits => CommandError::ValueOutOfRange(w),
        _ => CommandError::NotInteger(n.to_string()),
    }
}

/// `value` of a set_reading: decimal text or a JSON number, taken exactly as written.
fn reading_value(map: &Map<String, Value>) -> Result<crate::decimal::Decimal, CommandError> {
    let text = match map.get("value") {
        None | Some(Value::Null) => return Err(CommandError::MissingValue("set_reading")),
        Some(Value::String(s)) => s.clone(),
        Some(Value::Number(n)) => n.to_string(),
        Some(other) => return Err(CommandError::NotDecimal(other.to_string())),
    };
    crate::decimal::Decimal::parse(&text).map_err(|e| CommandError::NotDecimal(e.to_string()))
}

/// The result JSON of a command.
pub fn result_json(
    id: Option<&str>,
    op: Option<&str>,
    outcome: &Result<Option<i64>, CommandError>,
) -> Value {
    let mut v = json!({});
    if let Some(id) = id {
        v["id"] = json!(id);
    }
    if let Some(op) = op {
        v["op"] = json!(op);
    }
    match outcome {
        Ok(count) => {
            v["ok"] = json!(true);
            if let Some(c) = count {
                v["count"] = json!(c);
            }
        }
        Err(e) => {
            v["ok"] = json!(false);
            v["error"] = json!(e.code());
            v["message"] = json!(e.to_string());
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(payload: &str, channel: bool) -> &'static str {
        parse_payload(payload.as_bytes(), channel)
            .unwrap_err()
            .1
            .code()
    }

    #[test]
    fn set_reading_takes_decimal_text_or_a_number_exactly_as_written() {
        use crate::decimal::Decimal;
        let d = |t| Op::SetReading(Decimal::parse(t).unwrap());
        let text = br#"{"op":"set_reading","value":"12345.678","id":"swap"}"#;
        let p = parse_payload(text, true).unwrap();
        assert_eq!((p.op, p.id.as_deref()), (d("12345.678"), Some("swap")));
        let number = br#"{"op":"set_reading","value":12345.678}"#;
        assert_eq!(parse_payload(number, true).unwrap().op, d("12345.678"));
        assert_eq!(d("12345.678").name(), "set_reading");
    }

    #[test]
    fn set_reading_refuses_what_is_not_a_reading_and_is_not_a_device_command() {
        for (payload, code) in [
            (&br#"{"op":"set_reading"}"#[..], "missing_value"),
            (br#"{"op":"set_reading","value":"12,5"}"#, "bad_value"),
            (br#"{"op":"set_reading","value":"1e99"}"#, "bad_value"),
            (br#"{"op":"set_reading","value":true}"#, "bad_value"),
            (
                br#"{"op":"set_reading","value":"1","scale":2}"#,
                "unexpected_field",
            ),
        ] {
            let (_, e) = parse_payload(payload, true).unwrap_err();
            assert_eq!(e.code(), code, "{}", String::from_utf8_lossy(payload));
        }
        let device_wide = br#"{"op":"set_reading","value":"1"}"#;
        assert_eq!(
            parse_payload(device_wide, false).unwrap_err().1.code(),
            "unknown_op"
        );
    }

    #[test]
    fn clear_and_preset_parse_on_a_channel() {
        assert_eq!(
            parse_payload(br#"{"op":"clear"}"#, true).unwrap().op,
            Op::Clear
        );
        let p = parse_payload(br#"{"op":"preset","value":3000,"id":"a1"}"#, true).unwrap();
        assert_eq!((p.op, p.id.as_deref()), (Op::Preset(3000), Some("a1")));
        assert_eq!(
            parse_payload(br#"{"op":"preset","value":-5}"#, true)
                .unwrap()
                .op,
            Op::Preset(-5)
        );
    }

    #[test]
    fn clear_all_is_only_for_the_device_topic() {
        assert_eq!(
            parse_payload(br#"{"op":"clear_all"}"#, false).unwrap().op,
            Op::ClearAll
        );
        assert_eq!(err(r#"{"op":"clear_all"}"#, true), "unknown_op");
        assert_eq!(err(r#"{"op":"clear"}"#, false), "unknown_op");
    }

    #[test]
    fn malformed_payloads_get_a_code_naming_the_cause() {
        assert_eq!(err("clear", true), "bad_json");
        assert_eq!(err("[1]", true), "bad_json");
        assert_eq!(err("{}", true), "missing_op");
        assert_eq!(err(r#"{"op":"explode"}"#, true), "unknown_op");
        assert_eq!(err(r#"{"op":7}"#, true), "unknown_op");
        assert_eq!(err(r#"{"op":"preset"}"#, true), "missing_value");
        assert_eq!(err(r#"{"op":"preset","value":1.5}"#, true), "bad_value");
        assert_eq!(err(r#"{"op":"preset","value":"3000"}"#, true), "bad_value");
        assert_eq!(err(r#"{"op":"preset","value":1e30}"#, true), "bad_value");
        assert_eq!(
            err(r#"{"op":"preset","value":99999999999999999999999}"#, true),
            "out_of_range"
        );
        assert_eq!(
            err(r#"{"op":"preset","value":-9223372036854775809}"#, true),
            "out_of_range"
        );
        assert_eq!(
            err(r#"{"op":"set_reading","value":null}"#, true),
            "missing_value"
        );
        assert_eq!(err(r#"{"op":"clear","value":5}"#, true), "unexpected_field");
        assert_eq!(err(r#"{"op":"clear","id":5}"#, true), "bad_id");
    }

    #[test]
    fn a_missing_value_names_the_op_that_needs_it() {
        let (_, e) = parse_payload(br#"{"op":"set_reading","value":null}"#, true).unwrap_err();
        assert_eq!(e.to_string(), "set_reading needs \"value\"");
        let (_, e) = parse_payload(br#"{"op":"preset"}"#, true).unwrap_err();
        assert_eq!(e.to_string(), "preset needs \"value\"");
    }

    #[test]
    fn an_error_result_echoes_the_id_when_it_could_be_read() {
        let (id, e) = parse_payload(br#"{"op":"preset","id":"x9"}"#, true).unwrap_err();
        let v = result_json(id.as_deref(), Some("preset"), &Err(e));
        assert_eq!(v["id"], "x9");
        assert_eq!(v["ok"], false);
        assert_eq!(v["error"], "missing_value");
        assert!(v["message"].as_str().unwrap().contains("value"));
    }

    #[test]
    fn an_ok_result_carries_the_count_read_back() {
        let v = result_json(Some("a"), Some("preset"), &Ok(Some(3000)));
        assert_eq!(v, json!({"id":"a","op":"preset","ok":true,"count":3000}));
    }

    #[test]
    fn oversized_payloads_and_ids_are_refused_before_parsing() {
        let big = format!(r#"{{"op":"clear","pad":"{}"}}"#, "a".repeat(11 * 1024));
        assert_eq!(err(&big, true), "too_large");
        let id = format!(r#"{{"op":"clear","id":"{}"}}"#, "i".repeat(200));
        let (echo, e) = parse_payload(id.as_bytes(), true).unwrap_err();
        assert_eq!((echo, e.code()), (None, "too_large"));
    }

    #[test]
    fn response_topics_with_wildcards_or_no_length_limit_are_refused() {
        for bad in ["evil/#", "a/+/b", "", "$SYS/x", "a\0b"] {
            assert_eq!(
                check_response_topic(bad).unwrap_err().code(),
                "bad_response_topic",
                "{bad:?}"
            );
        }
        assert!(check_response_topic(&"a".repeat(300)).is_err());
        assert!(check_response_topic("app/replies/42").is_ok());
    }
}

#[cfg(test)]
mod fuzz {
    use super::*;

    /// Ten thousand random and mutated payloads: the parser answers each with a result and never
    /// panics.
    #[test]
    fn the_parser_never_panics_on_arbitrary_bytes() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let base = br#"{"op":"preset","value":-2147483648,"id":"\u00e9"}"#;
        for _ in 0..10_000 {
            let mut p = base.to_vec();
            for _ in 0..next() % 6 {
                let i = (next() as usize) % p.len();
                p[i] = next() as u8;
            }
            p.truncate((next() as usize) % (p.len() + 1));
            for channel in [true, false] {
                let r = parse_payload(&p, channel);
                let json = match &r {
                    Ok(parsed) => {
                        result_json(parsed.id.as_deref(), Some(parsed.op.name()), &Ok(None))
                    }
                    Err((id, e)) => result_json(id.as_deref(), None, &Err(e.clone())),
                };
                assert!(json.get("ok").is_some());
            }
        }
    }
}
