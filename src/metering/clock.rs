//! Interval boundaries on the local clock of `gateway.timezone`. Pure (the time-zone rules are
//! jiff's bundled copy of the IANA database, compiled in).
//!
//! A boundary of a period shorter than a day is an instant whose local time is a whole
//! multiple of the period since local midnight: a quarter-hour grid skips the hour that a
//! spring change jumps over and runs twice through the hour an autumn change repeats, so every
//! quarter-hour record lasts 15 minutes (the German load profile's 92 and 100 quarter-hours).
//! A `1d` boundary is the start of the local day, so a DST day lasts 23 h or 25 h.

use jiff::Timestamp;
use jiff::tz::TimeZone;

use super::period::Period;

/// The time zone boundaries are reckoned in.
#[derive(Debug, Clone)]
pub struct Clock {
    tz: TimeZone,
    name: String,
}

/// `gateway.timezone` names no zone jiff knows.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not an IANA time zone name such as \"Europe/Berlin\" or \"UTC\"")]
pub struct UnknownZone(pub String);

impl PartialEq for Clock {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
    }
}

impl Default for Clock {
    fn default() -> Self {
        Clock {
            tz: TimeZone::UTC,
            name: "UTC".into(),
        }
    }
}

impl Clock {
    /// The zone of an IANA name.
    pub fn named(name: &str) -> Result<Clock, UnknownZone> {
        let tz = TimeZone::get(name).map_err(|_| UnknownZone(name.to_string()))?;
        Ok(Clock {
            tz,
            name: name.to_string(),
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// The local date and time at `ms`: what a tariff rule and a billing day are read against.
    pub fn local(&self, ms: i64) -> jiff::ZonedDateTime {
        ts(ms).to_zoned_datetime(self.tz.clone())
    }

    /// The instant a local date and time names (in a spring gap: as if the clock had not
    /// jumped, which lands after the gap; in an autumn fold: the first of the two).
    pub fn instant(&self, local: jiff::civil::DateTime) -> i64 {
        self.tz
            .to_ambiguous_zoned_datetime(local)
            .compatible()
            .map_or(i64::MAX, |z| z.timestamp().as_millisecond())
    }

    /// The next change of the zone's offset after `ms` (a daylight-saving change), if any.
    pub fn next_change(&self, ms: i64) -> Option<i64> {
        self.tz
            .following(ts(ms))
            .next()
            .map(|t| t.timestamp().as_millisecond())
    }

    fn offset_ms(&self, ms: i64) -> i64 {
        i64::from(self.tz.to_offset(ts(ms)).seconds()) * 1000
    }

    /// The latest boundary of `period` at or before `ms` (Unix milliseconds).
    pub fn floor(&self, period: &Period, ms: i64) -> i64 {
        if period.is_day() {
            return ts(ms)
                .to_zoned_datetime(self.tz.clone())
                .start_of_day()
                .map_or(ms, |z| z.timestamp().as_millisecond());
        }
        let p = period.ms();
        let mut t = ms;
        // Each turn steps back over one offset change; a period is at most a day.
        for _ in 0..8 {
            let off = self.offset_ms(t);
            let c = t - (t + off).rem_euclid(p);
            if self.offset_ms(c) == off {
                return c;
            }
            // An offset change lies in (c, t]: no grid point of this offset before t.
            let Some(change) = self.tz.preceding(ts(t + 1)).next() else {
                return c;
            };
            t = change.timestamp().as_millisecond() - 1;
        }
        t
    }

    /// The earliest boundary of `period` after `ms`.
    pub fn next(&self, period: &Period, ms: i64) -> i64 {
        if period.is_day() {
            let next = ts(ms)
                .to_zoned_datetime(self.tz.clone())
                .start_of_day()
                .and_then(|z| z.tomorrow())
                .and_then(|z| z.start_of_day());
            return next.map_or(ms + period.ms(), |z| z.timestamp().as_millisecond());
        }
        let p = period.ms();
        let mut b = ms;
        for _ in 0..8 {
            let off = self.offset_ms(b);
            let c = b + p - (b + off).rem_euclid(p);
            if self.offset_ms(c) == off {
                return c;
            }
            // The offset changed in (b, c]: the first grid point of the new offset.
            let Some(change) = self.tz.following(ts(b)).next() else {
                return c;
            };
            let at = change.timestamp().as_millisecond();
            let off = self.offset_ms(at);
            let r = (at + off).rem_euclid(p);
            let c = if r == 0 { at } else { at + p - r };
            if self.offset_ms(c) == off {
                return c;
            }
            b = at;
        }
        b + p
    }
}

fn ts(ms: i64) -> Timestamp {
    Timestamp::from_millisecond(ms).unwrap_or(Timestamp::UNIX_EPOCH)
}

/// `2026-03-29T01:00:00Z`: a boundary as records print it (UTC, no fraction when whole).
pub fn iso(ms: i64) -> String {
    let t = ts(ms);
    if ms % 1000 == 0 {
        t.strftime("%Y-%m-%dT%H:%M:%SZ").to_string()
    } else {
        t.strftime("%Y-%m-%dT%H:%M:%S%.3fZ").to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(text: &str) -> i64 {
        text.parse::<Timestamp>().unwrap().as_millisecond()
    }

    fn hours(ms: i64) -> f64 {
        ms as f64 / 3_600_000.0
    }

    /// The boundaries of `period` from `from` for `n` steps.
    fn walk(clock: &Clock, period: &str, from: &str, n: usize) -> Vec<String> {
        let p = Period::parse(period).unwrap();
        let mut b = clock.floor(&p, at(from));
        let mut out = vec![iso(b)];
        for _ in 0..n {
            b = clock.next(&p, b);
            out.push(iso(b));
        }
        out
    }

    #[test]
    fn a_berlin_day_starts_at_local_midnight_and_dst_days_last_23_and_25_hours() {
        let berlin = Clock::named("Europe/Berlin").unwrap();
        let day = Period::parse("1d").unwrap();
        // Spring: Sunday 29 March 2026, 02:00 CET → 03:00 CEST.
        let start = berlin.floor(&day, at("2026-03-29T12:00:00Z"));
        assert_eq!(iso(start), "2026-03-28T23:00:00Z", "midnight CET");
        let end = berlin.next(&day, start);
        assert_eq!(iso(end), "2026-03-29T22:00:00Z", "midnight CEST");
        assert_eq!(hours(end - start), 23.0);
        // Autumn: Sunday 25 October 2026, 03:00 CEST → 02:00 CET.
        let start = berlin.floor(&day, at("2026-10-25T01:30:00Z"));
        assert_eq!(iso(start), "2026-10-24T22:00:00Z", "midnight CEST");
        let end = berlin.next(&day, start);
        assert_eq!(iso(end), "2026-10-25T23:00:00Z", "midnight CET");
        assert_eq!(hours(end - start), 25.0);
        // An ordinary day around them is 24 h, and the boundaries are fixed points.
        let next = berlin.next(&day, end);
        assert_eq!(hours(next - end), 24.0);
        assert_eq!(berlin.floor(&day, end), end);
        assert_eq!(berlin.floor(&day, end - 1), start);
    }

    #[test]
    fn quarter_hours_skip_the_spring_gap_and_repeat_the_autumn_hour() {
        let berlin = Clock::named("Europe/Berlin").unwrap();
        let spring = walk(&berlin, "15min", "2026-03-29T00:40:00Z", 2);
        // 01:30 CET, 01:45 CET, then 03:00 CEST: fifteen minutes each.
        assert_eq!(
            spring,
            [
                "2026-03-29T00:30:00Z",
                "2026-03-29T00:45:00Z",
                "2026-03-29T01:00:00Z"
            ]
        );
        // 02:45 CEST, then 02:00 CET (the hour again), 02:15 CET.
        let autumn = walk(&berlin, "15min", "2026-10-25T00:50:00Z", 2);
        assert_eq!(
            autumn,
            [
                "2026-10-25T00:45:00Z",
                "2026-10-25T01:00:00Z",
                "2026-10-25T01:15:00Z"
            ]
        );
        // A whole autumn day has 100 quarter-hours, a spring day 92.
        for (day, want) in [("2026-10-25T12:00:00Z", 100), ("2026-03-29T12:00:00Z", 92)] {
            let d = Period::parse("1d").unwrap();
            let q = Period::parse("15min").unwrap();
            let (start, end) = (berlin.floor(&d, at(day)), berlin.next(&d, at(day)));
            let mut b = start;
            let mut n = 0;
            while b < end {
                let next = berlin.next(&q, b);
                assert_eq!(next - b, 900_000, "every quarter-hour lasts 15 min");
                b = next;
                n += 1;
            }
            assert_eq!((n, b), (want, end));
        }
    }

    #[test]
    fn hours_follow_a_half_hour_zone_and_utc_is_the_default() {
        let india = Clock::named("Asia/Kolkata").unwrap();
        let h = Period::parse("1h").unwrap();
        assert_eq!(
            iso(india.floor(&h, at("2026-06-01T10:10:00Z"))),
            "2026-06-01T09:30:00Z"
        );
        let utc = Clock::default();
        assert_eq!(
            iso(utc.floor(&h, at("2026-06-01T10:10:00Z"))),
            "2026-06-01T10:00:00Z"
        );
        assert_eq!(
            iso(utc.next(&h, at("2026-06-01T10:00:00Z"))),
            "2026-06-01T11:00:00Z"
        );
        let s = Period::parse("10s").unwrap();
        assert_eq!(utc.floor(&s, 12_345), 10_000);
        assert_eq!(utc.next(&s, 10_000), 20_000);
    }

    #[test]
    fn an_unknown_zone_is_refused_by_name() {
        assert_eq!(
            Clock::named("Mars/Olympus").unwrap_err(),
            UnknownZone("Mars/Olympus".into())
        );
        assert_eq!(iso(1_500), "1970-01-01T00:00:01.500Z");
    }
}
