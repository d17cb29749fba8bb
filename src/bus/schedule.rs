//! Earliest-deadline-first polling and backoff for offline devices. Pure: instants come in.
//!
//! A device with interval records also has a boundary: the next interval boundary of its
//! channels, when it must be read as soon as the line allows. A boundary that is due goes
//! before every ordinary poll that is due; it does not move the device's own poll phase.

use std::time::Duration;

use tokio::time::Instant;

/// When a device is next due, and how many deadlines it has missed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    pub due: Instant,
    pub interval: Duration,
    pub missed: u64,
    /// The next interval boundary to read at, if the device has intervals.
    pub boundary: Option<Instant>,
}

impl Slot {
    pub fn new(first: Instant, interval: Duration) -> Slot {
        Slot {
            due: first,
            interval,
            missed: 0,
            boundary: None,
        }
    }

    /// When the device wants the line next: its poll or its boundary.
    pub fn next_at(&self) -> Instant {
        self.boundary.map_or(self.due, |b| b.min(self.due))
    }

    /// Whether its boundary has come at `now`.
    pub fn boundary_due(&self, now: Instant) -> bool {
        self.boundary.is_some_and(|b| b <= now)
    }

    /// After a poll that finished at `now`: the next deadline keeps the phase; deadlines that
    /// already passed are counted as missed, not queued up (no catch-up bursts).
    pub fn advance(&mut self, now: Instant) {
        self.due += self.interval;
        if self.due <= now {
            let behind = now - self.due;
            let skipped = (behind.as_nanos() / self.interval.as_nanos().max(1)) as u64 + 1;
            self.missed += skipped;
            self.due += self.interval * skipped as u32;
        }
    }

    /// After a poll that finished at `now`, which was a boundary read if the deadline had not
    /// come: the deadline moves if it had, or if it was less than half an interval away (that
    /// poll is the boundary read, not one more transaction right after it); otherwise the
    /// boundary read leaves the poll phase alone.
    pub fn advance_if_due(&mut self, now: Instant) {
        if self.due <= now + self.interval / 2 {
            self.advance(now);
        }
    }

    /// Moves the deadline to `at` (a backoff probe), counting nothing.
    pub fn defer_to(&mut self, at: Instant) {
        self.due = at;
    }
}

/// The index of the slot due first at `now`: a boundary that has come goes before any
/// ordinary poll (earliest boundary first); otherwise the earliest poll or boundary. Ties go to
/// the lower index, i.e. config order.
///
/// `after_boundary`: the last transaction was a boundary read. Then a poll that is late by half
/// its interval or more goes first: during a burst of boundary reads (many devices due at one
/// boundary) the other devices still get every other turn, so they keep their rate and the
/// boundary reads still get at least half the line.
pub fn earliest(slots: &[Slot], now: Instant, after_boundary: bool) -> Option<usize> {
    let late = slots
        .iter()
        .enumerate()
        .filter(|(_, s)| after_boundary && !s.boundary_due(now) && s.due + s.interval / 2 <= now)
        .min_by_key(|(i, s)| (s.due, *i))
        .map(|(i, _)| i);
    if late.is_some() {
        return late;
    }
    let boundary = slots
        .iter()
        .enumerate()
        .filter(|(_, s)| s.boundary_due(now))
        .min_by_key(|(i, s)| (s.boundary, *i))
        .map(|(i, _)| i);
    boundary.or_else(|| {
        slots
            .iter()
            .enumerate()
            .min_by_key(|(i, s)| (s.next_at(), *i))
            .map(|(i, _)| i)
    })
}

/// Exponential backoff between probes of an offline device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    pub min: Duration,
    pub max: Duration,
    next: Duration,
}

impl Backoff {
    pub fn new(min: Duration, max: Duration) -> Backoff {
        Backoff {
            min,
            max,
            next: min,
        }
    }

