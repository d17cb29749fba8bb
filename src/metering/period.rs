//! Interval periods as the config writes them (`"15min"`, `"1h"`, `"1d"`). Pure.

use std::fmt;

/// Milliseconds in a day: every period divides it, so boundaries repeat each day.
pub const DAY_MS: i64 = 86_400_000;

/// One interval period: its length and the text the config used (the topic's last level).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Period {
    text: String,
    ms: i64,
}

/// A period the gateway cannot keep.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PeriodError {
    #[error(
        "{0:?} is not a period such as \"15min\", \"1h\" or \"1d\" (a whole number and s, min, h or d)"
    )]
    Syntax(String),
    #[error("{0:?} is ambiguous: write \"min\" for minutes")]
    Minutes(String),
    #[error(
        "{0:?} does not divide a day: intervals must tile every day the same way (e.g. 5min, 15min, 1h, 6h, 1d)"
    )]
    NotDivisor(String),
}

impl Period {
    /// Parses `<n><unit>` with unit `s`, `min`, `h` or `d`; the period must divide a day.
    pub fn parse(text: &str) -> Result<Period, PeriodError> {
        let syntax = || PeriodError::Syntax(text.to_string());
        let split = text
            .find(|c: char| !c.is_ascii_digit())
            .ok_or_else(syntax)?;
        let (digits, unit) = text.split_at(split);
        if digits.is_empty() || digits.len() > 6 || digits.starts_with('0') {
            return Err(syntax());
        }
        let n: i64 = digits.parse().map_err(|_| syntax())?;
        let unit_ms = match unit {
            "s" => 1_000,
            "min" => 60_000,
            "h" => 3_600_000,
            "d" => DAY_MS,
            "m" | "M" => return Err(PeriodError::Minutes(text.to_string())),
            _ => return Err(syntax()),
        };
        let ms = n * unit_ms;
        if ms > DAY_MS || DAY_MS % ms != 0 {
            return Err(PeriodError::NotDivisor(text.to_string()));
        }
        Ok(Period {
            text: text.to_string(),
            ms,
        })
    }

    /// The text as written in the config (`15min`): the topic's last level and the state key.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// Length in milliseconds (a `1d` day is 23 h or 25 h on a DST change; this says 24 h).
    pub fn ms(&self) -> i64 {
        self.ms
    }

    /// Whether intervals are local days (start at local midnight).
    pub fn is_day(&self) -> bool {
        self.ms == DAY_MS
    }

    /// How late a read may come after a boundary and still count as that boundary's read: a
    /// quarter of the period, at most a minute. A later read would put the next interval's
    /// pulses into this one; the boundary is missed instead and the record becomes `merged`.
    pub fn max_lag_ms(&self) -> i64 {
        (self.ms / 4).min(60_000)
    }
}

impl fmt::Display for Period {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tariff_periods_parse_with_their_length_and_text() {
        for (text, ms) in [
            ("1s", 1_000),
            ("10s", 10_000),
            ("15min", 900_000),
            ("30min", 1_800_000),
            ("1h", 3_600_000),
            ("6h", 21_600_000),
            ("1d", DAY_MS),
        ] {
            let p = Period::parse(text).unwrap();
            assert_eq!((p.text(), p.ms()), (text, ms));
        }
    }

    #[test]
    fn a_period_that_does_not_divide_a_day_is_refused_by_name() {
        for text in ["7min", "2d", "25h", "11s"] {
            assert_eq!(
                Period::parse(text),
                Err(PeriodError::NotDivisor(text.into()))
            );
        }
    }

    #[test]
    fn malformed_periods_say_what_is_wrong() {
        for text in [
            "",
            "min",
            "15",
            "15 min",
            "0s",
            "015min",
            "1.5h",
            "-1h",
            "15sec",
            "99999999s",
        ] {
            assert_eq!(
                Period::parse(text),
                Err(PeriodError::Syntax(text.into())),
                "{text}"
            );
        }
        assert_eq!(
            Period::parse("15m"),
            Err(PeriodError::Minutes("15m".into()))
        );
    }

    #[test]
    fn the_lag_a_boundary_read_may_have_is_a_quarter_period_up_to_a_minute() {
        assert_eq!(Period::parse("10s").unwrap().max_lag_ms(), 2_500);
        assert_eq!(Period::parse("15min").unwrap().max_lag_ms(), 60_000);
    }
}
