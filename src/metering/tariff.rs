//! The time-of-use calendar (`[tariffs]`): which tariff is in force at an instant. Pure.
//!
//! Rules are read against the local wall clock of `gateway.timezone`, as a meter's tariff
//! switch does: a 07:00 rule switches at 07:00 local on both sides of a daylight-saving change,
//! while records keep tiling UTC. Rules are tried in order and the first that matches wins;
//! `from` is inclusive, `to` exclusive; a holiday takes the default tariff all day. Because
//! `check` only accepts rule times that are boundaries of every metered channel's shortest
//! interval, every complete record of that interval lies inside one tariff.

use std::collections::BTreeSet;

use jiff::civil::{Date, DateTime, Time};

use super::clock::Clock;
use super::period::{DAY_MS, Period};

/// Weekday names as the config writes them, Monday first.
pub const DAYS: [&str; 7] = ["mon", "tue", "wed", "thu", "fri", "sat", "sun"];

/// One `[[tariffs.rule]]`, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rule {
    /// Index into [`Calendar::names`].
    pub tariff: usize,
    /// Monday first.
    pub days: [bool; 7],
    /// Milliseconds since local midnight; `to` is `DAY_MS` for a rule that runs to midnight.
    pub from_ms: i64,
    pub to_ms: i64,
}

/// The checked calendar.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Calendar {
    /// Tariff names in the order they are first named (the default first): the OBIS tariff
    /// group of a name is its index plus one.
    names: Vec<String>,
    holidays: BTreeSet<Date>,
    rules: Vec<Rule>,
}

/// A calendar that cannot be kept, in words a field engineer understands.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TariffError {
    #[error("at most 9 tariffs (an OBIS tariff group is one digit): {0} are named")]
    TooMany(usize),
    #[error("{0:?} is not a day: write one of mon, tue, wed, thu, fri, sat, sun")]
    Day(String),
    #[error("{0:?} is listed twice")]
    DayTwice(String),
    #[error("names no day: a rule needs at least one")]
    NoDays,
    #[error("{0:?} is not a time of day such as \"07:00\" (hours 00-23, minutes 00-59)")]
    Time(String),
    #[error(
        "runs from {from} to {to}: `to` must be after `from` (\"00:00\" means midnight); a rule across midnight is two rules"
    )]
    Empty { from: String, to: String },
    #[error(
        "never applies: earlier rules cover all of its days and hours (the first rule that matches wins)"
    )]
    Shadowed,
    #[error("{0:?} is not a date such as \"2026-12-25\"")]
    Holiday(String),
}

/// A rule as the config writes it (before checking).
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawRule {
    pub tariff: String,
    pub days: Vec<String>,
    pub from: String,
    pub to: String,
}

impl Calendar {
    /// Checks a calendar; every error, each with the index of the rule it is about (`None`:
    /// the calendar as a whole).
    pub fn new(
        default: &str,
        holidays: &[String],
        rules: &[RawRule],
    ) -> Result<Calendar, Vec<(Option<usize>, TariffError)>> {
        let mut errs = Vec::new();
        let mut names = vec![default.to_string()];
        for r in rules {
            if !names.contains(&r.tariff) {
                names.push(r.tariff.clone());
            }
        }
        if names.len() > 9 {
            errs.push((None, TariffError::TooMany(names.len())));
        }
        let mut days = BTreeSet::new();
        for h in holidays {
            match h.parse::<Date>() {
                Ok(d) => {
                    days.insert(d);
                }
                Err(_) => errs.push((None, TariffError::Holiday(h.clone()))),
            }
        }
        let mut checked: Vec<Rule> = Vec::new();
        for (i, raw) in rules.iter().enumerate() {
            match rule(raw, &names) {
                Ok(r) if shadowed(&r, &checked) => errs.push((Some(i), TariffError::Shadowed)),
                Ok(r) => checked.push(r),
                Err(list) => errs.extend(list.into_iter().map(|e| (Some(i), e))),
            }
        }
        if !errs.is_empty() {
            return Err(errs);
        }
        Ok(Calendar {
            names,
            holidays: days,
            rules: checked,
        })
    }

