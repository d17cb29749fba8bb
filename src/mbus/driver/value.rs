//! What a record's data field holds, exactly: an integer (binary or BCD) with its decimal
//! exponent, a real, a date, text or bytes. Pure.

use std::fmt;

/// A record's value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// `raw × 10^exp`, exactly (a 10^-3 m³ step: raw 12345, exp -3 is 12.345 m³).
    Number(Exact),
    /// A 32-bit real times `10^exp` (the VIF's scale still applies to a real).
    Real { value: f32, exp: i32 },
    /// Type G.
    Date(Date),
    /// Type F (minutes) or type I (seconds).
    DateTime(DateTime),
    /// A variable-length ASCII string (sent last character first; kept in reading order).
    Text(String),
    /// Bytes with no number in them: manufacturer data, long binary numbers, an unread date.
    Bytes(Vec<u8>),
    /// A BCD field holding digits A–E (meters mark errors so) or F other than as the sign:
    /// not a number. The digits as sent, most significant first.
    InvalidBcd(String),
    /// The data field is empty (DIF data field 0, or "selection for readout").
    Empty,
}

/// An exact decimal: `raw × 10^exp`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exact {
    pub raw: i64,
    pub exp: i32,
}

impl Exact {
    /// The number as a decimal text a person would write (`12.345`, `-0.5`, `1200`).
    pub fn to_decimal_string(&self) -> String {
        let digits = self.raw.unsigned_abs().to_string();
        let sign = if self.raw < 0 { "-" } else { "" };
        if self.exp >= 0 {
            if self.raw == 0 {
                return "0".into();
            }
            let zeros = "0".repeat(self.exp as usize);
            return format!("{sign}{digits}{zeros}");
        }
        let places = self.exp.unsigned_abs() as usize;
        let padded = format!("{digits:0>width$}", width = places + 1);
        let (int, frac) = padded.split_at(padded.len() - places);
        let frac = frac.trim_end_matches('0');
        if frac.is_empty() {
            format!("{sign}{int}")
        } else {
            format!("{sign}{int}.{frac}")
        }
    }

    /// The nearest `f64` (from the decimal text, so 0.001 steps print as themselves).
    pub fn to_f64(&self) -> f64 {
        self.to_decimal_string().parse().unwrap_or(f64::NAN)
    }
}

impl fmt::Display for Exact {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.to_decimal_string())
    }
}

impl Value {
    /// The value as a number, where it is one.
    pub fn to_f64(&self) -> Option<f64> {
        match self {
            Value::Number(e) => Some(e.to_f64()),
            Value::Real { value, exp } => {
                let scaled = format!("{value}e{exp}");
                scaled.parse().ok()
            }
            _ => None,
        }
    }

    /// The value as an exact decimal text, where it is a number (a real prints as the
    /// shortest text that reads back as the same `f32`, then scaled).
    pub fn to_decimal_string(&self) -> Option<String> {
        match self {
            Value::Number(e) => Some(e.to_decimal_string()),
            Value::Real { .. } => self.to_f64().map(|v| v.to_string()),
            _ => None,
        }
    }

    /// The same value with its exponent moved by `by` (a VIFE's correction factor).
    pub fn scaled(self, by: i32) -> Value {
        match self {
            Value::Number(e) => Value::Number(Exact {
                raw: e.raw,
                exp: e.exp + by,
            }),
            Value::Real { value, exp } => Value::Real {
                value,
                exp: exp + by,
            },
            other => other,
        }
    }
}

/// A calendar date (type G). Fields are as sent: a meter may send zeros for "no date".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Date {
    pub year: u16,
    pub month: u8,
    pub day: u8,
}

impl Date {
    /// Whether this is a real calendar date (a meter sends day 0 or month 0 for none).
    pub fn is_valid(&self) -> bool {
        (1..=12).contains(&self.month) && (1..=31).contains(&self.day)
    }
}

impl fmt::Display for Date {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

/// A date and time (type F, or type I with seconds), in the meter's local time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DateTime {
    pub date: Date,
    pub hour: u8,
    pub minute: u8,
    pub second: u8,
    /// The meter flags the time as invalid (IV bit).
    pub invalid: bool,
    /// The meter says summer time.
    pub summer_time: bool,
}

impl fmt::Display for DateTime {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}T{:02}:{:02}:{:02}",
            self.date, self.hour, self.minute, self.second
        )
    }
}

/// Type G: day bits 0–4, year bits 5–7 (low) and 12–15 (high), month bits 8–11. Years are
/// counted from 2000, as meters and libmbus do.
pub fn date_g(b: [u8; 2]) -> Date {
    let year = u16::from((b[0] & 0xE0) >> 5) | u16::from((b[1] & 0xF0) >> 1);
    Date {
        year: 2000 + year,
        month: b[1] & 0x0F,
        day: b[0] & 0x1F,
    }
}