    /// The wait before the next probe; each call doubles the following one, up to `max`.
    pub fn next_wait(&mut self) -> Duration {
        let wait = self.next;
        self.next = (self.next * 2).min(self.max);
        wait
    }

    pub fn reset(&mut self) {
        self.next = self.min;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn an_on_time_poll_keeps_the_phase() {
        let t0 = Instant::now();
        let mut s = Slot::new(t0, 100 * MS);
        s.advance(t0 + 30 * MS);
        assert_eq!((s.due, s.missed), (t0 + 100 * MS, 0));
    }

    #[test]
    fn missed_deadlines_are_counted_not_queued() {
        let t0 = Instant::now();
        let mut s = Slot::new(t0, 100 * MS);
        // The poll took 350 ms: deadlines at 100, 200, 300 passed.
        s.advance(t0 + 350 * MS);
        assert_eq!(s.missed, 3);
        assert_eq!(s.due, t0 + 400 * MS);
    }

    #[test]
    fn the_earliest_deadline_goes_first_and_ties_keep_config_order() {
        let t0 = Instant::now();
        let slots = [
            Slot::new(t0 + 50 * MS, MS),
            Slot::new(t0 + 10 * MS, MS),
            Slot::new(t0 + 10 * MS, MS),
        ];
        assert_eq!(earliest(&slots, t0, false), Some(1));
        assert_eq!(earliest(&[], t0, false), None);
    }

    #[test]
    fn a_boundary_that_has_come_goes_before_polls_that_are_overdue() {
        let t0 = Instant::now();
        let mut metered = Slot::new(t0 + 60_000 * MS, 60_000 * MS);
        metered.boundary = Some(t0 + 10 * MS);
        let slots = [Slot::new(t0, 100 * MS), metered];
        // Before the boundary the overdue poll goes first; at it, the boundary read does.
        assert_eq!(earliest(&slots, t0 + 5 * MS, false), Some(0));
        assert_eq!(earliest(&slots, t0 + 10 * MS, false), Some(1));
        assert_eq!(slots[1].next_at(), t0 + 10 * MS);
    }

    #[test]
    fn a_boundary_read_takes_the_place_of_a_poll_due_within_half_an_interval_only() {
        let t0 = Instant::now();
        let mut s = Slot::new(t0 + 400 * MS, 1000 * MS);
        s.advance_if_due(t0 + 50 * MS);
        assert_eq!(
            s.due,
            t0 + 1400 * MS,
            "the poll at 400 ms was the boundary read"
        );
        let mut s = Slot::new(t0 + 800 * MS, 1000 * MS);
        s.advance_if_due(t0 + 50 * MS);
        assert_eq!(s.due, t0 + 800 * MS, "a poll 750 ms away keeps its place");
    }

    #[test]
    fn in_a_burst_of_boundary_reads_a_poll_late_by_half_its_interval_gets_every_other_turn() {
        let t0 = Instant::now();
        let mut slots = vec![Slot::new(t0, 100 * MS)];
        for _ in 0..3 {
            let mut metered = Slot::new(t0 + 60_000 * MS, 60_000 * MS);
            metered.boundary = Some(t0);
            slots.push(metered);
        }
        let at = t0 + 50 * MS;
        // The boundary reads go first; after one, the late poll goes; after it, a boundary.
        assert_eq!(earliest(&slots, at, false), Some(1));
        assert_eq!(earliest(&slots, at, true), Some(0));
        // A poll late by less than half its interval waits for the boundary reads.
        assert_eq!(earliest(&slots, t0 + 40 * MS, true), Some(1));
    }

    #[test]
    fn backoff_doubles_up_to_its_limit_and_resets() {
        let mut b = Backoff::new(Duration::from_secs(1), Duration::from_secs(60));
        let waits: Vec<u64> = (0..8).map(|_| b.next_wait().as_secs()).collect();
        assert_eq!(waits, [1, 2, 4, 8, 16, 32, 60, 60]);
        b.reset();
        assert_eq!(b.next_wait().as_secs(), 1);
    }
}
