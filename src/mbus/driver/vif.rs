//! The value information block: VIF, up to ten VIFEs and a plain-text unit (EN 13757-3),
//! read from the bytes; [`super::vif_table`] and [`super::vife`] say what they mean. Pure.

use super::error::DecodeError;

/// The standard's limit of VIFEs in one record.
pub const MAX_VIFE: usize = 10;

/// A record's value information block, as sent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Vib {
    /// The VIF and its VIFEs.
    pub bytes: Vec<u8>,
    /// The unit of a plain-text VIF (7C/FC), in reading order.
    pub text: Option<String>,
    /// The plain-text unit came right after an FC VIF, before its VIFEs (what Elvaco CMa10
    /// meters send), not after the VIFEs as the standard places it.
    pub text_before_vifes: bool,
}

impl Vib {
    /// The VIF.
    pub fn vif(&self) -> u8 {
        self.bytes[0]
    }

    /// The VIFEs.
    pub fn vifes(&self) -> &[u8] {
        &self.bytes[1..]
    }
}

/// Reads the VIB at the start of `data` (`at` is its offset in the telegram, for errors);
/// returns it and its length.
pub fn read(data: &[u8], at: usize) -> Result<(Vib, usize), DecodeError> {
    let Some(&vif) = data.first() else {
        return Err(DecodeError::PrematureEnd { at, part: "VIF" });
    };
    if vif & 0x7F != 0x7C {
        let (bytes, len) = extensions(data, at)?;
        return Ok((
            Vib {
                bytes,
                text: None,
                text_before_vifes: false,
            },
            len,
        ));
    }
    if vif == 0x7C {
        let (text, len) = plain_text(&data[1..], at)?;
        let vib = Vib {
            bytes: vec![vif],
            text: Some(text),
            text_before_vifes: false,
        };
        return Ok((vib, 1 + len));
    }
    // FC: the standard puts the length and text after the VIFEs; some meters put them
    // right after the VIF. The standard's place first; the other where that cannot be read.
    let standard = extensions(data, at).and_then(|(bytes, len)| {
        let (text, tlen) = plain_text(&data[len..], at)?;
        Ok((bytes, Some(text), len + tlen))
    });
    let (bytes, text, len, early) = match standard {
        Ok((bytes, text, len)) => (bytes, text, len, false),
        Err(first) => {
            let Ok((text, tlen)) = plain_text(&data[1..], at) else {
                return Err(first);
            };
            let mut rest = vec![vif];
            rest.extend_from_slice(&data[1 + tlen..]);
            let (bytes, len) = extensions(&rest, at)?;
            (bytes, Some(text), len + tlen, true)
        }
    };
    let vib = Vib {
        bytes,
        text,
        text_before_vifes: early,
    };
    Ok((vib, len))
}

/// The VIF and the VIFEs its extension bits chain to.
fn extensions(data: &[u8], at: usize) -> Result<(Vec<u8>, usize), DecodeError> {
    let mut bytes = vec![data[0]];
    while bytes[bytes.len() - 1] & 0x80 != 0 {
        if bytes.len() > MAX_VIFE {
            return Err(DecodeError::TooManyVifes { at });
        }
        let Some(&vife) = data.get(bytes.len()) else {
            return Err(DecodeError::PrematureEnd { at, part: "VIFE" });
        };
        bytes.push(vife);
    }
    let len = bytes.len();
    Ok((bytes, len))
}

/// A length byte and that many printable ASCII characters, sent last character first.
fn plain_text(data: &[u8], at: usize) -> Result<(String, usize), DecodeError> {
    let Some(&len) = data.first() else {
        return Err(DecodeError::PrematureEnd {
            at,
            part: "plain-text unit",
        });
    };
    let len = usize::from(len);
    let Some(chars) = data.get(1..1 + len) else {
        return Err(DecodeError::PlainTextOverrun { at, len });
    };
    if !chars.iter().all(|c| (0x20..0x7F).contains(c)) {
        return Err(DecodeError::PlainTextNotAscii { at });
    }
    let text = chars.iter().rev().map(|c| char::from(*c)).collect();
    Ok((text, 1 + len))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_vif_chains_its_vifes_by_the_extension_bit() {
        let (vib, len) = read(&[0x84, 0x90, 0x28, 0xAA], 0).unwrap();
        assert_eq!(vib.bytes, [0x84, 0x90, 0x28]);
        assert_eq!(len, 3);
    }

    #[test]
    fn an_eleventh_vife_is_a_typed_error_and_ten_are_fine() {
        let mut ten = vec![0x84];
        ten.extend([0x80; 9]);
        ten.push(0x00);
        assert_eq!(read(&ten, 0).unwrap().1, 11);
        let mut eleven = vec![0x84];
        eleven.extend([0x80; 10]);
        eleven.push(0x00);
        assert_eq!(
            read(&eleven, 5).unwrap_err(),
            DecodeError::TooManyVifes { at: 5 }
        );
    }

    #[test]
    fn a_plain_text_unit_is_read_in_reverse() {
        // 7C 03 "HR%" (sent reversed) → "%RH".
        let (vib, len) = read(&[0x7C, 0x03, 0x48, 0x52, 0x25], 0).unwrap();
        assert_eq!(vib.text.as_deref(), Some("%RH"));
        assert_eq!(len, 5);
    }

    #[test]
    fn an_fc_text_is_read_after_the_vifes_or_else_right_after_the_vif() {
        // The standard's place: FC 74, then 03 "HR%".
        let (vib, len) = read(&[0xFC, 0x74, 0x03, 0x48, 0x52, 0x25], 0).unwrap();
        assert_eq!((vib.bytes.as_slice(), len), (&[0xFC, 0x74][..], 6));
        assert!(!vib.text_before_vifes);
        // Elvaco's: FC 03 "HR%" 74.
        let (vib, len) = read(&[0xFC, 0x03, 0x48, 0x52, 0x25, 0x74, 0xD4], 0).unwrap();
        assert_eq!((vib.bytes.as_slice(), len), (&[0xFC, 0x74][..], 6));
        assert_eq!(vib.text.as_deref(), Some("%RH"));
        assert!(vib.text_before_vifes);
    }

    #[test]
    fn a_text_longer_than_the_telegram_is_a_typed_error() {
        assert_eq!(
            read(&[0x7C, 0x13, 0x48], 9).unwrap_err(),
            DecodeError::PlainTextOverrun { at: 9, len: 0x13 }
        );
    }
}
