//! Counter truth: a module's count → delta, total and events, so that every pulse is booked once.
//!
//! Pure: time comes in as a [`Stamp`] with each count: the wall clock (for `ts` and across
//! restarts) and a monotonic clock (for elapsed time within a run, so a wall clock that steps
//! never creates or hides pulses).
//!
//! A 32-bit count wraps; a module that restarts or is cleared by someone else jumps to 0; a noisy
//! read may return a lone wrong value. A jump is plausible only if the rate it implies is possible
//! at the channel's highest input rate; a jump across the wrap point must in addition fit what the
//! channel itself has shown (its observed peak rate, with a margin), so that a module that lost
//! power during a long absence is a reset, not four billion pulses. Any other jump is *suspect*:
//! the total does not move until the next read says which story is true. If the next count
//! continues from the old one, the suspect read was a glitch; if it continues from the suspect
//! one, the module was reset and the new count is the number of pulses since the reset.

use serde::{Deserialize, Serialize};

use crate::event::Event;

/// When a count was read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stamp {
    /// Milliseconds since the Unix epoch (the wall clock: may step either way).
    pub wall_ms: u64,
    /// Milliseconds on a clock that never steps, valid within one run of the gateway.
    pub mono_ms: u64,
}

impl Stamp {
    /// A stamp whose two clocks agree (tests, tools).
    pub fn at(ms: u64) -> Stamp {
        Stamp {
            wall_ms: ms,
            mono_ms: ms,
        }
    }
}

/// Which way a count moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Either way, taken the short way round (encoders).
    Both,
    /// Only up: a lower count is a wrap or a reset (unsigned inputs, counters counting up).
    Up,
    /// Only down (a ZH-YX1600 counter commanded to count down).
    Down,
}

/// How a channel counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CounterSpec {
    /// Number of distinct count values (2^32 for 32-bit counts).
    pub modulus: i64,
    pub direction: Direction,
    /// Highest input rate the module can count, in pulses per second.
    pub max_rate_hz: f64,
    /// Where the count stands after a reset the gateway did not make.
    pub restart: Restart,
}

/// Where a count starts again after a reset the gateway did not make (a module that lost power,
/// a clear by another master, a meter replaced).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Restart {
    /// From zero: the count after the reset is the number of pulses since (a pulse input).
    FromZero,
    /// Anywhere: a meter replaced by another stands wherever the new one's register stood when
    /// it was fitted; counting goes on from the first read of it, and what the register held
    /// then is no delta (a meter register).
    FromFirstRead,
}

/// For this long a channel may go from idle to the datasheet's maximum rate: a wrap within it is
/// judged by the datasheet alone, as before any history existed.
pub const BURST_MS: u64 = 10_000;
/// Margin on the observed peak rate when judging a wrap over a longer time.
pub const PEAK_MARGIN: f64 = 4.0;
/// Deltas over shorter times do not teach the peak rate (timing jitter would inflate it).
const PEAK_MIN_MS: u64 = 50;

impl CounterSpec {
    /// Largest jump that `elapsed_ms` can explain at the datasheet's maximum input rate, with
    /// room for timing jitter.
    pub fn plausible(&self, elapsed_ms: u64) -> i64 {
        let secs = elapsed_ms.max(1) as f64 / 1000.0;
        (self.max_rate_hz * secs * 1.25 + 16.0) as i64
    }

    /// Largest jump across the wrap point that `elapsed_ms` can explain for a channel whose
    /// observed peak rate is `peak_hz`: a burst at the datasheet maximum for up to
    /// [`BURST_MS`], plus [`PEAK_MARGIN`] × the peak for the whole time, and never more than
    /// the datasheet allows.
    pub fn plausible_wrap(&self, elapsed_ms: u64, peak_hz: u64) -> i64 {
        let secs = elapsed_ms as f64 / 1000.0;
        let burst = self.plausible(elapsed_ms.min(BURST_MS)) as f64;
        let history = burst + PEAK_MARGIN * peak_hz as f64 * secs;
        self.plausible(elapsed_ms).min(history as i64)
    }

