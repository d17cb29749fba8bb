//! The messages of a channel's account that ride on an interval record: the tariff register it
//! moved (`…/tariff/<name>`) and the billing period it closed (`…/billing`). Pure.
//!
//! Both are retained: a register is a meter's register (the last value is the state), and the
//! last billing record is what a consumer that connects later needs. They travel inside the
//! record's output, so they are owed exactly as the record is (spooled, in order, sent again
//! with it after a crash).

use std::collections::BTreeMap;

use serde::Serialize;
use serde_json::value::RawValue;

use crate::metering::billing::{BillingRecord, PeriodStatus};
use crate::metering::clock::iso;
use crate::outbox::Message;
use crate::reading::IntervalRecord;
use crate::topics::Topics;

use super::signed::Signer;
use crate::metering::obis::Obis;
use crate::metering::tariff::Calendar;
use std::sync::Arc;

/// `{"total":1234,"value":1.234,"unit":"kWh","seq":17}`
#[derive(Debug, Serialize)]
struct RegisterJson {
    total: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<Box<RawValue>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    unit: Option<String>,
    seq: u64,
    /// The channel's OBIS name with the tariff's number as its last group (`1-0:1.8.2`).
    #[serde(skip_serializing_if = "Option::is_none")]
    obis: Option<String>,
}

/// A billing period's demand: the largest demand record's rate and where it began.
#[derive(Debug, Serialize)]
struct DemandJson {
    value: Box<RawValue>,
    unit: String,
    start: String,
    /// The maximum demand's OBIS name (`1-0:1.6.0`).
    #[serde(skip_serializing_if = "Option::is_none")]
    obis: Option<String>,
}

#[derive(Debug, Serialize)]
struct BillingJson<'a> {
    start: String,
    end: String,
    total_start: i64,
    total_end: i64,
    delta: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<Box<RawValue>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    unit: Option<String>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    by_tariff: &'a BTreeMap<String, i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    demand: Option<DemandJson>,
    status: PeriodStatus,
    seq: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    obis: Option<String>,
}

fn raw(text: String) -> Option<Box<RawValue>> {
    RawValue::from_string(text).ok()
}

fn scaled(i: &IntervalRecord, n: i64) -> Option<Box<RawValue>> {
    let u = i.units.as_deref()?;
    raw(crate::config::units::value(u, n)?.to_string())
}

fn obis(i: &IntervalRecord) -> Option<Obis> {
    i.units.as_deref()?.obis
}

fn unit(i: &IntervalRecord) -> Option<String> {
    let u = i.units.as_deref()?;
    u.scale?;
    u.unit.clone()
}

/// The JSON of a billing record of `i`'s channel.
pub fn billing_json(i: &IntervalRecord, b: &BillingRecord) -> String {
    let units = i.units.as_deref();
    let scale = units.and_then(|u| u.scale.as_ref());
    let demand = b.peak.map(|p| DemandJson {
        value: raw(crate::metering::demand::rate(&p, scale).to_string()).expect("a number"),
        unit: crate::metering::demand::rate_unit(unit(i).as_deref()),
        start: iso(p.start_ms),
        obis: obis(i).map(|o| o.demand().to_string()),
    });
    let json = BillingJson {
        start: iso(b.start_ms),
        end: iso(b.end_ms),
        total_start: b.total_start,
        total_end: b.total_end,
        delta: b.delta,
        value: scaled(i, b.delta),
        unit: unit(i),
        by_tariff: &b.by_tariff,
        demand,
        status: b.status,
        seq: b.seq,
        obis: obis(i).map(|o| o.to_string()),
    };
    serde_json::to_string(&json).expect("billing serializes")
}

/// What the messages of a channel's account are written with: the calendar that numbers the
/// tariffs (their OBIS names) and the signer of billing records, when there is one.
#[derive(Debug, Clone, Default)]
pub struct Ledger {
    pub calendar: Option<Arc<Calendar>>,
    pub signer: Option<Signer>,
}

/// The register and billing messages that ride on record `i` (none without a booking).
pub fn messages(topics: &Topics, i: &IntervalRecord, qos: u8, ledger: &Ledger) -> Vec<Message> {
    let Some(booking) = &i.record.booking else {
        return Vec::new();
    };
    let mut out = Vec::new();
    if let (Some(name), Some(reg)) = (&booking.tariff, &booking.register) {
        let json = RegisterJson {
            total: reg.total,
            value: scaled(i, reg.total),
            unit: unit(i),
            seq: reg.seq,
            obis: register_obis(i, ledger.calendar.as_deref(), name),
        };
        let body = serde_json::to_string(&json).expect("register serializes");
        let topic = topics.tariff(&i.device, &i.channel, name);
        out.push(Message::new(topic, body, qos, true));
    }
    for b in &booking.billing {
        let topic = topics.billing(&i.device, &i.channel);
        let mut body = billing_json(i, b);
        if let Some(s) = &ledger.signer {
            body = s.billing(i, body);
        }
        out.push(Message::new(topic, body, qos, true));
    }
    out
}

/// The OBIS name of `tariff`'s register of `i`'s channel: the channel's with the tariff's number.
fn register_obis(i: &IntervalRecord, calendar: Option<&Calendar>, tariff: &str) -> Option<String> {
    let number = calendar?.number(tariff)?;
    Some(obis(i)?.tariff(number).to_string())
}

#[cfg(test)]
#[path = "account_tests.rs"]
mod tests;