    /// Tariff names, the default first, in the order they are first named.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The checked rules, in order.
    pub fn rules(&self) -> &[Rule] {
        &self.rules
    }

    /// The tariff's position counted from 1 (its OBIS tariff group).
    pub fn number(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name).map(|i| i + 1)
    }

    /// The tariff in force at `ms` (Unix ms) on the local clock of `clock`.
    pub fn at(&self, clock: &Clock, ms: i64) -> &str {
        let local = clock.local(ms);
        let date = local.date();
        if self.holidays.contains(&date) {
            return &self.names[0];
        }
        let day = date.weekday().to_monday_zero_offset() as usize;
        let tod = time_ms(local.time());
        self.rules
            .iter()
            .find(|r| r.days[day] && (r.from_ms..r.to_ms).contains(&tod))
            .map_or(&self.names[0], |r| &self.names[r.tariff])
    }

    /// The next instant after `ms` at which the tariff may change: a rule's `from` or `to`, a
    /// local midnight (a weekday or a holiday begins), or a change of the zone's offset (a rule
    /// time inside a spring gap switches when the clock jumps over it).
    pub fn next_switch(&self, clock: &Clock, ms: i64) -> i64 {
        let local = clock.local(ms);
        let tod = time_ms(local.time());
        let mut times: Vec<i64> = self
            .rules
            .iter()
            .flat_map(|r| [r.from_ms, r.to_ms])
            .chain([DAY_MS])
            .filter(|t| *t > tod)
            .collect();
        times.sort_unstable();
        let date = local.date();
        let mut best = i64::MAX;
        for t in times {
            let at = if t == DAY_MS {
                date.tomorrow().map_or(i64::MAX, |d| {
                    clock.instant(DateTime::from_parts(d, Time::MIN))
                })
            } else {
                clock.instant(DateTime::from_parts(date, time_of(t)))
            };
            if at > ms {
                best = at;
                break;
            }
        }
        match clock.next_change(ms) {
            Some(c) if c < best => c,
            _ => best,
        }
    }

    /// The instants after `ms` at which the tariff does change, with the tariff from then on;
    /// at most `n` of them (a calendar with one tariff has none).
    pub fn changes(&self, clock: &Clock, ms: i64, n: usize) -> Vec<(i64, &str)> {
        let mut out = Vec::new();
        let mut now = self.at(clock, ms);
        let mut t = ms;
        // A year of switches is plenty to find `n` changes of any calendar that has them.
        for _ in 0..(366 * 8) {
            if out.len() >= n {
                break;
            }
            t = self.next_switch(clock, t);
            if t == i64::MAX {
                break;
            }
            let next = self.at(clock, t);
            if next != now {
                out.push((t, next));
                now = next;
            }
        }
        out
    }

    /// The tariffs in force during `[start, end)`, in the order they come, once each.
    pub fn spanned(&self, clock: &Clock, start: i64, end: i64) -> Vec<&str> {
        let mut out = vec![self.at(clock, start)];
        let mut t = start;
        // A merged record spans at most the time the gateway was away; the cap bounds a
        // record over years from a state file edited by hand.
        for _ in 0..100_000 {
            t = self.next_switch(clock, t);
            if t >= end {
                break;
            }
            let name = self.at(clock, t);
            if !out.contains(&name) {
                out.push(name);
            }
        }
        out
    }

    /// The rule times that are not boundaries of `period` (each as written, `"07:10"`): a
    /// record of `period` would straddle them.
    pub fn off_grid(&self, period: &Period) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for r in &self.rules {
            for t in [r.from_ms, r.to_ms] {
                let text = hhmm(t);
                if t % period.ms() != 0 && !out.contains(&text) {
                    out.push(text);
                }
            }
        }
        out
    }
}

