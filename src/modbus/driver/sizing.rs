//! How long one device's reads may be: shorter while answers are lost to noise, longer again
//! when the line is clean. Pure: read outcomes in, the longest read allowed out.
//!
//! On a line that drops or garbles a byte in a few dozen, a long answer (a 64-register block is
//! 133 characters) almost never arrives whole, while a short one mostly does; but a lost read
//! costs a whole answer timeout, whatever its length, and every read its frames and silences.
//! So the device's recent reads give an estimate of the share of characters the line breaks,
//! and the limit is the length that brings the most registers through per character of line
//! time at that rate: full length on a clean line, a few registers at a few percent, one value a
//! read beyond that (the planner never splits a value). Lengths are powers of two up to
//! [`MAX_READ`], so a plan changes only when the line does.

use crate::modbus::config::plan::{MAX_READ, read_chars};

/// Reads the estimate remembers (their weight halves about every 11 reads).
const MEMORY: f64 = 16.0;

/// The lengths the limit takes, shortest first.
const LENGTHS: [u16; 8] = [1, 2, 4, 8, 16, 32, 64, MAX_READ];

/// What reads cost on this device's line, in characters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prices {
    /// A read beyond its registers: frames, silences, turnaround.
    pub overhead: f64,
    /// A lost read on top of that: the answer timeout waited out.
    pub loss: f64,
}

/// The longest read a device's planner may use now, and what it learnt of the line.
#[derive(Debug, Clone, PartialEq)]
pub struct Sizing {
    /// Recent reads, their characters and their losses, each weighted by how recent it is.
    reads: f64,
    chars: f64,
    losses: f64,
    limit: u16,
}

impl Default for Sizing {
    /// A line assumed clean: as if some clean reads had been seen, so the first loss on a
    /// healthy line does not shorten reads on its own.
    fn default() -> Sizing {
        let reads = MEMORY / 4.0;
        Sizing {
            reads,
            chars: reads * read_chars(16),
            losses: 0.0,
            limit: MAX_READ,
        }
    }
}

/// A change of the limit, for the log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    /// Reads are shortened to this many registers.
    Shortened(u16),
    /// Reads grow to this many registers.
    Grown(u16),
}

impl Sizing {
    /// The longest read allowed, in registers ([`MAX_READ`] when the line is clean).
    pub fn limit(&self) -> u16 {
        self.limit
    }

    /// Whether reads are at their full length.
    pub fn is_full(&self) -> bool {
        self.limit == MAX_READ
    }

    /// A read of `len` registers was answered whole.
    pub fn answered(&mut self, len: u16, prices: &Prices) -> Option<Change> {
        self.record(len, false, prices)
    }

    /// A read of `len` registers was lost to the line: no answer, a garbled one, or one that
    /// did not fit the request.
    pub fn lost(&mut self, len: u16, prices: &Prices) -> Option<Change> {
        self.record(len, true, prices)
    }

    /// The share of characters the line breaks, as the recent reads tell: a read of `n`
    /// characters comes through with probability `(1 - e)^n`.
    pub fn char_error(&self) -> f64 {
        let lost = (self.losses / self.reads).min(0.9999);
        -(1.0 - lost).ln() / (self.chars / self.reads)
    }

    fn record(&mut self, len: u16, lost: bool, prices: &Prices) -> Option<Change> {
        let keep = 1.0 - 1.0 / MEMORY;
        self.reads = self.reads * keep + 1.0;
        self.chars = self.chars * keep + read_chars(len);
        self.losses = self.losses * keep + f64::from(u8::from(lost));
        let best = best_length(self.char_error(), prices);
        let change = match best.cmp(&self.limit) {
            std::cmp::Ordering::Less => Change::Shortened(best),
            std::cmp::Ordering::Greater => Change::Grown(best),
            std::cmp::Ordering::Equal => return None,
        };
        self.limit = best;
        Some(change)
    }
}

