//! Earliest-deadline-first polling and backoff for offline devices. Pure: instants come in.

use std::time::Duration;

use tokio::time::Instant;

/// When a device is next due, and how many deadlines it has missed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    pub due: Instant,
    pub interval: Duration,
    pub missed: u64,
}

impl Slot {
    pub fn new(first: Instant, interval: Duration) -> Slot {
        Slot {
            due: first,
            interval,
            missed: 0,
        }
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

    /// Moves the deadline to `at` (a backoff probe), counting nothing.
    pub fn defer_to(&mut self, at: Instant) {
        self.due = at;
    }
}

/// The index of the slot due first (ties go to the lower index, i.e. config order).
pub fn earliest(slots: &[Slot]) -> Option<usize> {
    slots
        .iter()
        .enumerate()
        .min_by_key(|(i, s)| (s.due, *i))
        .map(|(i, _)| i)
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
        assert_eq!(earliest(&slots), Some(1));
        assert_eq!(earliest(&[]), None);
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
