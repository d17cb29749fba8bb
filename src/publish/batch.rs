//! When readings go to the broker: at once, or together with the next polls' (`mqtt.batch`).
//!
//! Each write to the broker costs the gateway a system call and, at QoS 1, a wake-up for the
//! acknowledgements; per poll, that was most of the CPU an RTU transaction costs beyond the
//! Modbus exchange itself. Held for a moment, the readings of several polls leave in one
//! write and are acknowledged in one read. A batch goes out
//! - with the first reading that comes once it is three quarters of a window old: the gateway
//!   is awake for that poll anyway, so frequent polls never need a wake-up of their own for it;
//! - else when the window is over (a timer): no reading waits longer than the window;
//! - with anything else sent meanwhile (the connection's acknowledgements let more out, a
//!   command result, an availability change): nothing is held behind them, order is kept.
//!
//! Only *when* messages are handed to the MQTT client changes: they are in the outbox (and its
//! spool) from the moment they are made, exactly as without a batch.

use std::time::Duration;

use tokio::time::Instant;

/// What to do with the reading just queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Send what is queued now.
    Send,
    /// Hold it; a batch started with it: send at the latest at this time.
    HoldUntil(Instant),
    /// Hold it with the batch already waiting.
    Hold,
}

/// The readings held for the broker, as times (the messages themselves are in the outbox).
#[derive(Debug)]
pub struct Batch {
    window: Duration,
    /// When the oldest held reading was queued.
    since: Option<Instant>,
}

impl Batch {
    /// A zero window sends every reading at once.
    pub fn new(window: Duration) -> Batch {
        Batch {
            window,
            since: None,
        }
    }

    /// A reading was queued at `now`.
    pub fn reading(&mut self, now: Instant) -> Verdict {
        if self.window.is_zero() {
            return Verdict::Send;
        }
        let Some(since) = self.since else {
            self.since = Some(now);
            return Verdict::HoldUntil(now + self.window);
        };
        if now.saturating_duration_since(since) >= self.window * 3 / 4 {
            self.since = None;
            Verdict::Send
        } else {
            Verdict::Hold
        }
    }

    /// Whatever was held has been handed over (the window ran out, or something else was sent).
    pub fn sent(&mut self) {
        self.since = None;
    }

    /// Readings are held: the timer for the end of the window is armed.
    pub fn holding(&self) -> bool {
        self.since.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn without_a_window_every_reading_goes_at_once() {
        let mut b = Batch::new(Duration::ZERO);
        let t = Instant::now();
        assert_eq!(b.reading(t), Verdict::Send);
        assert_eq!(b.reading(t + MS), Verdict::Send);
        assert!(!b.holding());
    }

    #[test]
    fn readings_of_polls_in_the_first_three_quarters_of_the_window_are_held_together() {
        let mut b = Batch::new(250 * MS);
        let t = Instant::now();
        // The first poll starts the batch and says when it must go at the latest.
        assert_eq!(b.reading(t), Verdict::HoldUntil(t + 250 * MS));
        assert_eq!(b.reading(t + 40 * MS), Verdict::Hold);
        assert_eq!(b.reading(t + 124 * MS), Verdict::Hold);
        assert_eq!(b.reading(t + 187 * MS), Verdict::Hold);
        assert!(b.holding());
        // Three quarters of a window on, the next poll takes them all along: no timer
        // wake-up needed.
        assert_eq!(b.reading(t + 188 * MS), Verdict::Send);
        assert!(!b.holding());
        // And the one after starts a new batch.
        let t2 = t + 200 * MS;
        assert_eq!(b.reading(t2), Verdict::HoldUntil(t2 + 250 * MS));
    }

    #[test]
    fn a_batch_sent_by_something_else_starts_afresh() {
        let mut b = Batch::new(250 * MS);
        let t = Instant::now();
        b.reading(t);
        // An acknowledgement let the queued readings out (or a command result went).
        b.sent();
        assert!(!b.holding());
        assert_eq!(b.reading(t + 200 * MS), Verdict::HoldUntil(t + 450 * MS));
    }

    #[test]
    fn a_clock_that_seems_to_run_backwards_holds_rather_than_panics() {
        let mut b = Batch::new(250 * MS);
        let t = Instant::now() + 10 * MS;
        b.reading(t);
        assert_eq!(b.reading(t - 5 * MS), Verdict::Hold);
    }
}
