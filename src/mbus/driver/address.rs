//! Who a slave is: its secondary address (8-digit id, manufacturer, version, medium), as its
//! long header says and as a select frame asks for it, wildcards included. Pure.

use std::fmt;

/// A slave's secondary address, as its long header (CI 0x72) carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SecondaryAddress {
    /// The identification number's 8 BCD digits as nibbles (0x12345678 for id 12345678). A
    /// meter may send non-decimal nibbles; they are kept.
    pub id: u32,
    /// The manufacturer code as the 16-bit number on the wire (three letters packed).
    pub manufacturer: u16,
    pub version: u8,
    pub medium: u8,
}

impl SecondaryAddress {
    /// Reads the 8 bytes of a long header or a select frame: id (LSB first), manufacturer
    /// (LSB first), version, medium.
    pub fn from_bytes(b: [u8; 8]) -> SecondaryAddress {
        SecondaryAddress {
            id: u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            manufacturer: u16::from_le_bytes([b[4], b[5]]),
            version: b[6],
            medium: b[7],
        }
    }

    /// The 8 bytes on the wire.
    pub fn to_bytes(&self) -> [u8; 8] {
        let id = self.id.to_le_bytes();
        let m = self.manufacturer.to_le_bytes();
        [
            id[0],
            id[1],
            id[2],
            id[3],
            m[0],
            m[1],
            self.version,
            self.medium,
        ]
    }

    /// The id as 8 characters (`"12345678"`; a non-decimal nibble shows as its hex digit).
    pub fn id_text(&self) -> String {
        format!("{:08X}", self.id)
    }

    /// The three letters of the manufacturer (`"KAM"`).
    pub fn manufacturer_code(&self) -> String {
        manufacturer_code(self.manufacturer)
    }

    /// A mask matching exactly this address.
    pub fn mask(&self) -> SecondaryMask {
        SecondaryMask {
            id: std::array::from_fn(|i| Some(((self.id >> (28 - 4 * i)) & 0xF) as u8)),
            manufacturer: Some(self.manufacturer),
            version: Some(self.version),
            medium: Some(self.medium),
        }
    }
}

impl fmt::Display for SecondaryAddress {
    /// `12345678 KAM v1 medium 04`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {} v{} medium {:02X}",
            self.id_text(),
            self.manufacturer_code(),
            self.version,
            self.medium
        )
    }
}

/// The three letters of a manufacturer code: `((c1-64)<<10)|((c2-64)<<5)|(c3-64)`. A code
/// outside A–Z shows a `?` for the letter that is not one.
pub fn manufacturer_code(code: u16) -> String {
    [10, 5, 0]
        .iter()
        .map(|shift| match ((code >> shift) & 0x1F) as u8 {
            l @ 1..=26 => char::from(b'@' + l),
            _ => '?',
        })
        .collect()
}

/// The 16-bit code of three letters A–Z (`"KAM"` → 0x2C2D).
pub fn manufacturer_from_letters(letters: &str) -> Option<u16> {
    let b = letters.as_bytes();
    if b.len() != 3 || !b.iter().all(u8::is_ascii_uppercase) {
        return None;
    }
    Some(
        b.iter()
            .fold(0u16, |acc, c| (acc << 5) | u16::from(c - b'@')),
    )
}

/// Who a select frame asks for: each part either a value or a wildcard.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SecondaryMask {
    /// The id's 8 digits, most significant first; `None` is the wildcard nibble F.
    pub id: [Option<u8>; 8],
    /// `None`: any manufacturer (`FFFF` on the wire).
    pub manufacturer: Option<u16>,
    /// `None`: any version (`FF`).
    pub version: Option<u8>,
    /// `None`: any medium (`FF`).
    pub medium: Option<u8>,
}

/// Why a text is not a secondary address mask.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MaskError {
    #[error("{0:?}: a secondary address id has 8 digits 0-9, F or * for any digit")]
    Id(String),
    #[error("{0:?}: a manufacturer is three letters A-Z")]
    Manufacturer(String),
}

impl SecondaryMask {
    /// Matches every slave.
    pub const ANY: SecondaryMask = SecondaryMask {
        id: [None; 8],
        manufacturer: None,
        version: None,
        medium: None,
    };

    /// A mask from an id text: 8 characters, digits or `F`/`f`/`*` for any digit; everything
    /// else a wildcard.
    pub fn from_id(text: &str) -> Result<SecondaryMask, MaskError> {
        let bad = || MaskError::Id(text.to_string());
        if text.len() != 8 {
            return Err(bad());
        }
        let mut id = [None; 8];
        for (slot, c) in id.iter_mut().zip(text.chars()) {
            *slot = match c {
                '0'..='9' => Some(c as u8 - b'0'),
                'F' | 'f' | '*' => None,
                _ => return Err(bad()),
            };
        }
        Ok(SecondaryMask { id, ..Self::ANY })
    }

