//! A device's metrics: which a channel has (its shape, from the config and profile), their
//! values in a birth and in a reading's DDATA, and the node's aliases. Pure.
//!
//! Per channel `<c>`: `<c>/Total` (UInt64, Int64 for an encoder position), `<c>/Count`,
//! `<c>/Delta` (Int64), `<c>/Rate` (pulses per second, Double), `<c>/Frequency` and `<c>/RPM`
//! where the module measures them, `<c>/Value` (the scaled total, Double, its unit in the
//! `engUnit` property) where the channel has a `scale`, `<c>/Event` (String: cleared, preset,
//! reset, rollover, gap), and the writable `<c>/Clear` (Boolean) and `<c>/Preset` (Int64) where
//! the device takes commands. A gauge (an M-Bus meter's temperature, power, date) has one:
//! `<c>/Value` (Double, String for text), its unit in `engUnit`.

use std::collections::{BTreeMap, HashMap};

use super::proto::{Metric, Value, datatype};
use crate::config::units::ChannelUnits;
use crate::profile::ChannelKind;
use crate::reading::{Reading, unix_ms};

/// The property Ignition (and most hosts) read as a tag's engineering unit.
pub const UNIT_PROPERTY: &str = "engUnit";

/// The property that names a channel's total and value by OBIS (`1-0:1.8.0`).
pub const OBIS_PROPERTY: &str = "obis";

/// What one channel publishes.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelShape {
    pub name: String,
    pub kind: ChannelKind,
    pub freq: bool,
    pub rpm: bool,
    /// The unit of the scaled value, when the channel has a `scale`.
    pub value_unit: Option<Option<String>>,
    /// `<c>/Clear` and `<c>/Preset` are written by the host.
    pub writable: bool,
    /// `Some(numeric)` for a gauge: its one metric is `<c>/Value` (Double, or String for text
    /// such as a date), in its unit.
    pub gauge: Option<bool>,
    /// The channel's OBIS name (`obis`), a property of its `Total` and `Value`.
    pub obis: Option<String>,
}

impl ChannelShape {
    /// A channel its device declared (an M-Bus meter's record), as its reading shows it: not
    /// writable (only a profile's channels are).
    pub fn of_reading(r: &Reading) -> ChannelShape {
        let units = r.units.as_deref();
        let gauge = r
            .measured
            .as_ref()
            .map(|m| !matches!(m, crate::reading::Measure::Text(_)));
        let value_unit = match gauge {
            Some(_) => Some(units.and_then(|u| u.unit.clone())),
            None => units.and_then(|u| u.scale.map(|_| u.unit.clone())),
        };
        ChannelShape {
            name: r.channel.to_string(),
            kind: r.kind,
            freq: r.freq_hz.is_some(),
            rpm: r.rpm.is_some(),
            value_unit,
            writable: false,
            gauge,
            obis: units.and_then(|u| u.obis).map(|o| o.to_string()),
        }
    }

    fn value_type(&self) -> u32 {
        match self.gauge {
            Some(false) => datatype::STRING,
            _ => datatype::DOUBLE,
        }
    }

    fn total_type(&self) -> u32 {
        match self.kind {
            ChannelKind::Encoder => datatype::INT64,
            ChannelKind::Counter => datatype::UINT64,
        }
    }
}

/// The node's aliases: one number per device metric, unique over the node, kept for the life
/// of the process (a rebirth declares the same ones again).
#[derive(Debug, Default)]
pub struct Aliases {
    by_metric: HashMap<(String, String), u64>,
    next: u64,
}

impl Aliases {
    /// The alias `metric` of `device` has, if any.
    pub fn get(&self, device: &str, metric: &str) -> Option<u64> {
        let key = (device.to_string(), metric.to_string());
        self.by_metric.get(&key).copied()
    }

    /// The alias of `metric` of `device`, given one at first use.
    pub fn of(&mut self, device: &str, metric: &str) -> u64 {
        let key = (device.to_string(), metric.to_string());
        let next = &mut self.next;
        *self.by_metric.entry(key).or_insert_with(|| {
            *next += 1;
            *next
        })
    }
}