    /// The movement from `from` to `to` in the channel's direction, and whether it crossed the
    /// wrap point.
    fn movement(&self, from: i64, to: i64) -> (i64, bool) {
        let m = self.modulus;
        match self.direction {
            Direction::Both => {
                let mut d = (to - from).rem_euclid(m);
                if d >= m / 2 {
                    d -= m;
                }
                (d, d != to - from)
            }
            Direction::Up => ((to - from).rem_euclid(m), to < from),
            Direction::Down => (-(from - to).rem_euclid(m), to > from),
        }
    }
}

/// What a channel remembers between reads, and across restarts (saved in the state file).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct CounterState {
    /// The last count booked into the total, and when it was read (wall clock).
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
    /// Highest rate the channel has shown (pulses per second, rounded up, capped at the
    /// datasheet maximum): bounds what a wrap after a long absence can be.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub peak_hz: u64,
    /// The open interval and record seq of each configured period (keyed by the period as
    /// written): a restart mid-interval still closes it from its saved start.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub intervals: std::collections::BTreeMap<String, crate::metering::IntervalState>,
    /// The offset of the channel's meter reading (`set_reading`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meter: Option<crate::metering::meter::MeterOffset>,
    /// Its tariff registers and open billing period (`[tariffs]`, `[billing]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub account: Option<crate::metering::account::Account>,
    /// Only in a state file, when it differs from `seq` and `total`: the channel's last
    /// reading handed to the MQTT side before the save. The pulses between it and `total`
    /// (deltas the publish policy carried, readings a crash took while they waited for a
    /// save) ride on the next run's first reading.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub handed: Option<Handed>,
}

/// The seq and total of a reading handed to the MQTT side.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Handed {
    pub seq: u64,
    pub total: i64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
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
    /// Monotonic time of the last booked read and of the suspect read, in this run. `None`
    /// after a resume: then the saved wall-clock time is all there is.
    mono: Option<u64>,
    suspect_mono: Option<u64>,
}

/// Time from `then` to `now`: monotonic where `then` was taken in this run, wall clock across a
/// restart. A wall clock that went backwards gives 0, which makes no jump more plausible.
fn elapsed(now: Stamp, wall_then: u64, mono_then: Option<u64>) -> u64 {
    match mono_then {
        Some(m) => now.mono_ms.saturating_sub(m),
        None => now.wall_ms.saturating_sub(wall_then),
    }
}

impl Counter {
    pub fn new(spec: CounterSpec) -> Counter {
        Counter {
            spec,
            state: CounterState::default(),
            mono: None,
            suspect_mono: None,
        }
    }

    /// Resumes from saved state: the first delta is taken against the saved count and flagged
    /// as a gap, so pulses counted while the gateway was down are booked once.
    pub fn resume(spec: CounterSpec, mut state: CounterState) -> Counter {
        state.gap = state.count.is_some();
        Counter {
            spec,
            state,
            mono: None,
            suspect_mono: None,
        }
    }

    /// The same state counted under a new spec (a changed run direction): the monotonic times
    /// of this run are kept.
    pub fn with_spec(&self, spec: CounterSpec) -> Counter {
        Counter {
            spec,
            ..self.clone()
        }
    }

    /// The device was away: the next delta covers the gap.
    pub fn mark_gap(&mut self) {
        if self.state.count.is_some() {
            self.state.gap = true;
        }
    }

    /// Books a count read at `at`. `None` when the read is held as suspect: it is not
    /// published (no phantom value on a dashboard) and the next read decides what it was.
    pub fn update(&mut self, count: i64, at: Stamp) -> Option<Update> {
        let Some(last) = self.state.count else {
            self.state.seq += 1;
            self.state.count = Some(count);
            self.state.at_ms = at.wall_ms;
            self.mono = Some(at.mono_ms);
            return Some(self.outcome(0, None, None));
        };
        let since_last = elapsed(at, self.state.at_ms, self.mono);
        let (d, wrapped) = self.spec.movement(last, count);
        let limit = if wrapped {
            self.spec.plausible_wrap(since_last, self.state.peak_hz)
        } else {
            self.spec.plausible(since_last)
        };
        if d.abs() <= limit {
            let event = wrapped.then_some(Event::Rollover);
            return Some(self.book(count, at, d, event, since_last));
        }
        // Does not follow from the last booked count. Does it follow from a suspect read?
        if let Some((suspect, suspect_at)) = self.state.suspect {
            let since = elapsed(at, suspect_at, self.suspect_mono);
            let (ds, _) = self.spec.movement(suspect, count);
            if ds.abs() <= self.spec.plausible(since) {
                // The module was reset: it has counted `count` pulses since (from zero); a
                // meter register counts on from the first read of the new meter.
                let delta = match self.spec.restart {
                    Restart::FromZero => count,
                    Restart::FromFirstRead => ds,
                };
                return Some(self.book(count, at, delta, Some(Event::Reset), since));
            }
        }
        self.state.suspect = Some((count, at.wall_ms));
        self.suspect_mono = Some(at.mono_ms);
        None
    }

