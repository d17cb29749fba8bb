//! Records as channels, tested on a corpus meter's answer and on hand-written records.

use super::*;
use crate::mbus::driver::telegram;

fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).unwrap())
        .collect()
}

/// Kamstrup 382 (from the corpus): energy (kWh, 32-bit), on time, power, max power, energy by
/// tariff and subunit, manufacturer data. Medium 0x02 (electricity).
const KAMSTRUP: &str = "72 20 91 83 14 2D 2C 01 02 04 00 00 00 04 06 00 00 00 00 04 22 09 00 00 00 04 2B 00 00 00 00 14 2B 00 00 00 00 84 50 06 00 00 00 00 84 60 06 00 00 00 00 0F 00 00";

fn kamstrup() -> Vec<Record> {
    let b = hex(KAMSTRUP);
    telegram::decode(b[0], &b[1..]).unwrap().records
}

/// A water meter's records (CI 0x78): volume 12.345 m³ in litres as 8-digit BCD, flow
/// 0.5 m³/h as a 16-bit integer in l/h, flow temperature 60.2 °C in 0.1 °C.
fn water() -> Vec<Record> {
    let b = hex("0C 13 45 23 01 00 02 3B F4 01 02 5A 5A 02");
    telegram::decode(0x78, &b).unwrap().records
}

fn at() -> At {
    At::now()
}

#[test]
fn every_record_with_a_value_is_a_channel_by_its_default_name() {
    let picked = channels(&kamstrup(), &BTreeMap::new(), Some(0x02));
    let names: Vec<&str> = picked.iter().map(|p| &*p.channel.name).collect();
    assert_eq!(
        names,
        [
            "energy",
            "on_time",
            "power",
            "power_max",
            "energy_t1_u1",
            "energy_t2_u1"
        ],
        "the manufacturer's bytes are no channel"
    );
    assert!(matches!(
        picked[0].channel.counting,
        Counting::Register { rollover, .. } if rollover == 1 << 32
    ));
    assert_eq!(picked[2].channel.counting, Counting::Gauge);
}

#[test]
fn a_volume_register_counts_litres_and_its_value_is_in_cubic_metres() {
    let picked = channels(&water(), &BTreeMap::new(), Some(0x07));
    let units = picked[0].channel.units.clone().unwrap();
    assert_eq!(units.scale.unwrap().to_string(), "0.001");
    assert_eq!(units.unit.as_deref(), Some("m³"));
    assert_eq!(units.device_class.as_deref(), Some("water"));
    assert_eq!(units.rate_unit.as_deref(), Some("m³/h"));
    assert!(matches!(
        picked[0].channel.counting,
        Counting::Register {
            rollover: 100_000_000,
            ..
        }
    ));
    let samples = samples(&water(), &picked, at(), false);
    assert_eq!(samples[0].value.count(), Some(12345));
    assert_eq!(
        samples[1].value,
        crate::sample::Value::Gauge(Measure::Exact(Decimal::parse("0.5").unwrap()))
    );
    assert_eq!(
        samples[2].value,
        crate::sample::Value::Gauge(Measure::Exact(Decimal::parse("60.2").unwrap()))
    );
    let flow = picked[1].channel.units.clone().unwrap();
    assert_eq!((flow.unit.as_deref(), flow.scale), (Some("m³/h"), None));
}

#[test]
fn a_gas_meters_volume_is_gas_and_a_kwh_register_is_in_kwh() {
    let gas = channels(&water(), &BTreeMap::new(), Some(0x03));
    let units = gas[0].channel.units.clone().unwrap();
    assert_eq!(units.device_class.as_deref(), Some("gas"));
    // 0C 06: energy in kWh steps, 8-digit BCD.
    let b = hex("0C 06 34 12 00 00");
    let heat = telegram::decode(0x78, &b).unwrap().records;
    let u = register_units(&heat[0], Some(0x04)).unwrap();
    assert_eq!(
        (u.unit.as_deref(), u.scale.unwrap().to_string()),
        (Some("kWh"), "1".into())
    );
    assert_eq!(u.rate_unit.as_deref(), Some("kW"));
}

#[test]
fn a_config_that_picks_records_gets_only_those_by_its_names() {
    let mut config = BTreeMap::new();
    config.insert(
        "heat".to_string(),
        ChannelConfig {
            record: Some(0),
            ..ChannelConfig::default()
        },
    );
    config.insert("power".to_string(), ChannelConfig::default());
    let picked = channels(&kamstrup(), &config, None);
    let names: Vec<(usize, &str)> = picked
        .iter()
        .map(|p| (p.record, &*p.channel.name))
        .collect();
    assert_eq!(names, [(0, "heat"), (2, "power")]);
}

#[test]
fn a_disabled_channel_is_left_out() {
    let mut config = BTreeMap::new();
    config.insert(
        "on_time".to_string(),
        ChannelConfig {
            enabled: false,
            ..ChannelConfig::default()
        },
    );
    let picked = channels(&kamstrup(), &config, None);
    assert!(picked.iter().all(|p| &*p.channel.name != "on_time"));
    assert_eq!(picked.len(), 5);
}

#[test]
fn a_signed_32_bit_register_past_2_pow_31_is_counted_as_its_unsigned_steps() {
    // 04 13: volume in litres, 32-bit: 0xFFFFFFFE is -2 signed, 4294967294 steps.
    let b = hex("04 13 FE FF FF FF");
    let records = telegram::decode(0x78, &b).unwrap().records;
    let picked = channels(&records, &BTreeMap::new(), None);
    let s = samples(&records, &picked, at(), true);
    assert_eq!(s[0].value.count(), Some(4_294_967_294));
    assert!(s[0].starts_over, "a replaced meter's registers start over");
}
