//! One data record of a variable data structure: `DIF [DIFE…] VIF [VIFE…] data`, read and
//! its data decoded by what the DIF and VIF say. Pure.

use super::dif::{self, Coding, Dib, Function, Start};
use super::error::DecodeError;
use super::quantity::{Quantity, Unit};
use super::value::{self, Exact, Value};
use super::vif::{self, Vib};
use super::vife::{self, Meaning, Modifier};

/// One data record.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    /// The record's place in the answer, from 0 (fillers are not records; the manufacturer
    /// data after DIF 0F/1F is the last record).
    pub index: usize,
    pub function: Function,
    pub storage: u64,
    pub tariff: u32,
    pub subunit: u16,
    /// How the data field is coded; `None` for manufacturer data (DIF 0F/1F).
    pub coding: Option<Coding>,
    /// Quantity, unit, exponent and what the VIFEs changed.
    pub meaning: Meaning,
    pub value: Value,
    /// The record's bytes as sent: DIB, VIB (with any plain text), data.
    pub bytes: Vec<u8>,
}

impl Record {
    /// The record's quantity.
    pub fn quantity(&self) -> &Quantity {
        &self.meaning.quantity
    }

    /// The value's unit, where it has one.
    pub fn unit(&self) -> Option<&Unit> {
        self.meaning.unit.as_ref()
    }

    /// Whether every VIFE was understood and the meter set no record error.
    pub fn is_understood(&self) -> bool {
        self.meaning.not_understood.is_empty() && self.meaning.record_error.is_none()
    }

    /// The modifiers the VIFEs applied.
    pub fn modifiers(&self) -> &[Modifier] {
        &self.meaning.modifiers
    }
}

/// What reading at one offset found.
pub enum Read {
    Record(Record),
    /// Manufacturer data to the end (DIF 0F, or 1F: `more_follows`).
    Manufacturer {
        record: Record,
        more_follows: bool,
    },
    /// An idle filler byte.
    Filler,
}

/// Reads the record at `data[at..]` (`index` is its number); returns it and its length.
pub fn read(data: &[u8], at: usize, index: usize) -> Result<(Read, usize), DecodeError> {
    let rest = &data[at..];
    let (start, dlen) = dif::read(rest, at)?;
    let dib = match start {
        Start::Filler => return Ok((Read::Filler, 1)),
        Start::Manufacturer | Start::MoreFollows => {
            let record = manufacturer(rest, index);
            let more_follows = start == Start::MoreFollows;
            return Ok((
                Read::Manufacturer {
                    record,
                    more_follows,
                },
                rest.len(),
            ));
        }
        Start::Data(dib) => dib,
    };
    let (vib, vlen) = vif::read(&rest[dlen..], at)?;
    let meaning = vife::meaning(&vib);
    let head = dlen + vlen;
    let field = &rest[head..];
    let (len, value) = data_field(dib.coding, field, &meaning, at)?;
    let record = Record {
        index,
        function: dib.function,
        storage: dib.storage,
        tariff: dib.tariff,
        subunit: dib.subunit,
        coding: Some(dib.coding),
        meaning,
        value,
        bytes: rest[..head + len].to_vec(),
    };
    Ok((Read::Record(record), head + len))
}

/// DIF 0F/1F: the rest of the telegram is the manufacturer's.
fn manufacturer(rest: &[u8], index: usize) -> Record {
    let dib = Dib {
        function: Function::Instantaneous,
        coding: Coding::None,
        storage: 0,
        tariff: 0,
        subunit: 0,
        bytes: vec![rest[0]],
    };
    let vib = Vib {
        bytes: vec![0x7F],
        text: None,
        text_before_vifes: false,
    };
    Record {
        index,
        function: dib.function,
        storage: 0,
        tariff: 0,
        subunit: 0,
        coding: None,
        meaning: vife::meaning(&vib),
        value: Value::Bytes(rest[1..].to_vec()),
        bytes: rest.to_vec(),
    }
}

