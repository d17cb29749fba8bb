//! Billing periods (`[billing]`): when a period closes, what its record holds, and the largest
//! demand of the period. Pure.
//!
//! A period closes at the boundary read of the channel's shortest interval that reaches its end
//! (local midnight, of the day or of the month's `day`): every pulse of a record is in exactly
//! one period, as it is in exactly one tariff. A period begun by a start runs from the first
//! reading, and its pulses before the first interval boundary are booked under the tariff in
//! force when they were read (those of that boundary's read, like a record's end read, under
//! the tariff before it), so `by_tariff` always sums to `delta` and each tariff's share beyond
//! them is exactly its records.

use std::collections::BTreeMap;

use jiff::civil::{Date, DateTime, Time};
use serde::{Deserialize, Serialize};

pub use super::booking::{BillingRecord, Peak, PeriodStatus};
use super::clock::Clock;
use super::interval::{Read, Record, Status};
use super::period::Period;

/// How often a billing period closes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cycle {
    /// At every local midnight.
    Daily,
    /// At 00:00 local on this day of every month (1..=28, so every month has it).
    Monthly { day: i8 },
}

/// `[billing]`, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BillingConfig {
    pub cycle: Cycle,
    /// The interval whose complete records compete for the period's demand.
    pub demand: Option<Period>,
    /// `signing_key`: where the Ed25519 key that signs records is.
    pub signing_key: Option<std::path::PathBuf>,
    /// The key read from `signing_key` when the config was checked: it signs every interval
    /// and billing record.
    pub signer: Option<std::sync::Arc<crate::signing::SigningKey>>,
}

impl BillingConfig {
    /// The first close of a period that began at `start_ms`.
    pub fn close_after(&self, clock: &Clock, start_ms: i64) -> i64 {
        match self.cycle {
            Cycle::Daily => clock.next(&Period::parse("1d").expect("a day"), start_ms),
            Cycle::Monthly { day } => {
                let local = clock.local(start_ms).date();
                let this = Date::new(local.year(), local.month(), day).unwrap_or(local);
                let at = |d: Date| clock.instant(DateTime::from_parts(d, Time::MIN));
                if at(this) > start_ms {
                    return at(this);
                }
                let (y, m) = if local.month() == 12 {
                    (local.year() + 1, 1)
                } else {
                    (local.year(), local.month() + 1)
                };
                Date::new(y, m, day).map_or(i64::MAX, at)
            }
        }
    }
}

/// The period being billed, as the state file keeps it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OpenPeriod {
    pub start_ms: i64,
    pub total_start: i64,
    /// The total up to which pulses are booked in `by_tariff`.
    pub booked: i64,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub by_tariff: BTreeMap<String, i64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak: Option<Peak>,
    #[serde(default)]
    pub partial: bool,
}

impl OpenPeriod {
    /// The period a channel's first reading begins: partial, from that reading.
    pub fn first(read: Read) -> OpenPeriod {
        OpenPeriod {
            start_ms: read.at_ms,
            total_start: read.total,
            booked: read.total,
            by_tariff: BTreeMap::new(),
            peak: None,
            partial: true,
        }
    }

    /// The period that follows `closed`.
    pub fn after(closed: &BillingRecord) -> OpenPeriod {
        OpenPeriod {
            start_ms: closed.end_ms,
            total_start: closed.total_end,
            booked: closed.total_end,
            by_tariff: BTreeMap::new(),
            peak: None,
            partial: false,
        }
    }

    /// When the period is due to close.
    pub fn end_ms(&self, clock: &Clock, b: &BillingConfig) -> i64 {
        b.close_after(clock, self.start_ms)
    }

    fn book(&mut self, to_total: i64, tariff: Option<&str>) {
        let n = to_total - self.booked;
        if let Some(t) = tariff
            && n != 0
        {
            *self.by_tariff.entry(t.to_string()).or_default() += n;
        }
        self.booked = to_total;
    }

    /// Books the pulses of a read that no record holds (before the first interval boundary)
    /// under `tariff`: the one in force when it was read, or, for the read of that boundary,
    /// just before it (see `super::account`).
    pub fn book_pre_interval(&mut self, read: Read, tariff: Option<&str>) {
        self.book(read.total, tariff);
    }

    /// Books a record of the shortest period under its tariff.
    pub fn book_record(&mut self, record: &Record, tariff: Option<&str>) {
        self.book(record.total_end, tariff);
    }

    /// Lets a record of the demand period compete: only complete ones inside the period; a tie
    /// keeps the first.
    pub fn note_demand(&mut self, b: &BillingConfig, period: &str, record: &Record) {
        let Some(d) = &b.demand else { return };
        if d.text() != period || record.status != Status::Complete {
            return;
        }
        if record.start_ms < self.start_ms {
            return;
        }
        if self.peak.is_none_or(|p| record.delta > p.delta) {
            self.peak = Some(Peak {
                delta: record.delta,
                start_ms: record.start_ms,
                ms: record.end_ms - record.start_ms,
            });
        }
    }

    /// The record of this period, closed at `end_ms` by the boundary read that reached its end
    /// (the total it read: `total_end`).
    pub fn close(
        &self,
        clock: &Clock,
        b: &BillingConfig,
        (end_ms, total_end): (i64, i64),
        seq: u64,
    ) -> BillingRecord {
        let status = if self.partial {
            PeriodStatus::Partial
        } else if end_ms != self.end_ms(clock, b) {
            PeriodStatus::Merged
        } else {
            PeriodStatus::Complete
        };
        BillingRecord {
            start_ms: self.start_ms,
            end_ms,
            total_start: self.total_start,
            total_end,
            delta: total_end - self.total_start,
            by_tariff: self.by_tariff.clone(),
            peak: self.peak,
            status,
            seq,
        }
    }
}

#[cfg(test)]
#[path = "billing_tests.rs"]
mod tests;
