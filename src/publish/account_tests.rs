use super::*;
use crate::config::units::ChannelUnits;
use crate::metering::booking::{Booking, Peak, Register};
use crate::metering::tariff::RawRule;
use crate::metering::{Record, Status};

fn calendar() -> Arc<Calendar> {
    let rule = RawRule {
        tariff: "peak".into(),
        days: vec!["mon".into()],
        from: "07:00".into(),
        to: "21:00".into(),
    };
    Arc::new(Calendar::new("offpeak", &[], &[rule]).unwrap())
}

/// A 15-minute record of a kWh channel named `obis`, booked to `tariff`, closing a period.
fn record(obis: Option<&str>, tariff: &str) -> IntervalRecord {
    let billing = BillingRecord {
        start_ms: 0,
        end_ms: 86_400_000,
        total_start: 0,
        total_end: 900,
        delta: 900,
        by_tariff: [("offpeak".to_string(), 300), ("peak".to_string(), 600)].into(),
        peak: Some(Peak {
            delta: 100,
            start_ms: 900_000,
            ms: 900_000,
        }),
        status: PeriodStatus::Complete,
        seq: 1,
    };
    let booking = Booking {
        tariff: Some(tariff.into()),
        tariffs: Vec::new(),
        register: Some(Register { total: 600, seq: 4 }),
        billing: vec![billing],
    };
    let record = Record {
        start_ms: 85_500_000,
        end_ms: 86_400_000,
        delta: 100,
        total_start: 800,
        total_end: 900,
        lag_start_ms: 0,
        lag_end_ms: 0,
        status: Status::Complete,
        seq: 96,
        events: Vec::new(),
        booking: Some(Box::new(booking)),
    };
    IntervalRecord {
        device: "m1".into(),
        channel: "a0".into(),
        period: "15min".into(),
        record,
        units: Some(Arc::new(ChannelUnits {
            scale: crate::decimal::Decimal::parse("0.001").ok(),
            unit: Some("kWh".into()),
            obis: obis.map(|o| o.parse().unwrap()),
            ..ChannelUnits::default()
        })),
    }
}

fn bodies(i: &IntervalRecord) -> Vec<(String, serde_json::Value)> {
    let ledger = Ledger {
        calendar: Some(calendar()),
        signer: None,
    };
    messages(&Topics::new("pg"), i, 1, &ledger)
        .into_iter()
        .map(|m| {
            (
                m.topic.to_string(),
                serde_json::from_slice(&m.payload).unwrap(),
            )
        })
        .collect()
}

#[test]
fn a_tariff_register_takes_the_tariffs_number_in_the_calendar_as_its_last_obis_group() {
    let peak = bodies(&record(Some("1-0:1.8.0"), "peak"));
    assert_eq!(peak[0].0, "pg/m1/a0/tariff/peak");
    assert_eq!(peak[0].1["obis"], "1-0:1.8.2", "{:?}", peak[0]);
    let offpeak = bodies(&record(Some("1-0:1.8.0"), "offpeak"));
    assert_eq!(
        offpeak[0].1["obis"], "1-0:1.8.1",
        "the default is named first"
    );
}

#[test]
fn a_billing_record_carries_the_channels_obis_and_its_demand_the_maximum_demand_name() {
    let out = bodies(&record(Some("1-0:1.8.0"), "peak"));
    let billing = &out[1];
    assert_eq!(billing.0, "pg/m1/a0/billing");
    assert_eq!(billing.1["obis"], "1-0:1.8.0");
    assert_eq!(billing.1["demand"]["obis"], "1-0:1.6.0");
    assert_eq!(billing.1["demand"]["unit"], "kW");
}

#[test]
fn a_channel_without_obis_publishes_no_obis_field() {
    for (_, body) in bodies(&record(None, "peak")) {
        assert!(body.get("obis").is_none(), "{body}");
        assert!(body["demand"].get("obis").is_none(), "{body}");
    }
}

#[test]
fn an_interval_record_and_a_reading_of_a_named_channel_carry_its_obis() {
    let i = record(Some("1-0:1.8.0"), "peak");
    let json: serde_json::Value =
        serde_json::from_str(&super::super::payload::interval(&i)).unwrap();
    assert_eq!(json["obis"], "1-0:1.8.0");
    let mut r = crate::reading::Reading::sample("m1", "a0", 1);
    r.units = i.units.clone();
    let json: serde_json::Value =
        serde_json::from_str(&super::super::payload::reading(&r)).unwrap();
    assert_eq!(json["obis"], "1-0:1.8.0");
    assert_eq!(json["unit"], "kWh");
}
