//! The fixed data structure of CI 0x73 (the older format some meters still send): id,
//! access, status, two medium/unit bytes and two 4-byte counters, BCD or binary as the status
//! says. Its units come from the standard's own table for this format. Pure.

use super::dif::{Coding, Function};
use super::error::DecodeError;
use super::header::Header;
use super::quantity::{Quantity, Unit};
use super::record::Record;
use super::value::{self, Exact, Value};
use super::vife::Meaning;

/// The structure's length after the CI field.
pub const LEN: usize = 16;

/// Reads the 16 bytes of a fixed data answer: its header and its two counters.
pub fn decode(data: &[u8]) -> Result<(Header, Vec<Record>), DecodeError> {
    if data.len() != LEN {
        return Err(DecodeError::FixedLength { have: data.len() });
    }
    let status = data[5];
    let header = Header::Fixed {
        id: u32::from_le_bytes([data[0], data[1], data[2], data[3]]),
        access: data[4],
        status,
        medium: (data[6] >> 6) | ((data[7] >> 6) << 2),
    };
    let records = (0..2)
        .map(|i| counter(i, status, data[6 + i], &data[8 + 4 * i..12 + 4 * i]))
        .collect();
    Ok((header, records))
}

fn counter(index: usize, status: u8, unit_byte: u8, bytes: &[u8]) -> Record {
    let binary = status & 0x80 != 0;
    let stored = status & 0x40 != 0;
    let (quantity, unit, exp) = unit_of(unit_byte & 0x3F);
    let raw = if binary {
        Value::Number(Exact {
            raw: value::int_le(bytes),
            exp: 0,
        })
    } else {
        value::bcd_le(bytes)
    };
    let meaning = Meaning {
        quantity,
        unit,
        exp,
        modifiers: Vec::new(),
        time_point: false,
        record_error: None,
        not_understood: Vec::new(),
    };
    Record {
        index,
        function: Function::Instantaneous,
        storage: u64::from(stored),
        tariff: 0,
        subunit: 0,
        coding: Some(if binary {
            Coding::Int(4)
        } else {
            Coding::Bcd(4)
        }),
        value: raw.scaled(meaning.exp),
        meaning,
        bytes: bytes.to_vec(),
    }
}

/// The fixed structure's unit codes: quantity, unit and exponent.
fn unit_of(code: u8) -> (Quantity, Option<Unit>, i32) {
    // Three steps of ten per prefix: Wh 10 Wh 100 Wh kWh …; the table runs in that order.
    let step = |first: u8| i32::from(code - first);
    use Quantity as Q;
    match code {
        0x02..=0x0A => (Q::Energy, Some(Unit::Wh), step(0x02)),
        0x0B..=0x13 => (Q::Energy, Some(Unit::J), 3 + step(0x0B)),
        0x14..=0x1C => (Q::Power, Some(Unit::W), step(0x14)),
        0x1D..=0x25 => (Q::Power, Some(Unit::JPerH), 3 + step(0x1D)),
        0x26..=0x2E => (Q::Volume, Some(Unit::M3), step(0x26) - 6),
        0x2F..=0x37 => (Q::VolumeFlow, Some(Unit::M3PerH), step(0x2F) - 6),
        0x38 => (Q::Extended("temperature"), Some(Unit::Celsius), -3),
        0x39 => (Q::HcaUnits, None, 0),
        _ => (Q::Unknown(super::quantity::Table::Fixed, code), None, 0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fixed_table_counts_in_steps_of_ten() {
        assert_eq!(unit_of(0x05), (Quantity::Energy, Some(Unit::Wh), 3));
        assert_eq!(unit_of(0x0E), (Quantity::Energy, Some(Unit::J), 6));
        assert_eq!(unit_of(0x29), (Quantity::Volume, Some(Unit::M3), -3));
        assert_eq!(unit_of(0x35), (Quantity::VolumeFlow, Some(Unit::M3PerH), 0));
    }
}
