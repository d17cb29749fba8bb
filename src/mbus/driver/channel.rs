//! Records as the core will see them: a stable default channel name per record, and which
//! records are meter registers (counted, with the roll-over of their width) and which are
//! values. Pure.

use std::collections::BTreeSet;

use super::dif::{Coding, Function};
use super::quantity::Quantity;
use super::record::Record;
use super::value::Value;

/// What the core does with a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A meter register: a running total, counted (delta, total) in its raw steps, rolling
    /// over at its width.
    Register(Rollover),
    /// A value published as it is (power, flow, temperatures, dates, stored values…).
    Value,
}

/// Where a register's raw count rolls over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rollover {
    /// A BCD register of this many digits rolls over at 10^digits.
    Digits(u32),
    /// A binary register of this many bits rolls over at 2^bits.
    Bits(u32),
}

impl Rollover {
    /// The number of raw steps after which the register starts again at 0.
    pub fn modulus(&self) -> u128 {
        match self {
            Rollover::Digits(d) => 10u128.pow(*d),
            Rollover::Bits(b) => 1u128 << b,
        }
    }
}

/// Whether `record` is a meter register: energy, volume, mass or heat cost allocator units,
/// of storage 0, the instantaneous value, fully understood, an integer or BCD number.
pub fn kind(record: &Record) -> Kind {
    let counted = matches!(
        record.quantity(),
        Quantity::Energy | Quantity::Volume | Quantity::Mass | Quantity::HcaUnits
    );
    let plain = record.function == Function::Instantaneous
        && record.storage == 0
        && record.is_understood()
        && record.modifiers().iter().all(|m| m.keeps_register())
        && matches!(record.value, Value::Number(_));
    if !(counted && plain) {
        return Kind::Value;
    }
    match record.coding {
        Some(Coding::Bcd(bytes)) => Kind::Register(Rollover::Digits(2 * u32::from(bytes))),
        Some(Coding::Int(bytes)) => Kind::Register(Rollover::Bits(8 * u32::from(bytes))),
        _ => Kind::Value,
    }
}

/// A record's name before duplicates are told apart: quantity, what the VIFEs changed,
/// function, then storage (`_s1`), tariff (`_t2`) and subunit (`_u1`) where not 0.
pub fn base_name(record: &Record) -> String {
    if record.coding.is_none() {
        return "manufacturer_data".into();
    }
    let mut name = record.quantity().name();
    for m in record.modifiers() {
        name.push_str(&m.suffix());
    }
    name.push_str(match record.function {
        Function::Instantaneous => "",
        Function::Maximum => "_max",
        Function::Minimum => "_min",
        Function::DuringError => "_error",
    });
    for (tag, n) in [
        ("s", record.storage),
        ("t", u64::from(record.tariff)),
        ("u", u64::from(record.subunit)),
    ] {
        if n > 0 {
            name.push_str(&format!("_{tag}{n}"));
        }
    }
    name
}

/// The default channel names of a telegram's records, in order: unique (a name already taken
/// gets `_2`, `_3`… in frame order), each a valid MQTT topic level (lowercase ASCII, digits,
/// `_`). The same records give the same names on every poll and every restart.
pub fn names(records: &[Record]) -> Vec<String> {
    let mut taken = BTreeSet::new();
    records
        .iter()
        .map(|r| {
            let base = base_name(r);
            let mut name = base.clone();
            let mut n = 2;
            while !taken.insert(name.clone()) {
                name = format!("{base}_{n}");
                n += 1;
            }
            name
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::telegram;
    use super::*;

    /// Kamstrup 382 (from the corpus): energy, on time, power, max power, energy by tariff
    /// and subunit, manufacturer data.
    const KAMSTRUP: &str = "72 20 91 83 14 2D 2C 01 02 04 00 00 00 04 06 00 00 00 00 04 22 09 00 00 00 04 2B 00 00 00 00 14 2B 00 00 00 00 84 50 06 00 00 00 00 84 60 06 00 00 00 00 0F 00 00";

    fn kamstrup() -> Vec<Record> {
        let bytes: Vec<u8> = KAMSTRUP
            .split_whitespace()
            .map(|h| u8::from_str_radix(h, 16).unwrap())
            .collect();
        telegram::decode(bytes[0], &bytes[1..]).unwrap().records
    }

    #[test]
    fn names_come_from_quantity_function_tariff_and_subunit() {
        assert_eq!(
            names(&kamstrup()),
            [
                "energy",
                "on_time",
                "power",
                "power_max",
                "energy_t1_u1",
                "energy_t2_u1",
                "manufacturer_data"
            ]
        );
    }

    #[test]
    fn a_name_taken_twice_gets_a_number_in_frame_order() {
        let mut records = kamstrup();
        records.truncate(1);
        records.push(records[0].clone());
        records.push(records[0].clone());
        assert_eq!(names(&records), ["energy", "energy_2", "energy_3"]);
    }

    #[test]
    fn an_instantaneous_energy_of_storage_0_is_a_register_and_power_is_a_value() {
        let records = kamstrup();
        assert_eq!(kind(&records[0]), Kind::Register(Rollover::Bits(32)));
        assert_eq!(kind(&records[2]), Kind::Value);
        assert_eq!(kind(&records[4]), Kind::Register(Rollover::Bits(32)));
        assert_eq!(Rollover::Digits(8).modulus(), 100_000_000);
        assert_eq!(Rollover::Bits(48).modulus(), 1 << 48);
    }
}
