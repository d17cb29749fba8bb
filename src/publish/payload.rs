//! JSON payloads. Pure.

use std::collections::BTreeMap;

use serde::Serialize;
use serde_json::value::RawValue;

use crate::event::Event;
use crate::reading::{IntervalRecord, Reading};

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
    /// The scaled total: a JSON number whose text is exactly `total × scale`.
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<Box<RawValue>>,
    /// The scaled rate, per the channel's `rate_per`.
    #[serde(skip_serializing_if = "Option::is_none")]
    rate: Option<f64>,
    /// The meter reading: the scaled total plus the offset `set_reading` gave it.
    #[serde(skip_serializing_if = "Option::is_none")]
    reading: Option<Box<RawValue>>,
    /// When `set_reading` last moved the reading (its sensor's `last_reset`).
    #[serde(skip_serializing_if = "Option::is_none")]
    reading_since: Option<String>,
    /// The unit of `value` and `reading`.
    #[serde(skip_serializing_if = "Option::is_none")]
    unit: Option<String>,
    /// The channel's OBIS name (`obis` in its config).
    #[serde(skip_serializing_if = "Option::is_none")]
    obis: Option<String>,
}

/// The JSON of a gauge's reading: its value (an exact decimal, a number or text) in its unit.
#[derive(Debug, Serialize)]
struct GaugeJson {
    ts: String,
    value: Box<RawValue>,
    #[serde(skip_serializing_if = "Option::is_none")]
    unit: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    obis: Option<String>,
}

/// A count's or a gauge's JSON.
#[derive(Debug, Serialize)]
#[serde(untagged)]
enum AnyJson {
    Count(ReadingJson),
    Gauge(GaugeJson),
}

/// The JSON of one interval record.
#[derive(Debug, Serialize)]
struct IntervalJson {
    start: String,
    end: String,
    delta: i64,
    /// The scaled delta: a JSON number whose text is exactly `delta × scale`.
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<Box<RawValue>>,
    total_start: i64,
    total_end: i64,
    read_lag_ms: Lags,
    status: crate::metering::Status,
    seq: u64,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    events: Vec<Event>,
    /// The tariff the record is booked to, and every tariff it spanned when more than one.
    #[serde(skip_serializing_if = "Option::is_none")]
    tariff: Option<String>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    tariffs: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    obis: Option<String>,
}

/// How long after each boundary its read was.
#[derive(Debug, Serialize)]
struct Lags {
    start: i64,
    end: i64,
}

/// `{"start":"2026-12-02T17:15:00Z","end":"2026-12-02T17:30:00Z","delta":120,…}`
pub fn interval(i: &IntervalRecord) -> String {
    use crate::metering::clock::iso;
    let r = &i.record;
    let value = i
        .units
        .as_deref()
        .and_then(|u| crate::config::units::value(u, r.delta))
        .and_then(|v| RawValue::from_string(v.to_string()).ok());
    let json = IntervalJson {
        start: iso(r.start_ms),
        end: iso(r.end_ms),
        delta: r.delta,
        value,
        total_start: r.total_start,
        total_end: r.total_end,
        read_lag_ms: Lags {
            start: r.lag_start_ms,
            end: r.lag_end_ms,
        },
        status: r.status,
        seq: r.seq,
        events: r.events.clone(),
        tariff: r.booking.as_ref().and_then(|b| b.tariff.clone()),
        tariffs: r
            .booking
            .as_ref()
            .map(|b| b.tariffs.clone())
            .unwrap_or_default(),
        obis: obis(i.units.as_deref()),
    };
    serde_json::to_string(&json).expect("record serializes")
}

/// The OBIS name of a channel with these units, as text.
pub(crate) fn obis(units: Option<&crate::config::units::ChannelUnits>) -> Option<String> {
    units?.obis.map(|o| o.to_string())
}

/// Rounds to 3 decimals so payloads stay short and stable.
pub(crate) fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// `{"ts":"2026-11-21T22:38:43.123Z","count":-13680,…,"seq":42}`
pub fn reading(r: &Reading) -> String {
    serde_json::to_string(&json_of(r)).expect("reading serializes")
}

/// `{"a0":{…reading…},"a1":{…}}`: the readings of one poll of a device, keyed by channel.
pub fn device(readings: &[Reading]) -> String {
    let map: BTreeMap<&str, AnyJson> = readings.iter().map(|r| (&*r.channel, json_of(r))).collect();
    serde_json::to_string(&map).expect("readings serialize")
}

fn json_of(r: &Reading) -> AnyJson {
    match &r.measured {
        Some(m) => AnyJson::Gauge(GaugeJson {
            ts: humantime::format_rfc3339_millis(r.ts).to_string(),
            value: measure_json(m),
            unit: r.units.as_deref().and_then(|u| u.unit.clone()),
            obis: obis(r.units.as_deref()),
        }),
        None => AnyJson::Count(count_json(r)),
    }
}