/// What `check` prints of a calendar: its tariffs and the next `n` switches after `now_ms`,
/// in UTC and on the local clock.
pub fn describe(cal: &Calendar, clock: &Clock, now_ms: i64, n: usize) -> String {
    use std::fmt::Write;
    let mut out = format!(
        "tariffs ({}): {}; now {}\n",
        clock.name(),
        cal.names()
            .iter()
            .enumerate()
            .map(|(i, n)| format!("{} = {n}", i + 1))
            .collect::<Vec<_>>()
            .join(", "),
        cal.at(clock, now_ms)
    );
    for (at, name) in cal.changes(clock, now_ms, n) {
        let local = clock.local(at).strftime("%a %Y-%m-%d %H:%M %Z").to_string();
        let _ = writeln!(out, "  {}  {local}  -> {name}", super::clock::iso(at));
    }
    out
}

fn rule(raw: &RawRule, names: &[String]) -> Result<Rule, Vec<TariffError>> {
    let mut errs = Vec::new();
    let mut days = [false; 7];
    if raw.days.is_empty() {
        errs.push(TariffError::NoDays);
    }
    for d in &raw.days {
        match DAYS.iter().position(|n| n == d) {
            Some(i) if days[i] => errs.push(TariffError::DayTwice(d.clone())),
            Some(i) => days[i] = true,
            None => errs.push(TariffError::Day(d.clone())),
        }
    }
    let from = parse_time(&raw.from).ok_or_else(|| TariffError::Time(raw.from.clone()));
    let to = parse_time(&raw.to)
        .map(|t| if t == 0 { DAY_MS } else { t })
        .ok_or_else(|| TariffError::Time(raw.to.clone()));
    let (from_ms, to_ms) = match (from, to) {
        (Ok(f), Ok(t)) if f < t => (f, t),
        (Ok(_), Ok(_)) => {
            errs.push(TariffError::Empty {
                from: raw.from.clone(),
                to: raw.to.clone(),
            });
            (0, 0)
        }
        (f, t) => {
            errs.extend(f.err());
            errs.extend(t.err());
            (0, 0)
        }
    };
    if !errs.is_empty() {
        return Err(errs);
    }
    let tariff = names.iter().position(|n| *n == raw.tariff).unwrap_or(0);
    Ok(Rule {
        tariff,
        days,
        from_ms,
        to_ms,
    })
}

/// Whether every day and hour of `r` is already taken by an earlier rule.
fn shadowed(r: &Rule, earlier: &[Rule]) -> bool {
    let mut cuts: Vec<i64> = earlier
        .iter()
        .flat_map(|e| [e.from_ms, e.to_ms])
        .chain([r.from_ms, r.to_ms])
        .filter(|t| (r.from_ms..=r.to_ms).contains(t))
        .collect();
    cuts.sort_unstable();
    cuts.dedup();
    (0..7).filter(|d| r.days[*d]).all(|d| {
        cuts.windows(2).all(|w| {
            earlier
                .iter()
                .any(|e| e.days[d] && e.from_ms <= w[0] && w[1] <= e.to_ms)
        })
    })
}

/// `"07:00"` → milliseconds since midnight.
fn parse_time(text: &str) -> Option<i64> {
    let (h, m) = text.split_once(':')?;
    if h.len() != 2 || m.len() != 2 {
        return None;
    }
    let (h, m): (i64, i64) = (h.parse().ok()?, m.parse().ok()?);
    ((0..24).contains(&h) && (0..60).contains(&m)).then_some((h * 60 + m) * 60_000)
}

fn hhmm(ms: i64) -> String {
    let m = ms / 60_000;
    format!("{:02}:{:02}", (m / 60) % 24, m % 60)
}

fn time_ms(t: Time) -> i64 {
    ((i64::from(t.hour()) * 60 + i64::from(t.minute())) * 60 + i64::from(t.second())) * 1000
        + i64::from(t.millisecond())
}

fn time_of(ms: i64) -> Time {
    let s = ms / 1000;
    Time::new((s / 3600) as i8, ((s / 60) % 60) as i8, (s % 60) as i8, 0).unwrap_or(Time::MIN)
}

#[cfg(test)]
#[path = "tariff_tests.rs"]
mod tests;
