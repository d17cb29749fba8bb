//! How often one kind of line may be logged: at most `per_minute` a minute, the rest counted
//! and said once, so a flood (bad commands, a noisy line) does not flood the journal. The one
//! rule for it: commands, devices, the MQTT task and Sparkplug all use it. Pure.

use std::time::Duration;

use tokio::time::Instant;

/// The window a budget counts in.
pub const WINDOW: Duration = Duration::from_secs(60);

/// Logs at most `per_minute` lines a minute of one kind and counts the rest, so a flood of bad
/// commands does not flood the journal.
#[derive(Debug, Clone)]
pub struct LogBudget {
    per_minute: u32,
    window_start: Option<Instant>,
    used: u32,
    suppressed: u64,
}

impl LogBudget {
    pub const fn new(per_minute: u32) -> LogBudget {
        LogBudget {
            per_minute,
            window_start: None,
            used: 0,
            suppressed: 0,
        }
    }

    /// Whether a line may be logged at `now`; when a new minute starts, also how many were
    /// suppressed in the last one (to log once).
    pub fn allow(&mut self, now: Instant) -> (bool, Option<u64>) {
        let mut summary = None;
        let expired = self
            .window_start
            .is_none_or(|s| now.saturating_duration_since(s) >= WINDOW);
        if expired {
            if self.suppressed > 0 {
                summary = Some(self.suppressed);
            }
            self.window_start = Some(now);
            self.used = 0;
            self.suppressed = 0;
        }
        if self.used < self.per_minute {
            self.used += 1;
            (true, summary)
        } else {
            self.suppressed += 1;
            (false, summary)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_log_budget_counts_what_it_suppresses_and_says_so_once() {
        let mut b = LogBudget::new(3);
        let t = Instant::now();
        let logged = (0..100).filter(|_| b.allow(t).0).count();
        assert_eq!(logged, 3);
        assert_eq!(b.allow(t + Duration::from_secs(61)), (true, Some(97)));
    }
}
