//! How long one device's reads may be: shorter after answers lost to noise, longer again when
//! the line is clean. Pure: answers in, the longest read allowed out.
//!
//! On a line that drops or garbles a byte in a few hundred, a long answer (a 64-register block
//! is 133 characters) almost never arrives whole, while a short one mostly does; and a lost
//! answer costs a whole timeout, whatever its length. So a lost answer halves the limit below
//! the read that was lost (down to 1: one value a read, as the planner never splits a value),
//! and a run of [`GROW_AFTER`] answers in a row doubles it again (up to [`MAX_READ`]). Halving at
//! once and growing slowly keeps a noisy line near the length that gets through; on a clean line
//! the limit is back at full length within a few polls.

use crate::plan::MAX_READ;

/// Answers in a row, with no loss between them, that double the limit.
pub const GROW_AFTER: u32 = 8;

/// The longest read a device's planner may use now, and what it learnt of the line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sizing {
    limit: u16,
    /// Answers in a row since the last loss or change of the limit.
    clean: u32,
}

impl Default for Sizing {
    fn default() -> Sizing {
        Sizing {
            limit: MAX_READ,
            clean: 0,
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
    pub fn answered(&mut self, _len: u16) -> Option<Change> {
        self.clean += 1;
        if self.clean < GROW_AFTER || self.is_full() {
            return None;
        }
        self.clean = 0;
        self.limit = self.limit.saturating_mul(2).min(MAX_READ);
        Some(Change::Grown(self.limit))
    }

    /// A read of `len` registers was lost to the line: no answer, a garbled one, or one that
    /// did not fit the request.
    pub fn lost(&mut self, len: u16) -> Option<Change> {
        self.clean = 0;
        let shorter = (len / 2).max(1);
        if shorter >= self.limit {
            return None;
        }
        self.limit = shorter;
        Some(Change::Shortened(shorter))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn after(events: &str, len: u16) -> Sizing {
        let mut s = Sizing::default();
        for e in events.chars() {
            match e {
                'a' => s.answered(len),
                'l' => s.lost(len.min(s.limit())),
                _ => unreachable!(),
            };
        }
        s
    }

    #[test]
    fn a_new_device_reads_at_full_length() {
        assert_eq!(Sizing::default().limit(), MAX_READ);
        assert!(Sizing::default().is_full());
    }

    #[test]
    fn a_lost_answer_halves_the_limit_below_the_read_that_was_lost() {
        let mut s = Sizing::default();
        assert_eq!(s.lost(64), Some(Change::Shortened(32)));
        assert_eq!(s.limit(), 32);
        assert_eq!(s.lost(32), Some(Change::Shortened(16)));
    }

    #[test]
    fn a_lost_short_read_does_not_lengthen_the_limit() {
        let mut s = Sizing::default();
        s.lost(64);
        assert_eq!(
            s.lost(64),
            None,
            "a read longer than the limit was planned before"
        );
        assert_eq!(s.lost(2), Some(Change::Shortened(1)));
        assert_eq!(s.lost(2), None);
        assert_eq!(s.limit(), 1);
    }

    #[test]
    fn losses_go_down_to_one_register_and_no_further() {
        let s = after("llllllllllll", 125);
        assert_eq!(s.limit(), 1);
    }

    #[test]
    fn eight_answers_in_a_row_double_the_limit() {
        let mut s = after("llllll", 64);
        assert_eq!(s.limit(), 1);
        for _ in 1..GROW_AFTER {
            assert_eq!(s.answered(1), None);
        }
        assert_eq!(s.answered(1), Some(Change::Grown(2)));
        assert_eq!(s.limit(), 2);
    }

    #[test]
    fn a_loss_in_the_run_starts_it_again() {
        let mut s = after("llllll", 64);
        for _ in 1..GROW_AFTER {
            s.answered(1);
        }
        s.lost(1);
        for _ in 1..GROW_AFTER {
            assert_eq!(s.answered(1), None);
        }
        assert_eq!(s.limit(), 1);
    }

    #[test]
    fn a_clean_line_grows_the_limit_back_to_full_length() {
        let mut s = after("llllllll", 125);
        let mut answers = 0;
        while !s.is_full() {
            s.answered(s.limit());
            answers += 1;
        }
        assert_eq!(s.limit(), MAX_READ);
        // 1 → 2 → … → 64 → 125: seven doublings.
        assert_eq!(answers, 7 * GROW_AFTER);
        assert_eq!(s.answered(125), None, "full length is as long as it gets");
    }

    #[test]
    fn a_clean_line_never_shortens_reads() {
        assert!(after(&"a".repeat(100), 64).is_full());
    }
}
