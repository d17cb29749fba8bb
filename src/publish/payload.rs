//! JSON payloads. Pure.

use serde::Serialize;

use crate::counter::Event;
use crate::reading::Reading;

/// The JSON of one reading.
#[derive(Debug, Serialize)]
struct ReadingJson {
    ts: String,
    count: i64,
    delta: i64,
    total: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    rate_hz: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    freq_hz: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rpm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    event: Option<Event>,
    seq: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    after_seq: Option<u64>,
}

/// Rounds to 3 decimals so payloads stay short and stable.
fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// `{"ts":"2026-11-21T22:38:43.123Z","count":-13680,…,"seq":42}`
pub fn reading(r: &Reading) -> String {
    let json = ReadingJson {
        ts: humantime::format_rfc3339_millis(r.ts).to_string(),
        count: r.count,
        delta: r.update.delta,
        total: r.update.total,
        rate_hz: r.update.rate_hz.map(round3),
        freq_hz: r.freq_hz.map(round3),
        rpm: r.rpm.map(round3),
        event: r.update.event,
        seq: r.update.seq,
        after_seq: r.after_seq,
    };
    serde_json::to_string(&json).expect("reading serializes")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::counter::Update;
    use std::time::{Duration, SystemTime};

    #[test]
    fn a_reading_has_the_documented_shape() {
        let r = Reading {
            device: "press1".into(),
            channel: "enc0".into(),
            ts: SystemTime::UNIX_EPOCH + Duration::from_millis(1_795_300_723_123),
            count: -13680,
            freq_hz: Some(1000.0),
            rpm: Some(60.0),
            update: Update {
                delta: 5,
                total: 10,
                seq: 42,
                rate_hz: Some(999.9996),
                event: Some(Event::Rollover),
            },
            after_seq: None,
        };
        let v: serde_json::Value = serde_json::from_str(&reading(&r)).unwrap();
        assert_eq!(v["ts"], "2026-11-21T22:38:43.123Z");
        assert_eq!(v["count"], -13680);
        assert_eq!(v["freq_hz"], 1000.0);
        assert_eq!(v["rpm"], 60.0);
        assert_eq!(v["rate_hz"], 1000.0);
        assert_eq!(v["event"], "rollover");
        assert_eq!(v["seq"], 42);
    }

    #[test]
    fn absent_values_are_left_out() {
        let r = Reading {
            device: "d".into(),
            channel: "a0".into(),
            ts: SystemTime::UNIX_EPOCH,
            count: 4_294_953_616,
            freq_hz: None,
            rpm: None,
            update: Update {
                delta: 0,
                total: 0,
                seq: 1,
                rate_hz: None,
                event: None,
            },
            after_seq: None,
        };
        let v: serde_json::Value = serde_json::from_str(&reading(&r)).unwrap();
        assert_eq!(v["count"], 4_294_953_616u64);
        assert!(v.get("freq_hz").is_none() && v.get("event").is_none());
    }
}
