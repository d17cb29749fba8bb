//! A meter's records as the core's channels: which records are channels and by what names
//! (every record by its default name, or the ones the config picks), how each counts (a
//! register with its roll-over, or a gauge), what one step is worth and in what unit, and per
//! poll each channel's sample. Pure.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::config::ChannelConfig;
use crate::config::units::{ChannelUnits, RatePer};
use crate::decimal::Decimal;
use crate::mbus::driver::channel::{self, Kind};
use crate::mbus::driver::quantity::{Quantity, Unit};
use crate::mbus::driver::record::Record;
use crate::mbus::driver::value::Value as RecordValue;
use crate::profile::ChannelKind;
use crate::sample::{At, Channel, Counting, Measure, Sample};

/// The most register steps a second a meter is taken to make unless a channel's `max_rate_hz`
/// says otherwise: a larger jump down than a roll-over explains is a meter replaced.
pub const DEFAULT_MAX_STEPS_HZ: f64 = 1000.0;

/// One record of the answer as a channel of the core.
#[derive(Debug, Clone, PartialEq)]
pub struct Picked {
    /// The record's 0-based index in the answer (across its telegrams).
    pub record: usize,
    pub channel: Channel,
}

/// The channels of a meter's `records`: every record with a value by its default name
/// ([`channel::names`]); when the config picks any (a channel with `record = N`), only the
/// picked ones, named by the config, and those it names by their default names. Channels the
/// config disables are left out. `medium` (the header's) tells water from gas.
pub fn channels(
    records: &[Record],
    config: &BTreeMap<String, ChannelConfig>,
    medium: Option<u8>,
) -> Vec<Picked> {
    let defaults = channel::names(records);
    let picking = config.values().any(|c| c.record.is_some());
    let mut out = Vec::new();
    for (r, default) in records.iter().zip(defaults) {
        if !has_value(r) {
            continue;
        }
        let by_record = config.iter().find(|(_, c)| c.record == Some(r.index));
        let (name, settings) = match by_record {
            Some((name, c)) => (name.clone(), Some(c)),
            None => {
                let named = config.get(&default).filter(|c| c.record.is_none());
                if picking && named.is_none() {
                    continue;
                }
                (default, named)
            }
        };
        if settings.is_some_and(|c| !c.enabled) {
            continue;
        }
        let max_rate = settings.and_then(|c| c.max_rate_hz);
        out.push(Picked {
            record: r.index,
            channel: channel_of(r, Arc::from(name.as_str()), max_rate, medium),
        });
    }
    out
}

/// Whether a record holds something to publish (not a readout selection, an empty field, or
/// the manufacturer's bytes).
fn has_value(r: &Record) -> bool {
    r.coding.is_some() && !matches!(r.value, RecordValue::Empty | RecordValue::Bytes(_))
}

fn channel_of(r: &Record, name: Arc<str>, max_rate: Option<f64>, medium: Option<u8>) -> Channel {
    match channel::kind(r) {
        Kind::Register(rollover) => Channel {
            name,
            kind: ChannelKind::Counter,
            counting: Counting::Register {
                rollover: modulus(rollover.modulus()),
                max_rate_hz: max_rate.unwrap_or(DEFAULT_MAX_STEPS_HZ),
            },
            units: register_units(r, medium),
        },
        Kind::Value => Channel {
            name,
            kind: ChannelKind::Counter,
            counting: Counting::Gauge,
            units: Some(ChannelUnits {
                unit: r.unit().map(Unit::symbol),
                ..ChannelUnits::default()
            }),
        },
    }
}

/// A roll-over that fits the core's counts (a 64-bit register never rolls over in practice).
fn modulus(m: u128) -> i64 {
    i64::try_from(m).unwrap_or(i64::MAX)
}

