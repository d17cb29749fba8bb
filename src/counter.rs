//! Counter truth: a module's count → delta, total and events, so that every pulse is booked once.
//!
//! Pure: time comes in as wall-clock milliseconds with each count.
//!
//! A 32-bit count wraps; a module that restarts or is cleared by someone else jumps to 0; a noisy
//! read may return a lone wrong value. A jump is a wrap only if the rate it implies is possible
//! at the channel's highest input rate. Any other jump is *suspect*: the total does not move until
//! the next read says which story is true. If the next count continues from the old one, the
//! suspect read was a glitch; if it continues from the suspect one, the module was reset and the
//! new count is the number of pulses since the reset.

use serde::{Deserialize, Serialize};

/// Something other than counting happened on a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Event {
    /// The count wrapped around its 32-bit range.
    Rollover,
    /// The module restarted or someone else cleared it; delta is the count since then.
    Reset,
    /// The gateway cleared the channel.
    Cleared,
    /// The gateway preset the channel.
    Preset,
    /// The gateway or the device was away; the delta covers the whole gap.
    Gap,
}

/// How a channel counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CounterSpec {
    /// Number of distinct count values (2^32 for 32-bit counts).
    pub modulus: i64,
    /// Signed counts (encoders, ZH-YX1600) move both ways; unsigned ones only up.
    pub signed: bool,
    /// Highest input rate the module can count, in pulses per second.
    pub max_rate_hz: f64,
}

impl CounterSpec {
    /// Largest jump that `elapsed_ms` can explain, with room for timing jitter.
    pub fn plausible(&self, elapsed_ms: u64) -> i64 {
        let secs = elapsed_ms.max(1) as f64 / 1000.0;
        (self.max_rate_hz * secs * 1.25 + 16.0) as i64
    }

    /// The movement from `from` to `to` taken the short way round (signed) or forward
    /// (unsigned), and whether it crossed the wrap point.
    fn movement(&self, from: i64, to: i64) -> (i64, bool) {
        let m = self.modulus;
        if self.signed {
            let mut d = (to - from).rem_euclid(m);
            if d >= m / 2 {
                d -= m;
            }
            (d, d != to - from)
        } else {
            let d = (to - from).rem_euclid(m);
            (d, to < from)
        }
    }
}

/// What a channel remembers between reads, and across restarts (saved in the state file).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct CounterState {
    /// The last count booked into the total, and when it was read.
    pub count: Option<i64>,
    pub at_ms: u64,
    /// Running sum of deltas.
    pub total: i64,
    /// Readings published so far.
    pub seq: u64,
    /// A read that did not fit, waiting for the next one to confirm or refute it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub suspect: Option<(i64, u64)>,
    /// The next delta covers a time the gateway did not watch.
    #[serde(default)]
    pub gap: bool,
}

/// The outcome of one read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Update {
    pub delta: i64,
    pub total: i64,
    pub seq: u64,
    /// Pulses per second over the time since the previous booked read.
    pub rate_hz: Option<f64>,
    pub event: Option<Event>,
}

/// A channel's counter: spec plus state.
#[derive(Debug, Clone, PartialEq)]
pub struct Counter {
    pub spec: CounterSpec,
    pub state: CounterState,
}

impl Counter {
    pub fn new(spec: CounterSpec) -> Counter {
        Counter {
            spec,
            state: CounterState::default(),
        }
    }

    /// Resumes from saved state: the first delta is taken against the saved count and flagged
    /// as a gap, so pulses counted while the gateway was down are booked once.
    pub fn resume(spec: CounterSpec, mut state: CounterState) -> Counter {
        state.gap = state.count.is_some();
        Counter { spec, state }
    }

    /// The device was away: the next delta covers the gap.
    pub fn mark_gap(&mut self) {
        if self.state.count.is_some() {
            self.state.gap = true;
        }
    }

    /// Books a count read at `at_ms`. `None` when the read is held as suspect: it is not
    /// published (no phantom value on a dashboard) and the next read decides what it was.
    pub fn update(&mut self, count: i64, at_ms: u64) -> Option<Update> {
        let s = &mut self.state;
        let Some(last) = s.count else {
            s.count = Some(count);
            s.at_ms = at_ms;
            s.seq += 1;
            return Some(self.outcome(0, None, None));
        };
        let elapsed = at_ms.saturating_sub(s.at_ms);
        let (d, wrapped) = self.spec.movement(last, count);
        if d.abs() <= self.spec.plausible(elapsed) {
            let rate = rate(d, elapsed);
            return Some(self.book(count, at_ms, d, wrapped.then_some(Event::Rollover), rate));
        }
        // Does not follow from the last booked count. Does it follow from a suspect read?
        if let Some((suspect, suspect_at)) = s.suspect {
            let since = at_ms.saturating_sub(suspect_at);
            let (ds, _) = self.spec.movement(suspect, count);
            if ds.abs() <= self.spec.plausible(since) {
                // The module was reset: it has counted `count` pulses since (from zero).
                let rate = rate(ds, since);
                return Some(self.book(count, at_ms, count, Some(Event::Reset), rate));
            }
        }
        s.suspect = Some((count, at_ms));
        None
    }

