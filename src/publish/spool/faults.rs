//! What went wrong with the spool's files, counted and said within a log budget per kind (a
//! full disk fails every write until it is freed; the journal hears of it a few times a
//! minute, with the count of what it did not hear).

use std::path::Path;

use tokio::time::Instant;

use crate::log_budget::LogBudget;

/// Lines a minute for each kind of spool fault.
const PER_MINUTE: u32 = 3;

/// Counters and log budgets of one spool's faults.
#[derive(Debug)]
pub struct Faults {
    write_log: LogBudget,
    read_log: LogBudget,
    other_log: LogBudget,
    /// Writes (or syncs) of spool files that failed, since start.
    pub write_failures: u64,
    /// Lines of spool files that were not a stored message, skipped, since start.
    pub unreadable_lines: u64,
}

/// Whether a line may be logged now; says first how many the last minute did not.
fn allow(budget: &mut LogBudget, kind: &str) -> bool {
    let (log, suppressed) = budget.allow(Instant::now());
    if let Some(n) = suppressed {
        tracing::warn!(
            suppressed = n,
            "{n} more spool {kind} in the last minute were not logged"
        );
    }
    log
}

impl Faults {
    pub fn new() -> Faults {
        Faults {
            write_log: LogBudget::new(PER_MINUTE),
            read_log: LogBudget::new(PER_MINUTE),
            other_log: LogBudget::new(PER_MINUTE),
            write_failures: 0,
            unreadable_lines: 0,
        }
    }

    /// A write (or sync) of `path` failed; `waiting` messages are in memory only now.
    pub fn write_failed(&mut self, path: &Path, error: &std::io::Error, waiting: u64) {
        self.write_failures += 1;
        if allow(&mut self.write_log, "write failures") {
            tracing::error!(
                file = %path.display(),
                waiting,
                "spool: cannot write {}: {error}; {waiting} unsent messages are held in memory only (bounded: beyond it the oldest of them are dropped and counted) and written at the next flush. They are not on disk: a stop or crash now loses them (the readings after them still carry the totals)",
                path.display()
            );
        }
    }

    /// A sync of `path` failed: its messages may not be on disk.
    pub fn sync_failed(&mut self, path: &Path, error: &std::io::Error) {
        self.write_failures += 1;
        if allow(&mut self.write_log, "write failures") {
            tracing::error!(
                file = %path.display(),
                "spool: cannot sync {}: {error}; its messages may not be on disk, so state saves wait for the broker to acknowledge them",
                path.display()
            );
        }
    }

    /// A segment at `path` cannot be read when its turn comes: its `lost` messages are not
    /// sent (counted as dropped); the file is left as it is.
    pub fn read_failed(&mut self, path: &Path, error: &std::io::Error, lost: u64) {
        if allow(&mut self.other_log, "file errors") {
            tracing::error!(
                file = %path.display(),
                lost,
                "spool: cannot read {}: {error}; its {lost} messages are not sent (counted as dropped), the file is left as it is",
                path.display()
            );
        }
    }

    /// A line of `path` at `offset` is not a stored message: skipped.
    pub fn unreadable(&mut self, path: &Path, offset: u64, why: &str) {
        self.unreadable_lines += 1;
        if allow(&mut self.read_log, "unreadable lines") {
            tracing::error!(
                file = %path.display(),
                offset,
                "spool: the line at byte {offset} of {} is not a stored message ({why}): skipped, the messages after it are sent; the file is kept as <name>.unreadable once they are acknowledged",
                path.display()
            );
        }
    }

    /// A segment's last line was cut short (a crash while writing): skipped.
    pub fn torn(&mut self, path: &Path, offset: u64) {
        if allow(&mut self.read_log, "unreadable lines") {
            tracing::warn!(
                file = %path.display(),
                offset,
                "spool: the last line of {} (at byte {offset}) was cut short, a crash while writing: skipped",
                path.display()
            );
        }
    }

    /// Something that puts no message at stake failed (a removal, a rename, a read).
    pub fn other(&mut self, path: &Path, what: &str, error: &std::io::Error) {
        if allow(&mut self.other_log, "file errors") {
            tracing::error!(file = %path.display(), "spool: {what} {}: {error}", path.display());
        }
    }
}
