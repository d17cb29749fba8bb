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

/// `{"total":1234,"value":1.234,"unit":"kWh","seq":17}`
#[derive(Debug, Serialize)]
struct RegisterJson {
    total: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    value: Option<Box<RawValue>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    unit: Option<String>,
    seq: u64,
}

/// A billing period's demand: the largest demand record's rate and where it began.
#[derive(Debug, Serialize)]
struct DemandJson {
    value: Box<RawValue>,
    unit: String,
    start: String,
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
}

fn raw(text: String) -> Option<Box<RawValue>> {
    RawValue::from_string(text).ok()
}

fn scaled(i: &IntervalRecord, n: i64) -> Option<Box<RawValue>> {
    let u = i.units.as_deref()?;
    raw(crate::config::units::value(u, n)?.to_string())
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
    };
    serde_json::to_string(&json).expect("billing serializes")
}

/// The register and billing messages that ride on record `i` (none without a booking).
/// Billing records are signed by `signer` when there is one.
pub fn messages(
    topics: &Topics,
    i: &IntervalRecord,
    qos: u8,
    signer: Option<&Signer>,
) -> Vec<Message> {
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
        };
        let body = serde_json::to_string(&json).expect("register serializes");
        let topic = topics.tariff(&i.device, &i.channel, name);
        out.push(Message::new(topic, body, qos, true));
    }
    for b in &booking.billing {
        let topic = topics.billing(&i.device, &i.channel);
        let mut body = billing_json(i, b);
        if let Some(s) = signer {
            body = s.billing(i, body);
        }
        out.push(Message::new(topic, body, qos, true));
    }
    out
}
