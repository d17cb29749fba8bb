//! A channel's rate over the last 15 minutes, in fixed buckets: the deltas of its readings
//! summed per bucket, so the memory is the same whatever the poll rate. Pure.

/// Length of a bucket.
pub const BUCKET_MS: i64 = 30_000;
/// Buckets kept: 15 minutes.
pub const BUCKETS: usize = 30;

/// Deltas summed per bucket; bucket `i` covers `[i × BUCKET_MS, (i + 1) × BUCKET_MS)`.
#[derive(Debug, Clone, PartialEq)]
pub struct History {
    /// The channel's first reading (nothing is known before it).
    first_ms: i64,
    /// The newest bucket written.
    newest: i64,
    /// Slot `i % BUCKETS` holds bucket `i`, for the `BUCKETS` buckets up to `newest`.
    sums: [i64; BUCKETS],
}

impl History {
    /// A history starting with a reading at `at_ms`.
    pub fn new(at_ms: i64) -> History {
        History {
            first_ms: at_ms,
            newest: at_ms.div_euclid(BUCKET_MS),
            sums: [0; BUCKETS],
        }
    }

    /// A reading's delta at `at_ms`. A reading older than the buckets kept is left out.
    pub fn add(&mut self, at_ms: i64, delta: i64) {
        let i = at_ms.div_euclid(BUCKET_MS);
        self.advance(i);
        if i + BUCKETS as i64 <= self.newest {
            return;
        }
        let slot = &mut self.sums[i.rem_euclid(BUCKETS as i64) as usize];
        *slot = slot.saturating_add(delta);
    }

    /// Empties the buckets between the newest and `i`, which becomes the newest.
    fn advance(&mut self, i: i64) {
        if i <= self.newest {
            return;
        }
        let steps = (i - self.newest).min(BUCKETS as i64);
        for k in 1..=steps {
            self.sums[(self.newest + k).rem_euclid(BUCKETS as i64) as usize] = 0;
        }
        self.newest = i;
    }

    /// Pulses a second of the `BUCKETS` buckets up to the one holding `now_ms`, oldest first;
    /// `None` for a bucket before the first reading. A bucket's rate is its deltas over the
    /// part of it that was watched (the first and the current bucket are partly).
    pub fn rates(&self, now_ms: i64) -> Vec<Option<f64>> {
        let now_i = now_ms.div_euclid(BUCKET_MS).max(self.newest);
        (now_i + 1 - BUCKETS as i64..=now_i)
            .map(|i| {
                let start = (i * BUCKET_MS).max(self.first_ms);
                let end = ((i + 1) * BUCKET_MS).min(now_ms.max(self.first_ms));
                if (i + 1) * BUCKET_MS <= self.first_ms {
                    return None;
                }
                let sum = if i > self.newest || i + (BUCKETS as i64) <= self.newest {
                    0
                } else {
                    self.sums[i.rem_euclid(BUCKETS as i64) as usize]
                };
                // At least a second: a reading just after a bucket began is not a spike.
                let secs = ((end - start) as f64 / 1000.0).max(1.0);
                Some(sum as f64 / secs)
            })
            .collect()
    }

    /// The end of the bucket holding `now_ms`.
    pub fn end_ms(now_ms: i64) -> i64 {
        (now_ms.div_euclid(BUCKET_MS) + 1) * BUCKET_MS
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T0: i64 = 1_700_000_000_000 / BUCKET_MS * BUCKET_MS;

    #[test]
    fn a_steady_rate_reads_back_as_that_rate_in_every_full_bucket() {
        let mut h = History::new(T0);
        // 10 pulses a second, a reading a second, for 20 minutes.
        for s in 1..=1200 {
            h.add(T0 + s * 1000, 10);
        }
        let rates = h.rates(T0 + 1200 * 1000);
        assert_eq!(rates.len(), BUCKETS);
        for r in &rates[..BUCKETS - 1] {
            assert!((r.unwrap() - 10.0).abs() < 1e-9, "{rates:?}");
        }
    }

    #[test]
    fn buckets_before_the_first_reading_are_unknown_and_quiet_ones_are_zero() {
        let mut h = History::new(T0 + 5 * BUCKET_MS);
        h.add(T0 + 5 * BUCKET_MS + 1000, 30);
        let rates = h.rates(T0 + 9 * BUCKET_MS + 10);
        assert_eq!(rates.iter().filter(|r| r.is_none()).count(), BUCKETS - 5);
        let known: Vec<f64> = rates.iter().flatten().copied().collect();
        assert_eq!(known.len(), 5);
        assert!(known[0] > 0.0);
        assert!(known[1..].iter().all(|r| *r == 0.0), "{known:?}");
    }

    #[test]
    fn memory_stays_the_same_after_hours_and_old_buckets_are_forgotten() {
        let mut h = History::new(T0);
        h.add(T0 + 1000, 1_000_000);
        for s in 0..(4 * 3600) {
            h.add(T0 + 3_600_000 + s * 1000, 1);
        }
        let rates = h.rates(T0 + 3_600_000 + 4 * 3_600_000);
        assert!(rates.iter().all(|r| r.unwrap() <= 1.0), "{rates:?}");
        // A late reading from before the kept window changes nothing.
        let before = h.clone();
        h.add(T0, 99);
        assert_eq!(h, before);
    }

    #[test]
    fn a_long_silence_empties_the_buckets_it_skips() {
        let mut h = History::new(T0);
        for s in 1..=60 {
            h.add(T0 + s * 1000, 5);
        }
        // 40 minutes later: everything kept is after the silence.
        h.add(T0 + 40 * 60_000, 7);
        let rates = h.rates(T0 + 40 * 60_000 + 500);
        let sum: f64 = rates.iter().flatten().sum();
        assert!(sum > 0.0 && sum <= 7.0, "{rates:?}");
    }
}
