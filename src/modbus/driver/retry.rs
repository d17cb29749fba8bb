//! When a read lost to the line is asked again. Pure: each loss in, what to do next out.
//!
//! A device that lost one request or answer to noise is asked again: on a noisy line a
//! corrupted request gets no answer at all, and three of those in a row must not make a healthy
//! device offline. But three silent reads in a row (no byte heard) end the poll: a dead device
//! costs the other devices on the bus three timeouts a poll, no more. A read whose blocks may
//! arrive apart (the count poll: each channel published whole or not at all) asks a block more
//! often before leaving it out, since a block given up wastes the blocks of the same channels
//! that did arrive; and once the device has been heard in it, the read ends only after
//! [`SILENT_HEARD`] silent reads in a row (on a line that loses a request in four, three in a
//! row come every few dozen reads, and would cut most polls short).

/// Times a block is asked again after noise when the read fails as a whole.
pub const NOISE_RETRIES: u32 = 2;

/// Times a block is asked again after noise when the read can leave it out.
pub const PARTIAL_RETRIES: u32 = 7;

/// Silent reads in a row that end a read that can leave blocks out, once the device was heard
/// in it.
pub const SILENT_HEARD: u32 = 6;

/// What a read of several blocks does with a block lost to the line (after its retries).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lost {
    /// The whole read fails: its values belong together (work modes, windows, clear/preset).
    FailsAll,
    /// The block is left out and the others are read: the count poll.
    LeftOut,
}

/// What to do after a block was lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Ask for it again.
    Again,
    /// Leave it out and go on with the next block.
    LeaveOut,
    /// End the read here (failed, or with what arrived, as [`Lost`] says).
    Stop,
}

/// The retries of one read of several blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tries {
    lost: Lost,
    /// Retries of the block being read.
    retries: u32,
    /// Reads in a row that heard nothing at all.
    silent: u32,
    /// The device said something in this read (an answer, a refusal, a garbled answer).
    heard: bool,
}

impl Tries {
    pub fn new(lost: Lost) -> Tries {
        Tries {
            lost,
            retries: 0,
            silent: 0,
            heard: false,
        }
    }

    /// The device answered (data or a refusal): the next block starts afresh.
    pub fn answered(&mut self) {
        self.retries = 0;
        self.silent = 0;
        self.heard = true;
    }

    /// A block was lost; `heard`: some of an answer came (garbled); `worth`: the device's
    /// availability finds another try worth it (an offline device that stays silent is not
    /// asked twice).
    pub fn lost(&mut self, heard: bool, worth: bool) -> Next {
        self.silent = if heard { 0 } else { self.silent + 1 };
        self.heard |= heard;
        let silence = match self.lost {
            Lost::LeftOut if self.heard => SILENT_HEARD,
            _ => NOISE_RETRIES + 1,
        };
        if self.silent >= silence {
            return Next::Stop;
        }
        let budget = match self.lost {
            Lost::FailsAll => NOISE_RETRIES,
            Lost::LeftOut => PARTIAL_RETRIES,
        };
        if self.retries < budget && worth {
            self.retries += 1;
            return Next::Again;
        }
        self.retries = 0;
        if !heard && !worth {
            // A probe of a device that is away: one silent read is its answer.
            return Next::Stop;
        }
        match self.lost {
            Lost::FailsAll => Next::Stop,
            Lost::LeftOut => Next::LeaveOut,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_read_that_fails_as_a_whole_asks_a_block_three_times() {
        let mut t = Tries::new(Lost::FailsAll);
        assert_eq!(t.lost(true, true), Next::Again);
        assert_eq!(t.lost(true, true), Next::Again);
        assert_eq!(t.lost(true, true), Next::Stop);
    }

    #[test]
    fn the_count_poll_asks_a_garbled_block_eight_times_then_leaves_it_out() {
        let mut t = Tries::new(Lost::LeftOut);
        for _ in 0..PARTIAL_RETRIES {
            assert_eq!(t.lost(true, true), Next::Again);
        }
        assert_eq!(t.lost(true, true), Next::LeaveOut);
        assert_eq!(
            t.lost(true, true),
            Next::Again,
            "the next block has its own tries"
        );
    }

    #[test]
    fn three_silent_reads_in_a_row_end_the_poll() {
        let mut t = Tries::new(Lost::LeftOut);
        assert_eq!(t.lost(false, true), Next::Again);
        assert_eq!(t.lost(false, true), Next::Again);
        assert_eq!(t.lost(false, true), Next::Stop);
    }

    #[test]
    fn once_the_device_was_heard_the_count_poll_takes_six_silent_reads_to_end() {
        let mut t = Tries::new(Lost::LeftOut);
        t.answered();
        for _ in 1..SILENT_HEARD {
            assert_ne!(t.lost(false, true), Next::Stop);
        }
        assert_eq!(t.lost(false, true), Next::Stop);
        // A read that fails as a whole ends at three, heard or not.
        let mut t = Tries::new(Lost::FailsAll);
        t.answered();
        t.lost(false, true);
        t.lost(false, true);
        assert_eq!(t.lost(false, true), Next::Stop);
    }

    #[test]
    fn a_garbled_answer_between_silent_reads_shows_the_device_is_there() {
        let mut t = Tries::new(Lost::LeftOut);
        t.lost(false, true);
        t.lost(false, true);
        t.lost(true, true);
        assert_eq!(t.lost(false, true), Next::Again);
        t.answered();
        assert_eq!(t.lost(false, true), Next::Again);
    }

    #[test]
    fn a_device_not_worth_a_retry_is_not_asked_again() {
        assert_eq!(Tries::new(Lost::FailsAll).lost(false, false), Next::Stop);
        assert_eq!(Tries::new(Lost::LeftOut).lost(false, false), Next::Stop);
    }
}