    /// The gateway cleared or preset the channel and read back `count`: the total stays, the
    /// next delta is taken from `count`.
    pub fn rebase(&mut self, count: i64, at_ms: u64, event: Event) -> Update {
        let s = &mut self.state;
        s.seq += 1;
        s.count = Some(count);
        s.at_ms = at_ms;
        s.suspect = None;
        s.gap = false;
        self.outcome(0, Some(event), None)
    }

    /// The gateway wrote `written` (0 for a clear, the preset value) and read back `count`: the
    /// pulses counted between the write and the read-back are booked (the movement from
    /// `written` to `count`), so a clear while counting loses nothing it could see.
    pub fn rebase_from(&mut self, written: i64, count: i64, at_ms: u64, event: Event) -> Update {
        let (delta, _) = self.spec.movement(written, count);
        let s = &mut self.state;
        s.seq += 1;
        s.count = Some(count);
        s.at_ms = at_ms;
        s.total += delta;
        s.suspect = None;
        s.gap = false;
        self.outcome(delta, Some(event), None)
    }

    fn book(
        &mut self,
        count: i64,
        at_ms: u64,
        delta: i64,
        event: Option<Event>,
        rate: Option<f64>,
    ) -> Update {
        let s = &mut self.state;
        s.seq += 1;
        s.count = Some(count);
        s.at_ms = at_ms;
        s.total += delta;
        s.suspect = None;
        let event = if std::mem::take(&mut s.gap) {
            event.filter(|e| *e == Event::Reset).or(Some(Event::Gap))
        } else {
            event
        };
        self.outcome(delta, event, rate)
    }

    fn outcome(&self, delta: i64, event: Option<Event>, rate_hz: Option<f64>) -> Update {
        Update {
            delta,
            total: self.state.total,
            seq: self.state.seq,
            rate_hz,
            event,
        }
    }
}