    /// The same mask with the manufacturer's three letters.
    pub fn with_manufacturer(self, letters: &str) -> Result<SecondaryMask, MaskError> {
        let code = manufacturer_from_letters(letters)
            .ok_or_else(|| MaskError::Manufacturer(letters.to_string()))?;
        Ok(SecondaryMask {
            manufacturer: Some(code),
            ..self
        })
    }

    /// The 8 bytes of a select frame's data.
    pub fn to_bytes(&self) -> [u8; 8] {
        let mut id = 0u32;
        for digit in self.id {
            id = (id << 4) | u32::from(digit.unwrap_or(0xF));
        }
        let id = id.to_le_bytes();
        let m = self.manufacturer.unwrap_or(0xFFFF).to_le_bytes();
        [
            id[0],
            id[1],
            id[2],
            id[3],
            m[0],
            m[1],
            self.version.unwrap_or(0xFF),
            self.medium.unwrap_or(0xFF),
        ]
    }

    /// Reads a select frame's 8 bytes: F nibbles and FF/FFFF bytes are wildcards.
    pub fn from_bytes(b: [u8; 8]) -> SecondaryMask {
        let id = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let nibble = |i: usize| ((id >> (28 - 4 * i)) & 0xF) as u8;
        let manufacturer = u16::from_le_bytes([b[4], b[5]]);
        SecondaryMask {
            id: std::array::from_fn(|i| Some(nibble(i)).filter(|n| *n != 0xF)),
            manufacturer: Some(manufacturer).filter(|m| *m != 0xFFFF),
            version: Some(b[6]).filter(|v| *v != 0xFF),
            medium: Some(b[7]).filter(|m| *m != 0xFF),
        }
    }

    /// Whether a slave with `address` answers a select with this mask.
    pub fn matches(&self, address: &SecondaryAddress) -> bool {
        let own = address.mask();
        let same = |want: Option<u8>, have: Option<u8>| want.is_none() || want == have;
        self.id.iter().zip(own.id).all(|(w, h)| same(*w, h))
            && (self.manufacturer.is_none() || self.manufacturer == own.manufacturer)
            && same(self.version, own.version)
            && same(self.medium, own.medium)
    }

    /// The id as text, `F` for a wildcard digit (`"12FFFFFF"`).
    pub fn id_text(&self) -> String {
        self.id
            .iter()
            .map(|d| d.map_or('F', |d| char::from(b'0' + d.min(9))))
            .collect()
    }
}

/// The medium's name by the standard's table (EN 13757-3 medium codes).
pub fn medium_name(medium: u8) -> &'static str {
    const NAMES: [&str; 0x1C] = [
        "other",
        "oil",
        "electricity",
        "gas",
        "heat (outlet)",
        "steam",
        "warm water",
        "water",
        "heat cost allocator",
        "compressed air",
        "cooling (outlet)",
        "cooling (inlet)",
        "heat (inlet)",
        "heat/cooling",
        "bus/system component",
        "unknown medium",
        "irrigation water",
        "water data logger",
        "gas data logger",
        "gas converter",
        "calorific value",
        "hot water",
        "cold water",
        "dual register water",
        "pressure",
        "A/D converter",
        "smoke detector",
        "room sensor",
    ];
    NAMES
        .get(usize::from(medium))
        .copied()
        .unwrap_or("reserved")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manufacturer_code_is_three_letters_both_ways() {
        assert_eq!(manufacturer_code(0x2C2D), "KAM");
        assert_eq!(manufacturer_from_letters("KAM"), Some(0x2C2D));
        assert_eq!(manufacturer_from_letters("kam"), None);
        assert_eq!(manufacturer_code(0), "???");
    }

    #[test]
    fn a_mask_with_wildcards_matches_only_the_digits_it_names() {
        let meter = SecondaryAddress::from_bytes([0x78, 0x56, 0x34, 0x12, 0x2D, 0x2C, 1, 4]);
        assert_eq!(meter.id_text(), "12345678");
        let mask = SecondaryMask::from_id("12FFFFFF").unwrap();
        assert!(mask.matches(&meter));
        assert!(!SecondaryMask::from_id("13FFFFFF").unwrap().matches(&meter));
        assert!(SecondaryMask::ANY.matches(&meter));
        assert!(meter.mask().matches(&meter));
        let other_maker = mask.with_manufacturer("ELS").unwrap();
        assert!(!other_maker.matches(&meter));
    }

    #[test]
    fn a_mask_goes_to_the_wire_with_f_nibbles_and_ff_bytes_and_back() {
        let mask = SecondaryMask::from_id("1234567F").unwrap();
        assert_eq!(
            mask.to_bytes(),
            [0x7F, 0x56, 0x34, 0x12, 0xFF, 0xFF, 0xFF, 0xFF]
        );
        assert_eq!(SecondaryMask::from_bytes(mask.to_bytes()), mask);
        assert_eq!(mask.id_text(), "1234567F");
    }
}
