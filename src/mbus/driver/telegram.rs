//! An answer's application layer (EN 13757-3): the CI field picks the header and the data
//! structure; the records are read one by one, every overrun a typed error. Pure.

use super::error::{ApplicationError, DecodeError, MAX_RECORDS};
use super::fixed;
use super::frame::{Frame, RSP_UD};
use super::header::{self, Header};
use super::record::{self, Read, Record};

/// A decoded answer: its header and records.
#[derive(Debug, Clone, PartialEq)]
pub struct Telegram {
    pub ci: u8,
    pub header: Header,
    pub records: Vec<Record>,
    /// DIF 0x1F: the meter has more records, in the next telegram (ask again with the FCB
    /// toggled).
    pub more_records_follow: bool,
}

/// Decodes the application layer of a slave's answer frame.
pub fn decode_frame(frame: &Frame) -> Result<Telegram, DecodeError> {
    match frame {
        Frame::Long {
            control, ci, data, ..
        } if control & 0x4F == RSP_UD => decode(*ci, data),
        Frame::Control { control, ci, .. } if control & 0x4F == RSP_UD => decode(*ci, &[]),
        Frame::Long { control, .. } | Frame::Control { control, .. } => {
            Err(DecodeError::NotUserData(*control))
        }
        Frame::Ack | Frame::Short { .. } => Err(DecodeError::NoData),
    }
}

/// Decodes the data after the CI field `ci`.
pub fn decode(ci: u8, data: &[u8]) -> Result<Telegram, DecodeError> {
    let (header, body) = match ci {
        0x70 => {
            return Err(DecodeError::Application(ApplicationError(
                data.first().copied(),
            )));
        }
        0x71 => return Err(DecodeError::AlarmStatus(data.first().copied())),
        0x72 => (
            header::long(need(ci, data, header::LONG)?),
            &data[header::LONG..],
        ),
        0x7A => (
            header::short(need(ci, data, header::SHORT)?),
            &data[header::SHORT..],
        ),
        0x78 => (Header::None, data),
        0x73 => {
            let (header, records) = fixed::decode(data)?;
            return Ok(Telegram {
                ci,
                header,
                records,
                more_records_follow: false,
            });
        }
        0x76 | 0x77 => return Err(DecodeError::MsbFirst(ci)),
        other => return Err(DecodeError::UnknownCi(other)),
    };
    let offset = data.len() - body.len();
    let (records, more_records_follow) = records(body, offset)?;
    Ok(Telegram {
        ci,
        header,
        records,
        more_records_follow,
    })
}

fn need(ci: u8, data: &[u8], len: usize) -> Result<&[u8], DecodeError> {
    if data.len() < len {
        return Err(DecodeError::HeaderTooShort {
            ci,
            need: len,
            have: data.len(),
        });
    }
    Ok(data)
}

/// The records of a variable data structure; `offset` is where `body` starts in the data.
fn records(body: &[u8], offset: usize) -> Result<(Vec<Record>, bool), DecodeError> {
    let mut records = Vec::new();
    let mut at = 0;
    while at < body.len() {
        if records.len() == MAX_RECORDS {
            return Err(DecodeError::TooManyRecords);
        }
        let (read, len) = record::read(body, at, records.len()).map_err(|e| shift(e, offset))?;
        at += len;
        match read {
            Read::Filler => {}
            Read::Record(r) => records.push(r),
            Read::Manufacturer {
                record,
                more_follows,
            } => {
                records.push(record);
                return Ok((records, more_follows));
            }
        }
    }
    Ok((records, false))
}

/// An error's offset counted from the start of the data, not of the records.
fn shift(e: DecodeError, by: usize) -> DecodeError {
    use DecodeError as E;
    match e {
        E::PrematureEnd { at, part } => E::PrematureEnd { at: at + by, part },
        E::TooManyDifes { at } => E::TooManyDifes { at: at + by },
        E::TooManyVifes { at } => E::TooManyVifes { at: at + by },
        E::ReservedDif { at, dif } => E::ReservedDif { at: at + by, dif },
        E::PlainTextOverrun { at, len } => E::PlainTextOverrun { at: at + by, len },
        E::PlainTextNotAscii { at } => E::PlainTextNotAscii { at: at + by },
        E::ReservedLvar { at, lvar } => E::ReservedLvar { at: at + by, lvar },
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn application_errors_alarms_and_unknown_ci_fields_are_typed_errors() {
        assert_eq!(
            decode(0x70, &[0x08]).unwrap_err().to_string(),
            "the meter reports an application error: application too busy to answer"
        );
        assert_eq!(
            decode(0x71, &[0x02]).unwrap_err(),
            DecodeError::AlarmStatus(Some(2))
        );
        assert_eq!(decode(0x77, &[]).unwrap_err(), DecodeError::MsbFirst(0x77));
        assert_eq!(decode(0x99, &[]).unwrap_err(), DecodeError::UnknownCi(0x99));
        assert_eq!(
            decode(0x72, &[0; 5]).unwrap_err(),
            DecodeError::HeaderTooShort {
                ci: 0x72,
                need: 12,
                have: 5
            }
        );
    }

    #[test]
    fn a_short_header_and_no_header_read_their_records() {
        // 7A: access 01, status 00, signature 00 00; then 01 FD 1B 05 (digital input 5).
        let t = decode(0x7A, &[0x01, 0x00, 0x00, 0x00, 0x01, 0xFD, 0x1B, 0x05]).unwrap();
        assert_eq!(t.records.len(), 1);
        assert_eq!(t.header.status(), Some(0));
        let t = decode(0x78, &[0x2F, 0x01, 0xFD, 0x1B, 0x05, 0x2F]).unwrap();
        assert_eq!(t.records.len(), 1, "fillers are skipped");
    }
}
