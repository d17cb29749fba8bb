//! One channel's account: the records its intervals close are booked to a tariff register (and,
//! with `[billing]`, into the open billing period). Pure; kept in the counter state file.
//!
//! Registers are fed by the records of the channel's shortest period only: those are the ones
//! `check` guarantees lie inside one tariff, and booking each pulse once is what lets the
//! registers sum to the total moved. A `merged` record that crossed a switch cannot be split
//! without guessing, so it is booked whole to the tariff in force at its start and says which
//! tariffs it spanned.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::billing::{BillingConfig, OpenPeriod};
pub use super::booking::{BillingRecord, Booking, Register};
use super::clock::Clock;
use super::interval::{Read, Record};
use super::tariff::Calendar;

/// The rules an account books by: the clock, the calendar, the billing periods.
#[derive(Debug, Clone, Copy)]
pub struct Books<'a> {
    pub clock: &'a Clock,
    pub calendar: Option<&'a Calendar>,
    pub billing: Option<&'a BillingConfig>,
}

/// The channel's shortest period and what this read did to it.
#[derive(Debug, Clone, Copy)]
pub struct Shortest<'a> {
    /// As written (`15min`): its records feed the registers and the billing period.
    pub period: &'a str,
    /// It had no open interval before this read: the read's pulses are in no record.
    pub fresh: bool,
    /// The boundary at which this read opened its first interval.
    pub opened: Option<i64>,
}

/// A channel's registers and open billing period, as the state file keeps them.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Account {
    /// Pulses per tariff since the registers began.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub registers: BTreeMap<String, i64>,
    #[serde(default)]
    pub register_seq: u64,
    /// The open billing period.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub open: Option<OpenPeriod>,
    /// The seq of the last billing record.
    #[serde(default)]
    pub seq: u64,
    /// A billing record closed by a read that closed no record: it goes with the next one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pending: Vec<BillingRecord>,
    /// The last billing records, newest last (`pulsegate billing` prints them).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub kept: Vec<BillingRecord>,
}

/// How many closed billing periods a channel keeps.
pub const KEPT: usize = 12;

impl Account {
    /// Books `read` and the records it closed (`closed`: each with its period as written).
    pub fn book(
        &mut self,
        books: &Books<'_>,
        shortest: &Shortest<'_>,
        read: Read,
        closed: &mut [(Arc<str>, Record)],
    ) {
        if books.calendar.is_none() && books.billing.is_none() {
            return;
        }
        if books.billing.is_some() {
            let open = self.open.get_or_insert_with(|| OpenPeriod::first(read));
            if shortest.fresh {
                // The read that opens the first interval is its start boundary's read: like
                // the read that ends any record, its pulses were counted before the boundary,
                // so they take the tariff in force just before it, as that record would.
                let when = shortest.opened.map_or(read.at_ms, |b| b - 1);
                let tariff = books.calendar.map(|c| c.at(books.clock, when));
                open.book_pre_interval(read, tariff);
            }
        }
        for (period, record) in closed.iter_mut() {
            let mut booking = Booking::default();
            if let Some(cal) = books.calendar {
                let spanned = cal.spanned(books.clock, record.start_ms, record.end_ms);
                booking.tariff = Some(spanned[0].to_string());
                if spanned.len() > 1 {
                    booking.tariffs = spanned.iter().map(|s| s.to_string()).collect();
                }
            }
            if **period == *shortest.period
                && let Some(name) = &booking.tariff
            {
                let total = self.registers.entry(name.clone()).or_default();
                *total += record.delta;
                self.register_seq += 1;
                booking.register = Some(Register {
                    total: *total,
                    seq: self.register_seq,
                });
            }
            if let (Some(b), Some(open)) = (books.billing, &mut self.open) {
                open.note_demand(b, period, record);
            }
            record.booking = Some(Box::new(booking));
        }
        self.close_periods(books, shortest, read, closed);
    }

    /// Books the shortest period's records into the open billing period and closes it at the
    /// boundary read that reaches its end: a record's end, or the read that opened the first
    /// interval. The record it closed at carries it (a close without a record waits in
    /// `pending` for the next).
    fn close_periods(
        &mut self,
        books: &Books<'_>,
        shortest: &Shortest<'_>,
        read: Read,
        closed: &mut [(Arc<str>, Record)],
    ) {
        let Some(b) = books.billing else { return };
        if let (Some(at), Some(open)) = (shortest.opened, &self.open)
            && at >= open.end_ms(books.clock, b)
        {
            let done = self.close(books.clock, b, (at, read.total));
            self.pending.push(done);
            return;
        }
        for (_, record) in closed.iter_mut().filter(|(p, _)| **p == *shortest.period) {
            let Some(open) = self.open.as_mut() else {
                return;
            };
            let tariff = record.booking.as_ref().and_then(|x| x.tariff.clone());
            open.book_record(record, tariff.as_deref());
            let booking = record.booking.get_or_insert_with(Default::default);
            booking.billing.append(&mut self.pending);
            if record.end_ms < open.end_ms(books.clock, b) {
                continue;
            }
            let done = self.close(books.clock, b, (record.end_ms, record.total_end));
            booking.billing.push(done);
        }
    }

    fn close(&mut self, clock: &Clock, b: &BillingConfig, end: (i64, i64)) -> BillingRecord {
        let open = self.open.take().unwrap_or_else(|| {
            OpenPeriod::first(Read {
                at_ms: end.0,
                total: end.1,
                event: None,
            })
        });
        self.seq += 1;
        let done = open.close(clock, b, end, self.seq);
        self.open = Some(OpenPeriod::after(&done));
        self.kept.push(done.clone());
        if self.kept.len() > KEPT {
            self.kept.remove(0);
        }
        done
    }
}

#[cfg(test)]
#[path = "account_tests.rs"]
mod tests;
