//! The simulator's own small M-Bus wire code, written from EN 13757-2/-3 and not from the
//! gateway's decoder (`mbus::driver`), so the two do not agree by construction: the requests a
//! meter understands, the answers it builds, and what the bus makes of answers that overlap.
//! Pure.

/// The single character acknowledgement.
pub const E5: u8 = 0xE5;

/// A request as a meter reads it off the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// `10 C A CS 16`.
    Short { c: u8, a: u8 },
    /// `68 L L 68 C A CI data CS 16`.
    Long { c: u8, a: u8, ci: u8, data: Vec<u8> },
}

/// Sum of the bytes, modulo 256.
pub fn sum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |s: u8, b| s.wrapping_add(*b))
}

/// The length of the request starting at `buf[0]`, once `buf` holds enough to tell: `None`
/// while it does not. A byte that starts no request is a request of length 1 (dropped).
pub fn request_len(buf: &[u8]) -> Option<usize> {
    match buf.first()? {
        0x10 => Some(5),
        0x68 => buf.get(1).map(|l| usize::from(*l) + 6),
        _ => Some(1),
    }
}

/// Reads one whole request; `None` for anything a meter would ignore (bad checksum, stop
/// byte, lengths that differ, noise).
pub fn read_request(b: &[u8]) -> Option<Request> {
    match b {
        [0x10, c, a, cs, 0x16] if sum(&[*c, *a]) == *cs => Some(Request::Short { c: *c, a: *a }),
        [0x68, l1, l2, 0x68, body @ .., cs, 0x16]
            if l1 == l2
                && usize::from(*l1) == body.len()
                && body.len() >= 3
                && sum(body) == *cs =>
        {
            Some(Request::Long {
                c: body[0],
                a: body[1],
                ci: body[2],
                data: body[3..].to_vec(),
            })
        }
        _ => None,
    }
}

/// A long frame from a slave: `68 L L 68 08 A CI data CS 16` (RSP_UD).
pub fn rsp_ud(address: u8, ci: u8, data: &[u8]) -> Vec<u8> {
    let len = (data.len() + 3) as u8;
    let mut out = vec![0x68, len, len, 0x68, 0x08, address, ci];
    out.extend_from_slice(data);
    out.push(sum(&out[4..]));
    out.push(0x16);
    out
}

/// `n` (0 ≤ n < 10^(2·bytes)) as BCD, least significant byte first (data type A).
pub fn bcd(mut n: u64, bytes: usize) -> Vec<u8> {
    (0..bytes)
        .map(|_| {
            let lo = (n % 10) as u8;
            let hi = ((n / 10) % 10) as u8;
            n /= 100;
            (hi << 4) | lo
        })
        .collect()
}

/// The 16-bit manufacturer code of three letters A–Z: 5 bits per letter, `A` = 1.
pub fn manufacturer(letters: [u8; 3]) -> u16 {
    letters.iter().fold(0, |acc, l| {
        (acc << 5) | u16::from(l.saturating_sub(b'@') & 0x1F)
    })
}

/// The 8 bytes of a secondary address: id (BCD, LSB first), manufacturer (LSB first),
/// version, medium.
pub fn secondary(id: u32, letters: [u8; 3], version: u8, medium: u8) -> [u8; 8] {
    let id = bcd(u64::from(id), 4);
    let m = manufacturer(letters).to_le_bytes();
    [id[0], id[1], id[2], id[3], m[0], m[1], version, medium]
}

/// Whether a select's 8 bytes name `own` (a secondary address's 8 bytes): an id nibble F, a
/// manufacturer FFFF, a version or medium FF match anything.
pub fn selects(mask: &[u8], own: &[u8; 8]) -> bool {
    if mask.len() != 8 {
        return false;
    }
    let nibbles_match = (0..4).all(|i| {
        let (m, o) = (mask[i], own[i]);
        (m >> 4 == 0xF || m >> 4 == o >> 4) && (m & 0xF == 0xF || m & 0xF == o & 0xF)
    });
    let manufacturer_match = mask[4..6] == [0xFF, 0xFF] || mask[4..6] == own[4..6];
    let byte_match = |i: usize| mask[i] == 0xFF || mask[i] == own[i];
    nibbles_match && manufacturer_match && byte_match(6) && byte_match(7)
}