/// The metrics of a channel, the one list of them, with the values of reading `r` (all null
/// without one, for a birth before any reading): name, datatype, value.
pub fn values(r: Option<&Reading>, shape: &ChannelShape) -> Vec<(String, u32, Option<Value>)> {
    let c = &shape.name;
    if shape.gauge.is_some() {
        let v = r.and_then(|r| r.measured.as_ref()).and_then(|m| match m {
            crate::reading::Measure::Text(t) => Some(Value::String(t.to_string())),
            other => other.to_f64().map(Value::Double),
        });
        return vec![(format!("{c}/Value"), shape.value_type(), v)];
    }
    let round = crate::publish::payload::round3;
    let total = r.map(|r| match shape.kind {
        ChannelKind::Encoder => r.update.total as u64,
        ChannelKind::Counter => r.update.total.max(0) as u64,
    });
    let mut out = vec![
        (
            format!("{c}/Total"),
            shape.total_type(),
            total.map(Value::Long),
        ),
        (
            format!("{c}/Count"),
            datatype::INT64,
            r.map(|r| Value::Long(r.count as u64)),
        ),
        (
            format!("{c}/Delta"),
            datatype::INT64,
            r.map(|r| Value::Long(r.update.delta as u64)),
        ),
        (
            format!("{c}/Rate"),
            datatype::DOUBLE,
            r.and_then(|r| r.update.rate_hz)
                .map(|v| Value::Double(round(v))),
        ),
    ];
    if shape.freq {
        let v = r.and_then(|r| r.freq_hz).map(|v| Value::Double(round(v)));
        out.push((format!("{c}/Frequency"), datatype::DOUBLE, v));
    }
    if shape.rpm {
        let v = r.and_then(|r| r.rpm).map(|v| Value::Double(round(v)));
        out.push((format!("{c}/RPM"), datatype::DOUBLE, v));
    }
    if shape.value_unit.is_some() {
        let v = r.and_then(|r| r.units.as_deref().and_then(|u| scaled(u, r.update.total)));
        out.push((format!("{c}/Value"), datatype::DOUBLE, v));
    }
    let event = r
        .and_then(|r| r.update.event)
        .and_then(|e| match serde_json::to_value(e) {
            Ok(serde_json::Value::String(s)) => Some(Value::String(s)),
            _ => None,
        });
    out.push((format!("{c}/Event"), datatype::STRING, event));
    out
}

fn scaled(units: &ChannelUnits, total: i64) -> Option<Value> {
    crate::config::units::value(units, total).map(|d| Value::Double(d.to_f64()))
}

/// The DDATA metrics of one reading: name and alias (the send turns them into alias only),
/// the reading's time, only the values it has (a missing rate is not sent as a change).
pub fn data(r: &Reading, shape: &ChannelShape, aliases: &mut Aliases) -> Vec<Metric> {
    let ts = unix_ms(r.ts);
    values(Some(r), shape)
        .into_iter()
        .filter(|(_, _, v)| v.is_some())
        .map(|(name, dt, v)| {
            let alias = aliases.of(&r.device, &name);
            let mut m = Metric::new(&name, Some(alias), dt, v);
            m.timestamp = Some(ts);
            m
        })
        .collect()
}

/// Whether a metric is what the channel's OBIS name names: its total or its scaled value.
fn is_register(name: &str) -> bool {
    name.ends_with("/Total") || name.ends_with("/Value")
}

/// Every metric of a device for its DBIRTH, with the last values seen (null before any).
pub fn birth(
    device: &str,
    shapes: &[ChannelShape],
    last: &BTreeMap<String, Reading>,
    aliases: &mut Aliases,
) -> Vec<Metric> {
    let mut out = Vec::new();
    for shape in shapes {
        let mut named = values(last.get(&shape.name), shape);
        // An event belongs to its reading: a birth does not repeat it.
        for (name, _, v) in &mut named {
            if name.ends_with("/Event") {
                *v = None;
            }
        }
        for (name, dt, v) in named {
            let mut m = Metric::new(&name, Some(aliases.of(device, &name)), dt, v);
            if let (true, Some(Some(unit))) = (name.ends_with("/Value"), &shape.value_unit) {
                m = m.with_property(UNIT_PROPERTY, unit);
            }
            if name.ends_with("/Rate") || name.ends_with("/Frequency") {
                m = m.with_property(UNIT_PROPERTY, "Hz");
            }
            if let (true, Some(obis)) = (is_register(&name), &shape.obis) {
                m = m.with_property(OBIS_PROPERTY, obis);
            }
            out.push(m);
        }
        if shape.writable {
            for (name, dt, v) in [
                (
                    format!("{}/Clear", shape.name),
                    datatype::BOOLEAN,
                    Value::Boolean(false),
                ),
                (
                    format!("{}/Preset", shape.name),
                    datatype::INT64,
                    Value::Long(0),
                ),
            ] {
                out.push(Metric::new(
                    &name,
                    Some(aliases.of(device, &name)),
                    dt,
                    Some(v),
                ));
            }
        }
    }
    out
}
