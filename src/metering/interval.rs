//! One channel's intervals of one period: boundary reads in, records out. Pure.
//!
//! A record is the change of the channel's total between two boundary reads: exact whatever
//! happened between them, because the module keeps counting. The read that counts for a
//! boundary is the first booked read after it, if it came within the period's
//! [`max_lag_ms`](super::Period::max_lag_ms); a later one would carry pulses of the next
//! interval. When a boundary has no such read (the gateway was stopped, the module offline),
//! nothing is guessed: the interval stays open and the next boundary read closes one `merged`
//! record over every interval it spans. Records never overlap and leave no hole.

use serde::{Deserialize, Serialize};

use super::clock::Clock;
use super::period::Period;
use crate::event::Event;

/// The interval being counted, as the state file keeps it (so a restart can close it).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Open {
    /// Its start boundary (Unix ms) and the total read for it.
    pub start_ms: i64,
    pub total_start: i64,
    /// How long after the start boundary its read was.
    pub lag_ms: i64,
    /// What the counter saw since, in order, once each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<Event>,
}

/// A channel's state of one period: the open interval and the seq of the last record.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct IntervalState {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub open: Option<Open>,
    #[serde(default)]
    pub seq: u64,
    /// Records closed in this state but not yet handed to the MQTT side when it was saved (only
    /// in a state file, never in a running channel): the next start sends them again, with
    /// their seq, so a crash right after the save cannot take one away.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unsent: Vec<Record>,
    /// The open interval's end boundary, once known in this run: reads before it need no
    /// time-zone arithmetic (most reads of a channel).
    #[serde(skip)]
    next_ms: Option<i64>,
}

/// Whether both boundaries of a record were read one period apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// One interval, both boundaries read.
    Complete,
    /// Boundaries in between were missed: one record over every interval from `start` to
    /// `end`, with their exact sum.
    Merged,
}

/// One closed interval (kept in a state file until it is handed to the MQTT side).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Record {
    pub start_ms: i64,
    pub end_ms: i64,
    pub delta: i64,
    pub total_start: i64,
    pub total_end: i64,
    /// How long after `start` and after `end` their reads were.
    pub lag_start_ms: i64,
    pub lag_end_ms: i64,
    pub status: Status,
    pub seq: u64,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub events: Vec<Event>,
    /// Its tariff, register and the billing period it closed (see `super::account`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub booking: Option<Box<super::booking::Booking>>,
}

/// One booked read of the channel's counter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Read {
    /// When its answer arrived (wall clock, Unix ms).
    pub at_ms: i64,
    /// The channel's total after it.
    pub total: i64,
    /// The counter's event on it (its delta may span the boundary: it is booked before).
    pub event: Option<Event>,
}

fn note(events: &mut Vec<Event>, e: Option<Event>) {
    if let Some(e) = e
        && !events.contains(&e)
    {
        events.push(e);
    }
}