/// What the master hears when several slaves answer at once: their bits on the bus at the
/// same time (a space from any slave wins), each a few bit times later than the one before,
/// so no answer survives whole.
pub fn collide(answers: &[Vec<u8>]) -> Vec<u8> {
    let len = answers.iter().map(Vec::len).max().unwrap_or(0) + 1;
    let mut out = vec![0xFF; len];
    for (k, answer) in answers.iter().enumerate() {
        let shift = 3 * k as u32 % 8;
        let mut carry = 0xFFu16;
        for (i, slot) in out.iter_mut().enumerate() {
            let byte = u16::from(*answer.get(i).unwrap_or(&0xFF));
            let wide = (carry << 8 | byte) >> shift;
            *slot &= wide as u8;
            carry = byte;
        }
    }
    out
}

/// Data information field codings the simulated meters use.
pub mod dif {
    /// 16-bit integer.
    pub const INT16: u8 = 0x02;
    /// 32-bit integer.
    pub const INT32: u8 = 0x04;
    /// 8-digit BCD.
    pub const BCD8: u8 = 0x0C;
    /// More records follow in the next telegram.
    pub const MORE: u8 = 0x1F;
}

/// Value information field codes of the primary table the simulated meters use.
pub mod vif {
    /// Energy in Wh (E000 0011: 10^(3-3) Wh).
    pub const WH: u8 = 0x03;
    /// Energy in kWh (E000 0110: 10^(6-3) Wh).
    pub const KWH: u8 = 0x06;
    /// Volume in litres (E001 0011: 10^(3-6) m³).
    pub const LITRE: u8 = 0x13;
    /// Power in W (E010 1011: 10^(3-3) W).
    pub const WATT: u8 = 0x2B;
    /// Volume flow in l/h (E011 1011: 10^(3-6) m³/h).
    pub const LITRE_PER_HOUR: u8 = 0x3B;
    /// Flow temperature in 0.01 °C (E101 10nn, nn = 1).
    pub const FLOW_CENTI_C: u8 = 0x59;
    /// Return temperature in 0.01 °C (E101 11nn, nn = 1).
    pub const RETURN_CENTI_C: u8 = 0x5D;
    /// Fabrication number.
    pub const FABRICATION: u8 = 0x78;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bcd_and_manufacturer_codes_are_the_standards() {
        assert_eq!(bcd(12345678, 4), [0x78, 0x56, 0x34, 0x12]);
        assert_eq!(manufacturer(*b"KAM"), 0x2C2D);
        assert_eq!(
            secondary(14491001, *b"KAM", 1, 4),
            [0x01, 0x10, 0x49, 0x14, 0x2D, 0x2C, 1, 4]
        );
    }

    #[test]
    fn requests_are_read_only_when_whole_and_summed_right() {
        assert_eq!(
            read_request(&[0x10, 0x7B, 0x01, 0x7C, 0x16]),
            Some(Request::Short { c: 0x7B, a: 1 })
        );
        assert_eq!(read_request(&[0x10, 0x7B, 0x01, 0x7D, 0x16]), None);
        assert_eq!(request_len(&[0x68, 0x0B]), Some(17));
        assert_eq!(request_len(&[0x68]), None);
    }

    #[test]
    fn a_select_matches_by_digit_with_f_as_any() {
        let own = secondary(12345678, *b"KAM", 1, 4);
        assert!(selects(
            &[0xFF, 0xFF, 0xFF, 0x1F, 0xFF, 0xFF, 0xFF, 0xFF],
            &own
        ));
        assert!(!selects(
            &[0xFF, 0xFF, 0xFF, 0x2F, 0xFF, 0xFF, 0xFF, 0xFF],
            &own
        ));
        assert!(selects(&own, &own));
        assert!(!selects(&[0x78, 0x56, 0x34, 0x12, 0x2D, 0x2C, 2, 4], &own));
    }

    #[test]
    fn two_acks_at_once_are_no_ack() {
        let heard = collide(&[vec![E5], vec![E5]]);
        assert_ne!(heard.first(), Some(&E5));
    }
}