/// The read length that brings the most registers through per character of line time when
/// the line breaks a share `error` of characters.
pub fn best_length(error: f64, prices: &Prices) -> u16 {
    let through = |len: u16| {
        let whole = (1.0 - error.clamp(0.0, 1.0)).powf(read_chars(len));
        let cost = prices.overhead + 2.0 * f64::from(len) + (1.0 - whole) * prices.loss;
        f64::from(len) * whole / cost
    };
    LENGTHS
        .into_iter()
        .max_by(|a, b| through(*a).total_cmp(&through(*b)))
        .unwrap_or(MAX_READ)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 19200 baud, 3 ms turnaround, a 100 ms answer timeout.
    const PRICES: Prices = Prices {
        overhead: 26.0,
        loss: 192.0,
    };

    /// A line that breaks a share of the characters: `n` reads of up to `len` registers (at
    /// most the limit), each lost as a fixed sequence of draws says.
    fn line(s: &mut Sizing, error: f64, n: usize, len: u16) -> Vec<Change> {
        let mut draw = 0x2545_F491_4F6C_DD1Du64;
        let mut changes = Vec::new();
        for _ in 0..n {
            draw ^= draw << 13;
            draw ^= draw >> 7;
            draw ^= draw << 17;
            let u = (draw >> 11) as f64 / (1u64 << 53) as f64;
            let len = len.min(s.limit());
            let whole = (1.0 - error).powf(read_chars(len));
            let change = if u < whole {
                s.answered(len, &PRICES)
            } else {
                s.lost(len, &PRICES)
            };
            changes.extend(change);
        }
        changes
    }

    #[test]
    fn a_new_device_reads_at_full_length() {
        assert_eq!(Sizing::default().limit(), MAX_READ);
        assert!(Sizing::default().is_full());
    }

    #[test]
    fn a_clean_line_reads_at_full_length_and_a_dirty_one_a_value_at_a_time() {
        assert_eq!(best_length(0.0, &PRICES), MAX_READ);
        assert_eq!(best_length(0.0005, &PRICES), MAX_READ);
        assert_eq!(best_length(0.3, &PRICES), 1);
    }

    #[test]
    fn a_few_percent_of_broken_characters_make_reads_of_a_few_registers() {
        // 4% of the characters: a 64-register read comes through 1 time in 300, one of 8
        // registers 1 in 3; with the timeout a lost read costs, 8 bring the most through.
        assert_eq!(best_length(0.04, &PRICES), 8);
        assert_eq!(best_length(0.01, &PRICES), 16);
        // A lost read costs its timeout whatever its length: where the timeout is long, fewer
        // and longer reads lose less time.
        let slow = Prices {
            loss: 1920.0,
            ..PRICES
        };
        assert!(best_length(0.04, &slow) >= 8);
    }

    #[test]
    fn one_lost_answer_on_a_clean_line_does_not_shorten_reads() {
        let mut s = Sizing::default();
        line(&mut s, 0.0, 100, 64);
        assert_eq!(s.lost(64, &PRICES), None);
        assert!(s.is_full());
    }

    #[test]
    fn a_noisy_line_shortens_reads_within_a_few_dozen_reads_and_keeps_them_short() {
        let mut s = Sizing::default();
        let changes = line(&mut s, 0.04, 30, 64);
        assert!(matches!(changes[0], Change::Shortened(_)), "{changes:?}");
        assert!(s.limit() <= 16, "{}", s.limit());
        line(&mut s, 0.04, 300, 64);
        assert!((2..=16).contains(&s.limit()), "{}", s.limit());
        let e = s.char_error();
        assert!(
            (0.02..0.07).contains(&e),
            "the estimate of 4% broken characters: {e}"
        );
    }

    #[test]
    fn a_device_whose_reads_are_all_lost_is_read_a_value_at_a_time() {
        let mut s = Sizing::default();
        line(&mut s, 1.0, 200, 64);
        assert_eq!(s.limit(), 1);
    }

    #[test]
    fn a_clean_line_grows_reads_back_to_full_length() {
        let mut s = Sizing::default();
        line(&mut s, 0.04, 300, 64);
        let mut n = 0;
        while !s.is_full() {
            line(&mut s, 0.0, 1, 64);
            n += 1;
            assert!(n < 200, "still at {} after {n} clean reads", s.limit());
        }
        assert_eq!(
            s.answered(64, &PRICES),
            None,
            "full length is as long as it gets"
        );
    }
}