fn rate(delta: i64, elapsed_ms: u64) -> Option<f64> {
    (elapsed_ms > 0).then(|| delta as f64 * 1000.0 / elapsed_ms as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: i64 = 1 << 32;

    fn di(rate: f64) -> Counter {
        Counter::new(CounterSpec {
            modulus: M,
            signed: false,
            max_rate_hz: rate,
        })
    }

    fn encoder(rate: f64) -> Counter {
        Counter::new(CounterSpec {
            modulus: M,
            signed: true,
            max_rate_hz: rate,
        })
    }

    /// Feeds (count, ms) pairs and returns the updates (held reads as `None`).
    fn feed(c: &mut Counter, reads: &[(i64, u64)]) -> Vec<Option<Update>> {
        reads.iter().map(|&(n, t)| c.update(n, t)).collect()
    }

    /// Like [`feed`] for reads that are all booked.
    fn booked(c: &mut Counter, reads: &[(i64, u64)]) -> Vec<Update> {
        feed(c, reads)
            .into_iter()
            .map(|u| u.expect("booked"))
            .collect()
    }

    #[test]
    fn the_first_read_books_nothing() {
        let mut c = di(1000.0);
        let u = c.update(500, 0).unwrap();
        assert_eq!((u.delta, u.total, u.seq, u.event), (0, 0, 1, None));
    }

    #[test]
    fn steady_counting_adds_up() {
        let mut c = di(1000.0);
        let u = booked(&mut c, &[(0, 0), (500, 500), (1000, 1000)]);
        assert_eq!(u.iter().map(|u| u.delta).collect::<Vec<_>>(), [0, 500, 500]);
        assert_eq!(c.state.total, 1000);
        assert_eq!(u[2].rate_hz, Some(1000.0));
    }

    #[test]
    fn an_unsigned_count_wraps_at_2_pow_32_with_a_positive_delta() {
        let mut c = di(1000.0);
        let u = booked(&mut c, &[(4_294_967_000, 0), (204, 500)]);
        assert_eq!(u[1].delta, 500);
        assert_eq!(u[1].event, Some(Event::Rollover));
        assert_eq!(c.state.total, 500);
    }

    #[test]
    fn an_encoder_crosses_the_i32_boundary_both_ways() {
        let mut c = encoder(1000.0);
        let max = i64::from(i32::MAX);
        let min = i64::from(i32::MIN);
        let u = booked(&mut c, &[(max - 100, 0), (min + 99, 200), (max - 100, 400)]);
        assert_eq!(u[1].delta, 200);
        assert_eq!(u[1].event, Some(Event::Rollover));
        assert_eq!(u[2].delta, -200);
        assert_eq!(u[2].event, Some(Event::Rollover));
        assert_eq!(c.state.total, 0);
    }

    #[test]
    fn an_encoder_moving_backwards_gives_negative_deltas_without_events() {
        let mut c = encoder(1000.0);
        let u = booked(&mut c, &[(100, 0), (-50, 500)]);
        assert_eq!((u[1].delta, u[1].event), (-150, None));
    }

    #[test]
    fn a_lone_zero_read_does_not_move_the_total_and_is_not_published() {
        let mut c = di(1000.0);
        let u = feed(&mut c, &[(1_000_000, 0), (0, 500), (1_001_000, 1000)]);
        assert_eq!(u[1], None, "the odd read is held, not published");
        let last = u[2].unwrap();
        assert_eq!((last.delta, last.event, last.seq), (1000, None, 2));
        assert_eq!(c.state.total, 1000);
    }

    #[test]
    fn a_module_reset_is_booked_once_as_pulses_since_the_reset() {
        let mut c = di(1000.0);
        // 1_000_000 before; the module restarts and has counted 100, then 600.
        let u = feed(
            &mut c,
            &[(1_000_000, 0), (1_000_400, 400), (100, 900), (600, 1400)],
        );
        assert_eq!(u[1].unwrap().delta, 400);
        assert_eq!(u[2], None, "the first read after the jump is held");
        let reset = u[3].unwrap();
        assert_eq!((reset.delta, reset.event), (600, Some(Event::Reset)));
        assert_eq!(c.state.total, 1000);
    }

    #[test]
    fn a_jump_too_large_for_the_input_rate_is_not_a_wrap() {
        // From near the top to a small count in 0.5 s would be a wrap of 1000 pulses, which a
        // 1 kHz input can do; from the middle it would need ~2^31 pulses: a reset.
        let mut c = di(1000.0);
        let u = feed(&mut c, &[(2_000_000_000, 0), (10, 500), (510, 1000)]);
        assert_eq!(u[1], None);
        assert_eq!(u[2].unwrap().event, Some(Event::Reset));
        assert_eq!(c.state.total, 510);
    }

    #[test]
    fn a_clear_by_the_gateway_never_moves_the_total() {
        let mut c = di(1000.0);
        booked(&mut c, &[(0, 0), (500, 500)]);
        let u = c.rebase(0, 510, Event::Cleared);
        assert_eq!((u.delta, u.total, u.event), (0, 500, Some(Event::Cleared)));
        let u = c.update(490, 1000).unwrap();
        assert_eq!((u.delta, u.total, u.event), (490, 990, None));
    }

    #[test]
    fn a_preset_by_the_gateway_never_moves_the_total() {
        let mut c = encoder(1000.0);
        booked(&mut c, &[(0, 0), (-500, 500)]);
        let u = c.rebase(3000, 510, Event::Preset);
        assert_eq!((u.total, u.event), (-500, Some(Event::Preset)));
        let u = c.update(3100, 600).unwrap();
        assert_eq!((u.delta, u.total), (100, -400));
    }

    #[test]
    fn resuming_books_the_pulses_counted_while_away_once_as_a_gap() {
        let mut c = di(1000.0);
        booked(&mut c, &[(0, 0), (1000, 1000)]);
        let saved = c.state.clone();
        let mut c = Counter::resume(c.spec, saved);
        let u = c.update(6000, 6000).unwrap();
        assert_eq!((u.delta, u.total, u.event), (5000, 6000, Some(Event::Gap)));
        assert_eq!(u.seq, 3);
        let u = c.update(6500, 6500).unwrap();
        assert_eq!(u.event, None);
    }

    #[test]
    fn a_device_that_was_away_books_its_gap_on_return() {
        let mut c = di(1000.0);
        booked(&mut c, &[(0, 0)]);
        c.mark_gap();
        let u = c.update(3000, 3000).unwrap();
        assert_eq!((u.delta, u.event), (3000, Some(Event::Gap)));
    }

    #[test]
    fn seq_counts_published_readings_only() {
        let mut c = di(1000.0);
        let u = feed(&mut c, &[(0, 0), (5, 10), (4_000_000_000, 20), (10, 30)]);
        let seqs: Vec<u64> = u.iter().flatten().map(|u| u.seq).collect();
        assert_eq!(seqs, [1, 2, 3]);
    }

    #[test]
    fn state_round_trips_through_json() {
        let mut c = di(1000.0);
        feed(&mut c, &[(0, 0), (7, 10), (0, 20)]);
        let text = serde_json::to_string(&c.state).unwrap();
        let back: CounterState = serde_json::from_str(&text).unwrap();
        assert_eq!(back, c.state);
    }

    #[test]
    fn a_clear_books_the_pulses_counted_between_the_write_and_the_read_back() {
        let mut c = di(1000.0);
        booked(&mut c, &[(500, 0), (700, 200)]);
        let u = c.rebase_from(0, 7, 210, Event::Cleared);
        assert_eq!((u.delta, u.total, u.event), (7, 207, Some(Event::Cleared)));
        let next = c.update(57, 260).expect("booked");
        assert_eq!((next.delta, next.total), (50, 257));
    }

    #[test]
    fn a_preset_of_an_encoder_books_its_movement_both_ways() {
        let mut c = encoder(1000.0);
        booked(&mut c, &[(10, 0)]);
        assert_eq!(c.rebase_from(3000, 2996, 10, Event::Preset).delta, -4);
    }
}
