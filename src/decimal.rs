//! Exact decimal numbers for engineering units. Pure.
//!
//! A pulse weight such as 0.001 kWh has no exact binary floating-point form, so a total scaled
//! with `f64` prints as `1234.5670000000002`. A [`Decimal`] keeps the weight as the integer
//! mantissa and decimal exponent the user wrote, and a scaled total is the integer total times
//! that mantissa: exact, printed as the text a person would write.

use std::fmt;

/// Largest mantissa a weight may have: keeps `total × mantissa` inside `i128` for any `i64`
/// total (9.3e18 × 1e18 < 1.7e38).
const MAX_MANTISSA: i128 = 1_000_000_000_000_000_000;

/// `mantissa × 10^-places`, exactly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decimal {
    mantissa: i128,
    places: u32,
}

/// A weight that is not a plain decimal number.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecimalError {
    #[error("{0:?} is not a decimal number such as 0.001, 10 or 1e-3")]
    Syntax(String),
    #[error("{0:?} has more than 18 significant digits or an exponent beyond ±18")]
    TooLong(String),
}

impl Decimal {
    /// Parses `12`, `0.001`, `-2.5`, `1e-3`, `2.5E+2` exactly.
    pub fn parse(text: &str) -> Result<Decimal, DecimalError> {
        let syntax = || DecimalError::Syntax(text.to_string());
        let too_long = || DecimalError::TooLong(text.to_string());
        let t = text.trim();
        let (number, exponent) = match t.find(['e', 'E']) {
            Some(i) => {
                let e: i32 = t[i + 1..].parse().map_err(|_| syntax())?;
                (&t[..i], e)
            }
            None => (t, 0),
        };
        if !(-18..=18).contains(&exponent) {
            return Err(too_long());
        }
        let (negative, digits) = match number.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, number.strip_prefix('+').unwrap_or(number)),
        };
        let (int, frac) = digits.split_once('.').unwrap_or((digits, ""));
        let all_digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
        if (int.is_empty() && frac.is_empty()) || !all_digits(int) || !all_digits(frac) {
            return Err(syntax());
        }
        let joined = format!("{int}{frac}");
        let significant = joined.trim_start_matches('0');
        if significant.len() > 18 {
            return Err(too_long());
        }
        let mut mantissa: i128 = significant.parse().unwrap_or(0);
        if negative {
            mantissa = -mantissa;
        }
        let mut places = frac.len() as i32 - exponent;
        while places < 0 {
            mantissa *= 10;
            places += 1;
            if mantissa.abs() > MAX_MANTISSA {
                return Err(too_long());
            }
        }
        Ok(Decimal {
            mantissa,
            places: places as u32,
        }
        .normalized())
    }

    /// The decimal closest to `v` with at most 15 significant digits: what the config crate
    /// hands over for a TOML float, turned back into the text the user wrote (Rust prints the
    /// shortest text that reads back as the same float, which for any literal of up to 15
    /// significant digits is that literal).
    pub fn from_f64(v: f64) -> Result<Decimal, DecimalError> {
        if !v.is_finite() {
            return Err(DecimalError::Syntax(v.to_string()));
        }
        Decimal::parse(&format!("{v:e}"))
    }

    /// Drops trailing zeros of the fraction, so equal values compare equal.
    fn normalized(mut self) -> Decimal {
        while self.places > 0 && self.mantissa % 10 == 0 {
            self.mantissa /= 10;
            self.places -= 1;
        }
        self
    }

    /// Digits after the decimal point (0.001 → 3).
    pub fn places(&self) -> u32 {
        self.places
    }

    /// Whether the value is greater than zero.
    pub fn is_positive(&self) -> bool {
        self.mantissa > 0
    }

    /// `n × self`, exactly: the scaled total of `n` pulses.
    pub fn times(&self, n: i64) -> Decimal {
        Decimal {
            mantissa: self.mantissa * i128::from(n),
            places: self.places,
        }
        .normalized()
    }

    /// `self + other`, exactly (a scaled total plus a meter's offset); `None` when the exact
    /// sum does not fit (numbers of wildly different scales, from hostile input).
    pub fn plus(&self, other: &Decimal) -> Option<Decimal> {
        let places = self.places.max(other.places);
        let widen = |d: &Decimal| {
            10i128
                .checked_pow(places - d.places)
                .and_then(|f| d.mantissa.checked_mul(f))
        };
        Some(
            Decimal {
                mantissa: widen(self)?.checked_add(widen(other)?)?,
                places,
            }
            .normalized(),
        )
    }

    /// `self - other`, exactly; `None` when it does not fit.
    pub fn minus(&self, other: &Decimal) -> Option<Decimal> {
        self.plus(&Decimal {
            mantissa: -other.mantissa,
            places: other.places,
        })
    }

    /// The nearest `f64`, for rates (which are measured, not counted).
    pub fn to_f64(&self) -> f64 {
        self.to_string().parse().unwrap_or(f64::NAN)
    }
}