/// Type F: minute bits 0–5, IV bit 7, hour bits 8–12, hundred-year bits 13–14, SU bit 15,
/// then a type G date. Without a hundred-year, years up to 80 are 20xx (old meters count two
/// digits), as libmbus reads them.
pub fn date_time_f(b: [u8; 4]) -> DateTime {
    let y = u16::from((b[2] & 0xE0) >> 5) | u16::from((b[3] & 0xF0) >> 1);
    let hundred = u16::from((b[1] & 0x60) >> 5);
    let century = if hundred == 0 && y <= 80 {
        2000
    } else {
        1900 + 100 * hundred
    };
    DateTime {
        date: Date {
            year: century + y,
            month: b[3] & 0x0F,
            day: b[2] & 0x1F,
        },
        hour: b[1] & 0x1F,
        minute: b[0] & 0x3F,
        second: 0,
        invalid: b[0] & 0x80 != 0,
        summer_time: b[1] & 0x80 != 0,
    }
}

/// Type I: second bits 0–5, then a type F (without hundred-year) shifted by one byte.
pub fn date_time_i(b: [u8; 6]) -> DateTime {
    let y = u16::from((b[3] & 0xE0) >> 5) | u16::from((b[4] & 0xF0) >> 1);
    DateTime {
        date: Date {
            year: 2000 + y,
            month: b[4] & 0x0F,
            day: b[3] & 0x1F,
        },
        hour: b[2] & 0x1F,
        minute: b[1] & 0x3F,
        second: b[0] & 0x3F,
        invalid: b[1] & 0x80 != 0,
        summer_time: b[0] & 0x40 != 0,
    }
}

/// A little-endian two's-complement integer of 1 to 8 bytes (data type B: signed).
pub fn int_le(bytes: &[u8]) -> i64 {
    let mut v: i64 = 0;
    for (i, b) in bytes.iter().take(8).enumerate() {
        v |= i64::from(*b) << (8 * i);
    }
    let bits = 8 * bytes.len().min(8) as u32;
    if bits < 64 {
        let shift = 64 - bits;
        v = (v << shift) >> shift;
    }
    v
}

/// A BCD field (least significant byte first, data type A): its value, negative where the
/// most significant digit is F; [`Value::InvalidBcd`] where any other digit is not 0–9.
pub fn bcd_le(bytes: &[u8]) -> Value {
    let digits: Vec<u8> = bytes
        .iter()
        .rev()
        .flat_map(|b| [b >> 4, b & 0x0F])
        .collect();
    let (negative, rest) = match digits.split_first() {
        Some((0xF, rest)) => (true, rest),
        _ => (false, &digits[..]),
    };
    if rest.iter().any(|d| *d > 9) || rest.len() > 18 {
        let text = digits.iter().map(|d| format!("{d:X}")).collect();
        return Value::InvalidBcd(text);
    }
    let magnitude = rest.iter().fold(0i64, |v, d| v * 10 + i64::from(*d));
    Value::Number(Exact {
        raw: if negative { -magnitude } else { magnitude },
        exp: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn exact(raw: i64, exp: i32) -> String {
        Exact { raw, exp }.to_decimal_string()
    }

    #[test]
    fn an_exact_value_prints_as_the_decimal_a_person_would_write() {
        assert_eq!(exact(12345, -3), "12.345");
        assert_eq!(exact(12340, -3), "12.34");
        assert_eq!(exact(5, -3), "0.005");
        assert_eq!(exact(-5, -1), "-0.5");
        assert_eq!(exact(12, 2), "1200");
        assert_eq!(exact(0, 3), "0");
        assert_eq!(exact(0, -3), "0");
        assert_eq!(exact(i64::MIN, -2), "-92233720368547758.08");
        assert_eq!(Exact { raw: 1, exp: -3 }.to_f64(), 0.001);
    }

    #[test]
    fn integers_are_signed_little_endian() {
        assert_eq!(int_le(&[0xFF]), -1);
        assert_eq!(int_le(&[0x34, 0x12]), 0x1234);
        assert_eq!(int_le(&[0x00, 0x00, 0x80]), -0x80_0000);
        assert_eq!(int_le(&[0xFF; 8]), -1);
    }

    #[test]
    fn bcd_reads_a_leading_f_as_minus_and_other_letters_as_not_a_number() {
        assert_eq!(
            bcd_le(&[0x78, 0x56, 0x34, 0x12]),
            Value::Number(Exact {
                raw: 12345678,
                exp: 0
            })
        );
        assert_eq!(
            bcd_le(&[0x23, 0xF1]),
            Value::Number(Exact { raw: -123, exp: 0 })
        );
        assert_eq!(bcd_le(&[0xEE, 0x0E]), Value::InvalidBcd("0EEE".into()));
    }

    #[test]
    fn dates_of_type_g_f_and_i_read_their_bits() {
        // 31.12.2014: day 31, month 12, year 14 = 0b0001110 (low 3 bits 110, high 0001).
        assert_eq!(date_g([0xDF, 0x1C]).to_string(), "2014-12-31");
        let dt = date_time_f([0x1E, 0x0E, 0x08, 0x22]);
        assert_eq!(dt.to_string(), "2016-02-08T14:30:00");
        assert!(!dt.invalid);
    }
}