/// A register's step and unit: the VIF's exponent and unit, energy in kWh (MWh) where its steps
/// are that large, its rate per hour (W, kW, m³/h), and Home Assistant's class by quantity and
/// medium (a volume of a water meter is water, of a gas meter gas).
pub fn register_units(r: &Record, medium: Option<u8>) -> Option<ChannelUnits> {
    let RecordValue::Number(e) = &r.value else {
        return None;
    };
    let (unit, shift, rate_unit, class) = match (r.quantity(), r.unit()) {
        (Quantity::Energy, Some(Unit::Wh)) => match e.exp {
            i32::MIN..=2 => ("Wh", 0, Some("W"), Some("energy")),
            3..=5 => ("kWh", 3, Some("kW"), Some("energy")),
            _ => ("MWh", 6, Some("MW"), Some("energy")),
        },
        (Quantity::Energy, Some(Unit::J)) => match e.exp {
            i32::MIN..=2 => ("J", 0, None, Some("energy")),
            3..=5 => ("kJ", 3, None, Some("energy")),
            6..=8 => ("MJ", 6, None, Some("energy")),
            _ => ("GJ", 9, None, Some("energy")),
        },
        (Quantity::Volume, Some(Unit::M3)) => ("m³", 0, Some("m³/h"), Some(volume_class(medium))),
        (Quantity::Mass, Some(Unit::Kg)) => ("kg", 0, Some("kg/h"), Some("weight")),
        (Quantity::HcaUnits, _) => {
            return Some(ChannelUnits {
                scale: Some(pow10(e.exp)?),
                rate_per: RatePer::Hour,
                ..ChannelUnits::default()
            });
        }
        _ => return None,
    };
    Some(ChannelUnits {
        scale: Some(pow10(e.exp - shift)?),
        unit: Some(unit.to_string()),
        rate_unit: rate_unit.map(str::to_string),
        rate_per: RatePer::Hour,
        device_class: class.map(str::to_string),
        obis: None,
    })
}

/// Home Assistant's class of a volume register by the meter's medium.
fn volume_class(medium: Option<u8>) -> &'static str {
    match medium {
        // Warm, hot, cold, dual register and irrigation water, water.
        Some(0x06 | 0x07 | 0x10 | 0x15 | 0x16 | 0x17) => "water",
        Some(0x03) => "gas",
        _ => "volume",
    }
}

/// `10^exp` exactly.
fn pow10(exp: i32) -> Option<Decimal> {
    Decimal::parse(&format!("1e{exp}")).ok()
}

/// Each picked channel's sample from this poll's `records`, at `at`; `replaced`: the meter in
/// the place of the last is another one (its registers start over).
pub fn samples(records: &[Record], picked: &[Picked], at: At, replaced: bool) -> Vec<Sample> {
    let mut out = Vec::with_capacity(picked.len());
    for (i, p) in picked.iter().enumerate() {
        let Some(r) = records.iter().find(|r| r.index == p.record) else {
            continue;
        };
        let sample = match (&p.channel.counting, &r.value) {
            (Counting::Register { rollover, .. }, RecordValue::Number(e)) => {
                let s = Sample::register(i, at, e.raw.rem_euclid(*rollover), *rollover);
                if replaced { s.starting_over() } else { s }
            }
            (Counting::Register { .. }, _) => continue,
            (_, value) => match measure(value) {
                Some(m) => Sample::gauge(i, at, m),
                None => continue,
            },
        };
        out.push(sample);
    }
    out
}

/// A record's value as a gauge's: exact where the meter sent a number.
pub fn measure(value: &RecordValue) -> Option<Measure> {
    Some(match value {
        RecordValue::Number(e) => match Decimal::parse(&e.to_decimal_string()) {
            Ok(d) => Measure::Exact(d),
            Err(_) => Measure::Real(e.to_f64()),
        },
        RecordValue::Real { .. } => Measure::Real(value.to_f64().filter(|v| v.is_finite())?),
        RecordValue::Date(d) => Measure::Text(Arc::from(d.to_string().as_str())),
        RecordValue::DateTime(d) => Measure::Text(Arc::from(d.to_string().as_str())),
        RecordValue::Text(t) => Measure::Text(Arc::from(t.as_str())),
        RecordValue::InvalidBcd(digits) => Measure::Text(Arc::from(digits.as_str())),
        RecordValue::Bytes(_) | RecordValue::Empty => return None,
    })
}

#[cfg(test)]
#[path = "records_tests.rs"]
mod tests;