impl fmt::Display for Decimal {
    /// Plain decimal text, never an exponent: `1234.567`, `-0.003`, `30`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let sign = if self.mantissa < 0 { "-" } else { "" };
        let digits = self.mantissa.unsigned_abs().to_string();
        let places = self.places as usize;
        if places == 0 {
            return write!(f, "{sign}{digits}");
        }
        let padded = format!("{digits:0>width$}", width = places + 1);
        let (int, frac) = padded.split_at(padded.len() - places);
        write!(f, "{sign}{int}.{frac}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_are_exact_and_a_sum_that_does_not_fit_is_none_not_a_panic() {
        let d = |t| Decimal::parse(t).unwrap();
        assert_eq!(
            d("12343.678").plus(&d("2.5")).unwrap().to_string(),
            "12346.178"
        );
        assert_eq!(d("3").minus(&d("50")).unwrap().to_string(), "-47");
        let tiny = d("0.000000000000000001e-18");
        let huge = d("999999999999999999");
        assert_eq!(huge.plus(&tiny), None);
    }

    fn d(s: &str) -> Decimal {
        Decimal::parse(s).unwrap()
    }

    #[test]
    fn a_thousandth_times_a_total_is_exact_decimal_text() {
        assert_eq!(d("0.001").times(1_234_567).to_string(), "1234.567");
    }

    #[test]
    fn a_tenth_times_three_is_three_tenths_not_the_float_sum() {
        assert_eq!(0.1f64 * 3.0, 0.30000000000000004, "the float trap is real");
        assert_eq!(d("0.1").times(3).to_string(), "0.3");
    }

    #[test]
    fn whole_weights_and_exponents_scale_up() {
        assert_eq!(d("10").times(7).to_string(), "70");
        assert_eq!(d("2.5E+2").times(2).to_string(), "500");
        assert_eq!(d("1e-3").times(5).to_string(), "0.005");
    }

    #[test]
    fn negative_totals_keep_their_sign_and_leading_zero() {
        assert_eq!(d("0.001").times(-3).to_string(), "-0.003");
        assert_eq!(d("0.01").times(0).to_string(), "0");
    }

    #[test]
    fn the_largest_total_times_the_longest_weight_does_not_overflow() {
        let w = d("0.123456789012345678");
        assert_eq!(w.places(), 18);
        let text = w.times(i64::MAX).to_string();
        assert_eq!(text, "1138687895536349061.688316917875412146");
    }

    #[test]
    fn toml_floats_come_back_as_the_literal_the_user_wrote() {
        for (v, text) in [
            (0.001, "0.001"),
            (0.1, "0.1"),
            (10.0, "10"),
            (0.0025, "0.0025"),
        ] {
            assert_eq!(Decimal::from_f64(v).unwrap().to_string(), text);
        }
    }

    #[test]
    fn garbage_and_overlong_weights_are_refused_with_their_text() {
        for bad in ["", ".", "1.2.3", "abc", "1e", "0x10", "--1", "1e99"] {
            let e = Decimal::parse(bad).unwrap_err();
            assert!(e.to_string().contains(&format!("{bad:?}")), "{e}");
        }
        assert!(matches!(
            Decimal::parse("1234567890123456789"),
            Err(DecimalError::TooLong(_))
        ));
        assert!(Decimal::from_f64(f64::NAN).is_err());
    }

    #[test]
    fn trailing_zeros_do_not_change_the_value() {
        assert_eq!(d("0.0010"), d("0.001"));
        assert_eq!(d("0.0010").times(3).to_string(), "0.003");
    }
}
