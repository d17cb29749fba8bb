//! Why an answer cannot be decoded: one typed error per cause, offsets counted from the
//! first byte after the CI field. Pure.

use std::fmt;

/// The most records one telegram may hold (a long frame of 252 data bytes holds at most
/// 126 records of 2 bytes; more can only come from a corrupt or hostile buffer).
pub const MAX_RECORDS: usize = 128;

/// An application error the slave reported (CI 0x70), by the standard's codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ApplicationError(pub Option<u8>);

impl fmt::Display for ApplicationError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let text = match self.0 {
            None | Some(0) => "unspecified error",
            Some(1) => "unimplemented CI field",
            Some(2) => "buffer too long, truncated",
            Some(3) => "too many records",
            Some(4) => "premature end of record",
            Some(5) => "more than 10 DIFEs",
            Some(6) => "more than 10 VIFEs",
            Some(8) => "application too busy to answer",
            Some(9) => "too many readouts",
            Some(code) => return write!(f, "reserved application error code {code:#04x}"),
        };
        f.write_str(text)
    }
}

/// Why an answer cannot be decoded. `at` is the offset of the record at fault, counted from
/// the first byte after the CI field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("the meter reports an application error: {0}")]
    Application(ApplicationError),
    #[error("the meter answers with an alarm status ({0:?}), not with data (CI 0x71)")]
    AlarmStatus(Option<u8>),
    #[error("the answer is not user data (C field {0:#04x}, RSP_UD 0x08 expected)")]
    NotUserData(u8),
    #[error("a single character or short frame carries no data")]
    NoData,
    #[error("unknown CI field {0:#04x}")]
    UnknownCi(u8),
    #[error("CI field {0:#04x}: data with the most significant byte first is not supported")]
    MsbFirst(u8),
    #[error("CI field {ci:#04x}: its header needs {need} bytes, the answer has {have}")]
    HeaderTooShort { ci: u8, need: usize, have: usize },
    #[error("fixed data structure of {have} bytes (16 expected)")]
    FixedLength { have: usize },
    #[error("premature end of record at byte {at}: its {part} is cut off")]
    PrematureEnd { at: usize, part: &'static str },
    #[error("record at byte {at}: more than 10 DIFEs")]
    TooManyDifes { at: usize },
    #[error("record at byte {at}: more than 10 VIFEs")]
    TooManyVifes { at: usize },
    #[error("record at byte {at}: reserved special DIF {dif:#04x}")]
    ReservedDif { at: usize, dif: u8 },
    #[error("record at byte {at}: plain-text unit of {len} characters runs past the answer")]
    PlainTextOverrun { at: usize, len: usize },
    #[error("record at byte {at}: plain-text unit is not printable ASCII")]
    PlainTextNotAscii { at: usize },
    #[error("record at byte {at}: reserved variable-length code {lvar:#04x}")]
    ReservedLvar { at: usize, lvar: u8 },
    #[error("more than {MAX_RECORDS} records in one telegram")]
    TooManyRecords,
}