/// A gauge's value: an exact decimal as a JSON number with its exact text, a real as a
/// number, text as a string.
fn measure_json(m: &crate::reading::Measure) -> Box<RawValue> {
    use crate::reading::Measure;
    let text = match m {
        Measure::Exact(d) => d.to_string(),
        Measure::Real(v) if v.is_finite() => serde_json::to_string(v).unwrap_or_default(),
        Measure::Real(_) => "null".into(),
        Measure::Text(t) => serde_json::to_string(&**t).unwrap_or_default(),
    };
    RawValue::from_string(text)
        .unwrap_or_else(|_| RawValue::from_string("null".into()).expect("null is JSON"))
}

fn count_json(r: &Reading) -> ReadingJson {
    let units = r.units.as_deref();
    let value = units
        .and_then(|u| crate::config::units::value(u, r.update.total))
        .and_then(|v| RawValue::from_string(v.to_string()).ok());
    let rate = units.and_then(|u| crate::config::units::rate(u, r.update.rate_hz?));
    let reading = units
        .and_then(|u| u.scale)
        .and_then(|s| crate::metering::meter::reading(&s, r.update.total, r.meter.as_ref()))
        .and_then(|v| RawValue::from_string(v.to_string()).ok());
    let reading_since = r
        .meter
        .as_ref()
        .filter(|_| reading.is_some())
        .map(|m| crate::metering::clock::iso(m.since_ms));
    ReadingJson {
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
        value,
        rate,
        reading,
        reading_since,
        unit: units
            .filter(|u| u.scale.is_some())
            .and_then(|u| u.unit.clone()),
        obis: obis(units),
    }
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
            meter: None,
            kind: crate::profile::ChannelKind::Encoder,
            units: None,
            measured: None,
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
            meter: None,
            kind: crate::profile::ChannelKind::Encoder,
            units: None,
            measured: None,
        };
        let v: serde_json::Value = serde_json::from_str(&reading(&r)).unwrap();
        assert_eq!(v["count"], 4_294_953_616u64);
        assert!(v.get("freq_hz").is_none() && v.get("event").is_none());
        assert!(v.get("value").is_none() && v.get("rate").is_none());
    }

    fn metered(total: i64, scale: &str, rate_hz: f64) -> Reading {
        use crate::config::units::ChannelUnits;
        use crate::config::units::RatePer;
        use crate::decimal::Decimal;
        Reading {
            device: "meter".into(),
            channel: "a0".into(),
            ts: SystemTime::UNIX_EPOCH,
            count: total,
            freq_hz: None,
            rpm: None,
            update: Update {
                delta: 1,
                total,
                seq: 1,
                rate_hz: Some(rate_hz),
                event: None,
            },
            kind: crate::profile::ChannelKind::Counter,
            units: Some(std::sync::Arc::new(ChannelUnits {
                scale: Some(Decimal::parse(scale).unwrap()),
                rate_per: RatePer::Hour,
                ..Default::default()
            })),
            after_seq: None,
            meter: None,
            measured: None,
        }
    }

    #[test]
    fn a_scaled_total_is_exact_decimal_text_in_the_payload() {
        let text = reading(&metered(1_234_567, "0.001", 1.0));
        assert!(text.contains(r#""value":1234.567,"#), "{text}");
        assert!(text.contains(r#""rate":3.6"#), "{text}");
        assert!(
            text.contains(r#""total":1234567"#),
            "raw fields stay: {text}"
        );
        let text = reading(&metered(3, "0.1", 0.0));
        assert!(text.contains(r#""value":0.3,"#), "{text}");
    }

    #[test]
    fn a_device_payload_keys_each_reading_by_its_channel() {
        let mut b = metered(5, "1", 0.0);
        b.channel = "b0".into();
        let v: serde_json::Value =
            serde_json::from_str(&device(&[metered(3, "0.1", 0.0), b])).unwrap();
        assert_eq!(v["a0"]["total"], 3);
        assert_eq!(v["b0"]["value"], 5);
        assert_eq!(v.as_object().unwrap().len(), 2);
    }

    #[test]
    fn a_gauge_publishes_its_exact_value_and_unit_and_nothing_counted() {
        use crate::config::units::ChannelUnits;
        use crate::decimal::Decimal;
        use crate::reading::Measure;
        let mut r = metered(0, "1", 0.0);
        r.channel = "flow_temperature".into();
        r.units = Some(std::sync::Arc::new(ChannelUnits {
            unit: Some("°C".into()),
            ..ChannelUnits::default()
        }));
        r.measured = Some(Measure::Exact(Decimal::parse("60.25").unwrap()));
        let text = reading(&r);
        assert_eq!(
            text,
            r#"{"ts":"1970-01-01T00:00:00.000Z","value":60.25,"unit":"°C"}"#
        );
        r.measured = Some(Measure::Text("2024-01-31".into()));
        let v: serde_json::Value = serde_json::from_str(&device(&[r])).unwrap();
        assert_eq!(v["flow_temperature"]["value"], "2024-01-31");
    }

    #[test]
    fn a_register_names_the_unit_of_its_value() {
        let mut r = metered(12_345, "0.001", 0.0);
        std::sync::Arc::make_mut(r.units.as_mut().unwrap()).unit = Some("m³".into());
        let text = reading(&r);
        assert!(text.contains(r#""value":12.345,"#), "{text}");
        assert!(text.contains(r#""unit":"m³""#), "{text}");
        assert!(text.contains(r#""total":12345"#), "{text}");
    }
}
