//! The headers an answer's CI field announces (EN 13757-3): the long header of CI 0x72
//! (secondary address, access number, status, signature), the short one of 0x7A, none for
//! 0x78. Pure.

use super::address::SecondaryAddress;

/// The header of a variable data answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Header {
    /// CI 0x72: the slave's secondary address, then access, status, signature.
    Long {
        address: SecondaryAddress,
        access: u8,
        status: u8,
        signature: u16,
    },
    /// CI 0x7A.
    Short {
        access: u8,
        status: u8,
        signature: u16,
    },
    /// CI 0x78.
    None,
    /// CI 0x73: the fixed data structure's id (BCD nibbles), access, status and medium.
    Fixed {
        id: u32,
        access: u8,
        status: u8,
        medium: u8,
    },
}

/// Long header length.
pub const LONG: usize = 12;
/// Short header length.
pub const SHORT: usize = 4;

/// Reads a long header (`b` has at least [`LONG`] bytes).
pub fn long(b: &[u8]) -> Header {
    Header::Long {
        address: SecondaryAddress::from_bytes(std::array::from_fn(|i| b[i])),
        access: b[8],
        status: b[9],
        signature: u16::from_le_bytes([b[10], b[11]]),
    }
}

/// Reads a short header (`b` has at least [`SHORT`] bytes).
pub fn short(b: &[u8]) -> Header {
    Header::Short {
        access: b[0],
        status: b[1],
        signature: u16::from_le_bytes([b[2], b[3]]),
    }
}

impl Header {
    /// The status byte, where the header has one.
    pub fn status(&self) -> Option<u8> {
        match self {
            Header::Long { status, .. }
            | Header::Short { status, .. }
            | Header::Fixed { status, .. } => Some(*status),
            Header::None => None,
        }
    }

    /// The secondary address, where the header carries one.
    pub fn address(&self) -> Option<&SecondaryAddress> {
        match self {
            Header::Long { address, .. } => Some(address),
            _ => None,
        }
    }
}

/// What the status byte of a variable data header says (bits 0–4; 5–7 are the
/// manufacturer's), in words; empty when all is well.
pub fn status_problems(status: u8) -> Vec<&'static str> {
    let mut out = Vec::new();
    match status & 0x03 {
        1 => out.push("application busy"),
        2 => out.push("application error"),
        3 => out.push("abnormal condition / alarm"),
        _ => {}
    }
    for (bit, text) in [
        (0x04, "power low"),
        (0x08, "permanent error"),
        (0x10, "temporary error"),
    ] {
        if status & bit != 0 {
            out.push(text);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_status_byte_names_busy_errors_and_low_power() {
        assert!(status_problems(0x00).is_empty());
        assert_eq!(status_problems(0x01), ["application busy"]);
        assert_eq!(
            status_problems(0x0E),
            ["application error", "power low", "permanent error"]
        );
        assert!(
            status_problems(0xE0).is_empty(),
            "bits 5-7 are the manufacturer's"
        );
    }
}
