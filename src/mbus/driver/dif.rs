//! The data information block: DIF and up to ten DIFEs (EN 13757-3): what the data field
//! holds (coding and length), the function, storage number, tariff and subunit. Pure.

use super::error::DecodeError;

/// The standard's limit of DIFEs in one record.
pub const MAX_DIFE: usize = 10;

/// What a value is of: the instant, a maximum, a minimum, or a value during an error state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Function {
    Instantaneous,
    Maximum,
    Minimum,
    DuringError,
}

impl Function {
    fn from_bits(bits: u8) -> Function {
        match bits & 0x3 {
            0 => Function::Instantaneous,
            1 => Function::Maximum,
            2 => Function::Minimum,
            _ => Function::DuringError,
        }
    }

    /// The function as the standard names it.
    pub fn name(&self) -> &'static str {
        match self {
            Function::Instantaneous => "instantaneous",
            Function::Maximum => "maximum",
            Function::Minimum => "minimum",
            Function::DuringError => "value during error state",
        }
    }
}

/// How the data field is coded (DIF bits 0–3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Coding {
    /// No data.
    None,
    /// Signed binary integer of this many bytes (1, 2, 3, 4, 6, 8).
    Int(u8),
    /// 32-bit IEEE real.
    Real,
    /// Selection for readout (a master's request; no data).
    Selection,
    /// BCD of this many bytes (1, 2, 3, 4, 6: 2 to 12 digits).
    Bcd(u8),
    /// Variable length: the first data byte (LVAR) says what follows.
    Variable,
}

impl Coding {
    fn from_nibble(n: u8) -> Coding {
        match n & 0x0F {
            0x0 => Coding::None,
            0x1 => Coding::Int(1),
            0x2 => Coding::Int(2),
            0x3 => Coding::Int(3),
            0x4 => Coding::Int(4),
            0x5 => Coding::Real,
            0x6 => Coding::Int(6),
            0x7 => Coding::Int(8),
            0x8 => Coding::Selection,
            0x9 => Coding::Bcd(1),
            0xA => Coding::Bcd(2),
            0xB => Coding::Bcd(3),
            0xC => Coding::Bcd(4),
            0xE => Coding::Bcd(6),
            // 0xD; 0xF (special functions) is read before a Dib is made.
            _ => Coding::Variable,
        }
    }

    /// The data field's length in bytes, where the DIF alone says it.
    pub fn data_len(&self) -> Option<usize> {
        match self {
            Coding::None | Coding::Selection => Some(0),
            Coding::Int(n) | Coding::Bcd(n) => Some(usize::from(*n)),
            Coding::Real => Some(4),
            Coding::Variable => None,
        }
    }
}

/// A record's data information block, read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Dib {
    pub function: Function,
    pub coding: Coding,
    /// Storage number (0 = the current value; 1… stored values).
    pub storage: u64,
    pub tariff: u32,
    pub subunit: u16,
    /// The DIF and DIFEs as sent.
    pub bytes: Vec<u8>,
}

/// What starts a record: a data record's DIB, or one of the special DIFs (data field F).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Start {
    Data(Dib),
    /// `0F`: manufacturer data to the end of the telegram.
    Manufacturer,
    /// `1F`: manufacturer data to the end, and more records follow in the next telegram.
    MoreFollows,
    /// `2F`: idle filler, skipped.
    Filler,
}

/// Reads the DIB at the start of `data`; returns it and its length.
pub fn read(data: &[u8], at: usize) -> Result<(Start, usize), DecodeError> {
    let Some(&dif) = data.first() else {
        return Err(DecodeError::PrematureEnd { at, part: "DIF" });
    };
    match dif {
        0x0F => return Ok((Start::Manufacturer, 1)),
        0x1F => return Ok((Start::MoreFollows, 1)),
        0x2F => return Ok((Start::Filler, 1)),
        d if d & 0x0F == 0x0F => return Err(DecodeError::ReservedDif { at, dif: d }),
        _ => {}
    }
    let mut dib = Dib {
        function: Function::from_bits(dif >> 4),
        coding: Coding::from_nibble(dif),
        storage: u64::from((dif >> 6) & 1),
        tariff: 0,
        subunit: 0,
        bytes: vec![dif],
    };
    let mut last = dif;
    while last & 0x80 != 0 {
        let n = dib.bytes.len() - 1;
        if n == MAX_DIFE {
            return Err(DecodeError::TooManyDifes { at });
        }
        let Some(&dife) = data.get(n + 1) else {
            return Err(DecodeError::PrematureEnd { at, part: "DIFE" });
        };
        dib.storage |= u64::from(dife & 0x0F) << (1 + 4 * n);
        dib.tariff |= u32::from((dife >> 4) & 0x3) << (2 * n);
        dib.subunit |= u16::from((dife >> 6) & 1) << n;
        dib.bytes.push(dife);
        last = dife;
    }
    let len = dib.bytes.len();
    Ok((Start::Data(dib), len))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dib(bytes: &[u8]) -> Dib {
        match read(bytes, 0).unwrap().0 {
            Start::Data(d) => d,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_dif_alone_says_coding_function_and_the_lowest_storage_bit() {
        let d = dib(&[0x4C]);
        assert_eq!(d.coding, Coding::Bcd(4));
        assert_eq!(d.function, Function::Instantaneous);
        assert_eq!(d.storage, 1);
        assert_eq!(dib(&[0x14]).function, Function::Maximum);
    }

    #[test]
    fn difes_add_the_higher_bits_of_storage_tariff_and_subunit() {
        // 8C 10: tariff 1; 84 40: subunit 1; C4 81 01: storage 1 + (1 << 1) + (1 << 5) = 35.
        assert_eq!(dib(&[0x8C, 0x10]).tariff, 1);
        assert_eq!(dib(&[0x84, 0x40]).subunit, 1);
        assert_eq!(dib(&[0xC4, 0x81, 0x01]).storage, 1 + 2 + 32);
        assert_eq!(dib(&[0x84, 0xA0, 0x30]).tariff, 2 + (3 << 2));
    }

    #[test]
    fn an_eleventh_dife_and_a_cut_dib_are_typed_errors() {
        let mut bytes = vec![0x84];
        bytes.extend([0x80; 11]);
        bytes.push(0x00);
        assert_eq!(
            read(&bytes, 7).unwrap_err(),
            DecodeError::TooManyDifes { at: 7 }
        );
        let mut ten = vec![0x84];
        ten.extend([0x80; 9]);
        ten.push(0x00);
        assert!(read(&ten, 0).is_ok());
        assert!(matches!(
            read(&[0x84], 0),
            Err(DecodeError::PrematureEnd { .. })
        ));
    }

    #[test]
    fn special_difs_are_told_apart() {
        assert_eq!(read(&[0x0F], 0).unwrap().0, Start::Manufacturer);
        assert_eq!(read(&[0x1F], 0).unwrap().0, Start::MoreFollows);
        assert_eq!(read(&[0x2F], 0).unwrap().0, Start::Filler);
        assert!(matches!(
            read(&[0x7F], 0),
            Err(DecodeError::ReservedDif { .. })
        ));
    }
}