impl IntervalState {
    /// Books `read`; the record it closes, if it is a boundary's read.
    pub fn observe(&mut self, clock: &Clock, period: &Period, read: Read) -> Option<Record> {
        if let (Some(open), Some(next)) = (&mut self.open, self.next_ms)
            && (open.start_ms..next).contains(&read.at_ms)
        {
            note(&mut open.events, read.event);
            return None;
        }
        let boundary = clock.floor(period, read.at_ms);
        let lag = read.at_ms - boundary;
        let on_time = lag <= period.max_lag_ms();
        let Some(open) = &mut self.open else {
            // Records start at the first boundary read.
            if on_time {
                self.open = Some(Open {
                    start_ms: boundary,
                    total_start: read.total,
                    lag_ms: lag,
                    events: Vec::new(),
                });
                self.next_ms = Some(clock.next(period, boundary));
            }
            return None;
        };
        note(&mut open.events, read.event);
        // Same interval, or a wall clock that stepped back: nothing closes.
        if boundary <= open.start_ms || !on_time {
            return None;
        }
        let complete = clock.next(period, open.start_ms) == boundary;
        self.seq += 1;
        let record = Record {
            start_ms: open.start_ms,
            end_ms: boundary,
            delta: read.total - open.total_start,
            total_start: open.total_start,
            total_end: read.total,
            lag_start_ms: open.lag_ms,
            lag_end_ms: lag,
            status: if complete {
                Status::Complete
            } else {
                Status::Merged
            },
            seq: self.seq,
            events: std::mem::take(&mut open.events),
            booking: None,
        };
        *open = Open {
            start_ms: boundary,
            total_start: read.total,
            lag_ms: lag,
            events: Vec::new(),
        };
        self.next_ms = Some(clock.next(period, boundary));
        Some(record)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(at_ms: i64, total: i64) -> Read {
        Read {
            at_ms,
            total,
            event: None,
        }
    }

    fn run(reads: &[Read]) -> Vec<Record> {
        let clock = Clock::default();
        let p = Period::parse("10s").unwrap();
        let mut st = IntervalState::default();
        reads
            .iter()
            .filter_map(|r| st.observe(&clock, &p, *r))
            .collect()
    }

    #[test]
    fn boundary_reads_close_complete_records_with_the_exact_delta() {
        let recs = run(&[
            read(100_050, 7),
            read(105_000, 9),
            read(110_040, 12),
            read(120_030, 20),
        ]);
        assert_eq!(recs.len(), 2);
        let r = &recs[0];
        assert_eq!((r.start_ms, r.end_ms, r.delta), (100_000, 110_000, 5));
        assert_eq!((r.total_start, r.total_end), (7, 12));
        assert_eq!((r.lag_start_ms, r.lag_end_ms), (50, 40));
        assert_eq!((r.status, r.seq), (Status::Complete, 1));
        assert_eq!(
            (recs[1].start_ms, recs[1].delta, recs[1].seq),
            (110_000, 8, 2)
        );
    }

    #[test]
    fn records_start_at_the_first_boundary_read_not_at_the_first_read() {
        let recs = run(&[read(103_000, 1), read(110_010, 4), read(120_010, 9)]);
        assert_eq!(recs.len(), 1);
        assert_eq!((recs[0].start_ms, recs[0].delta), (110_000, 5));
    }

    #[test]
    fn a_missed_boundary_is_not_guessed_the_next_boundary_read_closes_one_merged_record() {
        // Reads at 110 s come 5 s late (past the 2.5 s a 10 s period allows): missed.
        let recs = run(&[
            read(100_010, 0),
            read(115_000, 30),
            read(120_020, 44),
            read(130_020, 50),
        ]);
        assert_eq!(recs.len(), 2);
        assert_eq!(
            (
                recs[0].start_ms,
                recs[0].end_ms,
                recs[0].delta,
                recs[0].status
            ),
            (100_000, 120_000, 44, Status::Merged)
        );
        assert_eq!(recs[1].status, Status::Complete);
        assert_eq!(recs[1].start_ms, recs[0].end_ms, "records tile time");
    }

    #[test]
    fn events_of_an_interval_are_listed_once_in_order_and_belong_to_the_read_that_books_them() {
        let ev = |at_ms, total, e| Read {
            at_ms,
            total,
            event: Some(e),
        };
        let recs = run(&[
            read(100_010, 0),
            ev(103_000, 2, Event::Reset),
            ev(104_000, 3, Event::Rollover),
            ev(105_000, 4, Event::Reset),
            ev(110_010, 9, Event::Gap),
            read(120_010, 10),
        ]);
        assert_eq!(recs[0].events, [Event::Reset, Event::Rollover, Event::Gap]);
        assert!(recs[1].events.is_empty());
    }

    #[test]
    fn a_wall_clock_stepping_back_closes_nothing_and_never_overlaps() {
        let recs = run(&[
            read(100_010, 0),
            read(110_010, 5),
            read(95_000, 6),
            read(120_010, 9),
        ]);
        assert_eq!(recs.len(), 2);
        assert_eq!((recs[1].start_ms, recs[1].delta), (110_000, 4));
    }

    #[test]
    fn a_berlin_spring_day_is_one_complete_23_hour_record() {
        let clock = Clock::named("Europe/Berlin").unwrap();
        let day = Period::parse("1d").unwrap();
        let at = |t: &str| t.parse::<jiff::Timestamp>().unwrap().as_millisecond();
        let mut st = IntervalState::default();
        let mut records = Vec::new();
        // Midnight CET, a read every hour through the day, midnight CEST.
        let start = at("2026-03-28T23:00:05Z");
        for h in 0..=22 {
            let r = read(start + h * 3_600_000, h * 10);
            records.extend(st.observe(&clock, &day, r));
        }
        assert!(
            records.is_empty(),
            "the day is not over before 22:00Z (midnight CEST)"
        );
        records.extend(st.observe(&clock, &day, read(at("2026-03-29T22:00:07Z"), 250)));
        assert_eq!(records.len(), 1);
        let r = &records[0];
        assert_eq!(r.end_ms - r.start_ms, 23 * 3_600_000);
        assert_eq!(
            (r.status, r.delta, r.lag_end_ms),
            (Status::Complete, 250, 7_000)
        );
    }

    #[test]
    fn the_state_survives_a_save_and_a_restart_closes_the_interval_complete() {
        let clock = Clock::default();
        let p = Period::parse("10s").unwrap();
        let mut st = IntervalState::default();
        st.observe(&clock, &p, read(100_010, 3));
        let saved = serde_json::to_string(&st).unwrap();
        let mut back: IntervalState = serde_json::from_str(&saved).unwrap();
        let r = back.observe(&clock, &p, read(110_020, 10)).unwrap();
        assert_eq!((r.status, r.delta, r.seq), (Status::Complete, 7, 1));
    }

    #[test]
    fn an_unsent_record_survives_a_save_whole() {
        let st = IntervalState {
            unsent: run(&[
                read(100_050, 7),
                Read {
                    event: Some(Event::Reset),
                    ..read(105_000, 2)
                },
                read(110_040, 12),
            ]),
            ..Default::default()
        };
        let saved = serde_json::to_string(&st).unwrap();
        let back: IntervalState = serde_json::from_str(&saved).unwrap();
        assert_eq!(back.unsent, st.unsent);
        assert_eq!(back.unsent[0].events, vec![Event::Reset]);
    }
}