    /// The gateway cleared, preset or (re)started the channel and read back `count`: the total
    /// stays, the next delta is taken from `count`.
    pub fn rebase(&mut self, count: i64, at: Stamp, event: Event) -> Update {
        let s = &mut self.state;
        s.seq += 1;
        s.count = Some(count);
        s.at_ms = at.wall_ms;
        s.suspect = None;
        s.gap = false;
        self.mono = Some(at.mono_ms);
        self.suspect_mono = None;
        self.outcome(0, Some(event), None)
    }

    /// The gateway wrote `written` (0 for a clear, the preset value) and read back `count`: the
    /// pulses counted between the write and the read-back are booked (the movement from
    /// `written` to `count`), so a clear while counting loses nothing it could see.
    pub fn rebase_from(&mut self, written: i64, count: i64, at: Stamp, event: Event) -> Update {
        let (delta, _) = self.spec.movement(written, count);
        let s = &mut self.state;
        s.seq += 1;
        s.count = Some(count);
        s.at_ms = at.wall_ms;
        s.total += delta;
        s.suspect = None;
        s.gap = false;
        self.mono = Some(at.mono_ms);
        self.suspect_mono = None;
        self.outcome(delta, Some(event), None)
    }

    fn book(
        &mut self,
        count: i64,
        at: Stamp,
        delta: i64,
        event: Option<Event>,
        elapsed_ms: u64,
    ) -> Update {
        let rate = rate(delta, elapsed_ms);
        let max = self.spec.max_rate_hz;
        let s = &mut self.state;
        if elapsed_ms >= PEAK_MIN_MS
            && let Some(r) = rate
        {
            s.peak_hz = s.peak_hz.max(r.abs().min(max).ceil() as u64);
        }
        s.seq += 1;
        s.count = Some(count);
        s.at_ms = at.wall_ms;
        s.total += delta;
        s.suspect = None;
        self.mono = Some(at.mono_ms);
        self.suspect_mono = None;
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
            direction: Direction::Up,
            max_rate_hz: rate,
            restart: Restart::FromZero,
        })
    }

    fn encoder(rate: f64) -> Counter {
        Counter::new(CounterSpec {
            modulus: M,
            direction: Direction::Both,
            max_rate_hz: rate,
            restart: Restart::FromZero,
        })
    }

    /// Feeds (count, ms) pairs and returns the updates (held reads as `None`).
    fn feed(c: &mut Counter, reads: &[(i64, u64)]) -> Vec<Option<Update>> {
        reads
            .iter()
            .map(|&(n, t)| c.update(n, Stamp::at(t)))
            .collect()
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
        let u = c.update(500, Stamp::at(0)).unwrap();
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
        let u = c.rebase(0, Stamp::at(510), Event::Cleared);
        assert_eq!((u.delta, u.total, u.event), (0, 500, Some(Event::Cleared)));
        let u = c.update(490, Stamp::at(1000)).unwrap();
        assert_eq!((u.delta, u.total, u.event), (490, 990, None));
    }

    #[test]
    fn a_preset_by_the_gateway_never_moves_the_total() {
        let mut c = encoder(1000.0);
        booked(&mut c, &[(0, 0), (-500, 500)]);
        let u = c.rebase(3000, Stamp::at(510), Event::Preset);
        assert_eq!((u.total, u.event), (-500, Some(Event::Preset)));
        let u = c.update(3100, Stamp::at(600)).unwrap();
        assert_eq!((u.delta, u.total), (100, -400));
    }

    #[test]
    fn resuming_books_the_pulses_counted_while_away_once_as_a_gap() {
        let mut c = di(1000.0);
        booked(&mut c, &[(0, 0), (1000, 1000)]);
        let saved = c.state.clone();
        let mut c = Counter::resume(c.spec, saved);
        let u = c.update(6000, Stamp::at(6000)).unwrap();
        assert_eq!((u.delta, u.total, u.event), (5000, 6000, Some(Event::Gap)));
        assert_eq!(u.seq, 3);
        let u = c.update(6500, Stamp::at(6500)).unwrap();
        assert_eq!(u.event, None);
    }

    #[test]
    fn a_device_that_was_away_books_its_gap_on_return() {
        let mut c = di(1000.0);
        booked(&mut c, &[(0, 0)]);
        c.mark_gap();
        let u = c.update(3000, Stamp::at(3000)).unwrap();
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

    const HOUR: u64 = 3_600_000;
    const DAY: u64 = 24 * HOUR;

    /// Polls a channel counting `hz` every 200 ms for `n` polls, starting at `count` and
    /// `at` (wall clock `wall_offset` away from the monotonic one); returns the last count.
    fn poll_steady(c: &mut Counter, count: i64, at: u64, hz: i64, n: u64, wall: i64) -> i64 {
        let mut last = count;
        for i in 0..n {
            let mono = at + i * 200;
            last = count + hz * (i as i64) / 5;
            let stamp = Stamp {
                wall_ms: (mono as i64 + wall) as u64,
                mono_ms: mono,
            };
            let u = c.update(last, stamp).expect("booked");
            assert_eq!(u.event, None, "poll {i}");
        }
        last
    }

    #[test]
    fn a_wall_clock_stepped_back_an_hour_mid_run_books_exactly_the_module_count() {
        let mut c = di(2000.0);
        let start = 10 * HOUR;
        let mid = poll_steady(&mut c, 0, start, 2000, 50, 0);
        // The same monotonic time goes on; the wall clock is an hour behind from here.
        let end = poll_steady(
            &mut c,
            mid + 400,
            start + 50 * 200,
            2000,
            50,
            -(HOUR as i64),
        );
        assert_eq!(c.state.total, end);
    }

    #[test]
    fn a_wall_clock_stepped_forward_an_hour_mid_run_books_exactly_the_module_count() {
        let mut c = di(2000.0);
        let mid = poll_steady(&mut c, 0, 0, 2000, 50, 0);
        let end = poll_steady(&mut c, mid + 400, 50 * 200, 2000, 50, HOUR as i64);
        assert_eq!(c.state.total, end);
        assert!(c.state.peak_hz <= 2000, "rates from the monotonic clock");
    }

    #[test]
    fn after_two_days_away_a_lower_count_of_a_slow_channel_is_a_reset_not_a_wrap() {
        let mut c = di(50_000.0);
        // Counts at 5 Hz for a minute, then the gateway stops (state saved).
        booked(&mut c, &[(1_000_000, 0), (1_000_300, 60_000)]);
        assert_eq!(c.state.peak_hz, 5);
        let saved = c.state.clone();
        // Two days later the module has restarted from 0 and counted 18, then 20.
        let mut c = Counter::resume(c.spec, saved);
        let back = 60_000 + 2 * DAY;
        assert_eq!(c.update(18, Stamp::at(back)), None, "held, not a wrap");
        let u = c.update(20, Stamp::at(back + 200)).unwrap();
        assert_eq!((u.delta, u.event), (20, Some(Event::Reset)));
        assert_eq!(c.state.total, 300 + 20);
    }

    #[test]
    fn a_fast_channel_that_really_wrapped_during_a_long_absence_still_books_the_wrap() {
        let mut c = di(50_000.0);
        // 20 kHz, seen by the gateway.
        booked(
            &mut c,
            &[(0, 0), (20_000, 1000), (4_000_000_000, 200_000_000)],
        );
        assert_eq!(c.state.peak_hz, 20_000);
        let saved = c.state.clone();
        let mut c = Counter::resume(c.spec, saved);
        // Two days later it has wrapped and stands at 50_000.
        let u = c
            .update(50_000, Stamp::at(200_000_000 + 2 * DAY))
            .expect("a wrap the channel's history allows");
        assert_eq!(u.delta, (1 << 32) - 4_000_000_000 + 50_000);
        assert_eq!(u.event, Some(Event::Gap));
    }

    #[test]
    fn a_quiet_channel_near_the_top_still_wraps_within_the_burst_time() {
        let mut c = di(50_000.0);
        booked(&mut c, &[(4_294_967_000, 0), (4_294_967_000, 60_000)]);
        assert_eq!(c.state.peak_hz, 0);
        let u = c.update(500, Stamp::at(65_000)).unwrap();
        assert_eq!((u.delta, u.event), (796, Some(Event::Rollover)));
    }

    #[test]
    fn the_wrap_window_grows_with_the_observed_peak_only() {
        let spec = di(50_000.0).spec;
        // Within the burst time the datasheet decides.
        assert_eq!(spec.plausible_wrap(5_000, 0), spec.plausible(5_000));
        // Beyond it, the peak with its margin: 2 days at 5 Hz is about 3.5 million pulses.
        let two_days = spec.plausible_wrap(2 * DAY, 5);
        assert!((3_000_000..4_500_000).contains(&two_days), "{two_days}");
        // Never more than the datasheet's maximum.
        assert_eq!(
            spec.plausible_wrap(2 * DAY, 1_000_000),
            spec.plausible(2 * DAY)
        );
    }

    #[test]
    fn across_a_restart_a_wall_clock_that_went_backwards_makes_no_jump_plausible() {
        let mut c = di(50_000.0);
        booked(&mut c, &[(0, 10 * HOUR), (1000, 10 * HOUR + 1000)]);
        let mut c = Counter::resume(c.spec, c.state.clone());
        // Restarted with the wall clock a day behind: 10 million more is not plausible in 0 s.
        assert_eq!(c.update(10_001_000, Stamp::at(9 * HOUR)), None);
    }

    #[test]
    fn the_peak_rate_is_saved_and_capped_at_the_datasheet_maximum() {
        let mut c = di(1000.0);
        booked(&mut c, &[(0, 0), (1000, 1000)]);
        // A reset confirmed over a short time does not teach an impossible rate.
        feed(&mut c, &[(3_000_000_000, 1100), (3_000_000_100, 1150)]);
        assert!(c.state.peak_hz <= 1000, "{}", c.state.peak_hz);
        let text = serde_json::to_string(&c.state).unwrap();
        assert!(text.contains("\"peak_hz\":1000"), "{text}");
        let back: CounterState = serde_json::from_str(&text).unwrap();
        assert_eq!(back.peak_hz, c.state.peak_hz);
        // State saved before this field existed loads with no history.
        let old: CounterState =
            serde_json::from_str(r#"{"count":5,"at_ms":1,"total":2,"seq":3}"#).unwrap();
        assert_eq!(old.peak_hz, 0);
    }

    #[test]
    fn a_counter_counting_down_books_negative_deltas_and_a_rise_is_suspect() {
        let mut c = Counter::new(CounterSpec {
            modulus: M,
            direction: Direction::Down,
            max_rate_hz: 1000.0,
            restart: Restart::FromZero,
        });
        let u = booked(&mut c, &[(0, 0), (-300, 500)]);
        assert_eq!((u[1].delta, u[1].event), (-300, None));
        assert_eq!(
            c.update(-100, Stamp::at(600)),
            None,
            "a rise is not counting down"
        );
    }

    #[test]
    fn a_clear_books_the_pulses_counted_between_the_write_and_the_read_back() {
        let mut c = di(1000.0);
        booked(&mut c, &[(500, 0), (700, 200)]);
        let u = c.rebase_from(0, 7, Stamp::at(210), Event::Cleared);
        assert_eq!((u.delta, u.total, u.event), (7, 207, Some(Event::Cleared)));
        let next = c.update(57, Stamp::at(260)).expect("booked");
        assert_eq!((next.delta, next.total), (50, 257));
    }

    #[test]
    fn a_preset_of_an_encoder_books_its_movement_both_ways() {
        let mut c = encoder(1000.0);
        booked(&mut c, &[(10, 0)]);
        assert_eq!(
            c.rebase_from(3000, 2996, Stamp::at(10), Event::Preset)
                .delta,
            -4
        );
    }
}