/// The data field's length and value.
fn data_field(
    coding: Coding,
    field: &[u8],
    meaning: &Meaning,
    at: usize,
) -> Result<(usize, Value), DecodeError> {
    let short = || DecodeError::PrematureEnd { at, part: "data" };
    if let Some(len) = coding.data_len() {
        let bytes = field.get(..len).ok_or_else(short)?;
        return Ok((len, fixed_value(coding, bytes, meaning)));
    }
    let lvar = *field.first().ok_or_else(short)?;
    let (len, kind) = match lvar {
        0x00..=0xBF => (usize::from(lvar), Lvar::Text),
        0xC0..=0xC9 => (usize::from(lvar - 0xC0), Lvar::Bcd { negative: false }),
        0xD0..=0xD9 => (usize::from(lvar - 0xD0), Lvar::Bcd { negative: true }),
        0xE0..=0xEF => (usize::from(lvar - 0xE0), Lvar::Binary),
        0xF0..=0xF4 => (4 * usize::from(lvar - 0xEC), Lvar::Binary),
        0xF5 => (48, Lvar::Binary),
        0xF6 => (64, Lvar::Binary),
        _ => return Err(DecodeError::ReservedLvar { at, lvar }),
    };
    let bytes = field.get(1..1 + len).ok_or_else(short)?;
    let value = match kind {
        Lvar::Text => Value::Text(bytes.iter().rev().map(|b| char::from(*b)).collect()),
        Lvar::Bcd { negative } => match value::bcd_le(bytes).scaled(meaning.exp) {
            Value::Number(e) if negative => Value::Number(Exact { raw: -e.raw, ..e }),
            other => other,
        },
        Lvar::Binary if len <= 8 && len > 0 => number(value::int_le(bytes), meaning),
        Lvar::Binary => Value::Bytes(bytes.to_vec()),
    };
    Ok((1 + len, value))
}

enum Lvar {
    Text,
    Bcd { negative: bool },
    Binary,
}

fn number(raw: i64, meaning: &Meaning) -> Value {
    Value::Number(Exact {
        raw,
        exp: meaning.exp,
    })
}

/// A data field of the length the DIF gives.
fn fixed_value(coding: Coding, bytes: &[u8], meaning: &Meaning) -> Value {
    match coding {
        Coding::None | Coding::Selection | Coding::Variable => Value::Empty,
        Coding::Int(_) if meaning.time_point => time_point(bytes),
        Coding::Int(_) => number(value::int_le(bytes), meaning),
        Coding::Bcd(_) => value::bcd_le(bytes).scaled(meaning.exp),
        Coding::Real => {
            let value = f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
            Value::Real {
                value,
                exp: meaning.exp,
            }
        }
    }
}

/// A date (2 bytes, type G), a date and time (4 bytes type F, 6 bytes type I), or bytes.
fn time_point(bytes: &[u8]) -> Value {
    match bytes.len() {
        2 => Value::Date(value::date_g([bytes[0], bytes[1]])),
        4 => Value::DateTime(value::date_time_f([bytes[0], bytes[1], bytes[2], bytes[3]])),
        6 => Value::DateTime(value::date_time_i(std::array::from_fn(|i| bytes[i]))),
        _ => Value::Bytes(bytes.to_vec()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one(bytes: &[u8]) -> Record {
        match read(bytes, 0, 0).unwrap().0 {
            Read::Record(r) => r,
            _ => panic!("not a data record"),
        }
    }

    #[test]
    fn a_volume_in_litres_is_an_exact_number_in_cubic_metres() {
        let r = one(&[0x04, 0x13, 0x39, 0x30, 0x00, 0x00]);
        assert_eq!(
            r.value,
            Value::Number(Exact {
                raw: 12345,
                exp: -3
            })
        );
        assert_eq!(r.unit(), Some(&Unit::M3));
        assert_eq!(r.value.to_decimal_string().unwrap(), "12.345");
    }

    #[test]
    fn a_date_record_reads_type_g() {
        let r = one(&[0x42, 0x6C, 0xDF, 0x1C]);
        assert_eq!(r.storage, 1);
        assert_eq!(r.value.to_decimal_string(), None);
        assert!(matches!(r.value, Value::Date(d) if d.to_string() == "2014-12-31"));
    }

    #[test]
    fn variable_length_text_is_read_in_reverse() {
        let r = one(&[0x0D, 0xFD, 0x0C, 0x03, b'C', b'B', b'A']);
        assert_eq!(r.value, Value::Text("ABC".into()));
    }

    #[test]
    fn a_record_cut_short_is_a_typed_error() {
        assert!(matches!(
            read(&[0x04, 0x13, 0x39], 0, 0),
            Err(DecodeError::PrematureEnd { part: "data", .. })
        ));
        assert!(matches!(
            read(&[0x0D, 0x13, 0xFA], 0, 0),
            Err(DecodeError::ReservedLvar { lvar: 0xFA, .. })
        ));
    }
}
