//! Device availability: online at the first good answer, offline after `offline_after`
//! consecutive failures, then probed with backoff. [`Availability`] is the state machine (no
//! I/O: events in, [`Transition`]s out); `status.rs` is the bus task's shell around it, which
//! logs each transition once and publishes the status changes.

use std::time::Duration;

use tokio::time::Instant;

use super::schedule::Backoff;
use crate::log_budget::LogBudget;

/// What changed, as a value: the shell logs it and publishes the status ones.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transition {
    /// An error other than the last one (each logged once per change, not once per poll).
    Error(String),
    /// Answering again after an error while online.
    Recovered,
    /// Online: the first good answer, or `back` after being offline.
    Online { back: bool },
    /// Offline after `failures` consecutive failures.
    Offline { failures: u32 },
}

/// The availability of one device.
#[derive(Debug, Clone)]
pub struct Availability {
    online: Option<bool>,
    failures: u32,
    last_error: Option<String>,
    backoff: Backoff,
    offline_after: u32,
    /// Something came back since the device was last offline (an answer, garbled or not): it is
    /// on the line and answers in time.
    heard: bool,
    /// One error line a minute while the device stays online, the rest counted: a noisy line
    /// answers garbled or not at all several times a minute, and each would otherwise be a
    /// journal line (and its recovery another). State changes (offline, back online) are
    /// always logged.
    log: LogBudget,
    /// The last error was logged, so its recovery is worth a line too.
    logged: bool,
}

/// What a failed poll means: its transitions and, when the device is offline, how long to wait
/// before probing it again (`None`: keep its schedule).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verdict {
    pub transitions: Vec<Transition>,
    pub wait: Option<Duration>,
}

impl Availability {
    /// Not yet seen; offline after `offline_after` failures; probes back off from `min` to `max`.
    pub fn new(offline_after: u32, min: Duration, max: Duration) -> Availability {
        Availability {
            online: None,
            failures: 0,
            last_error: None,
            backoff: Backoff::new(min, max),
            offline_after: offline_after.max(1),
            heard: false,
            log: LogBudget::new(1),
            logged: false,
        }
    }

    /// Whether an error line may be written at `now`: `Some(n)` with the number of errors not
    /// logged since the last line, `None` to count this one silently.
    pub fn may_log_error(&mut self, now: Instant) -> Option<u32> {
        let (allowed, suppressed) = self.log.allow(now);
        self.logged = allowed;
        allowed.then(|| u32::try_from(suppressed.unwrap_or(0)).unwrap_or(u32::MAX))
    }

    /// Whether a recovery is worth a line: only after an error that was logged.
    pub fn may_log_recovery(&mut self) -> bool {
        std::mem::take(&mut self.logged)
    }

    /// `Some(true)` online, `Some(false)` offline, `None` not yet seen (or out of service).
    pub fn online(&self) -> Option<bool> {
        self.online
    }

    /// Whether a read lost to noise is worth asking again at once. `answered`: bytes came back
    /// (a garbled frame). Yes when the device is online, answered now, or has answered since it
    /// was last offline (garbled or not): it is on the line and answers in time, and on a noisy
    /// line a device must get several whole requests through in one poll to come online, which
    /// without retries it may never do. No for a device that has only been silent: it may be
    /// dead or answer too late, and a retry would cost the others a timeout (and could take a
    /// late answer to the first request for the retry's).
    pub fn worth_retrying(&self, answered: bool) -> bool {
        answered || self.heard || self.online == Some(true)
    }

    /// The last error, until the device answers again.
    pub fn last_error(&self) -> Option<&str> {
        self.last_error.as_deref()
    }

    /// The device answered a whole poll.
    pub fn answered(&mut self) -> Vec<Transition> {
        let mut out = Vec::new();
        self.failures = 0;
        self.heard = true;
        self.backoff.reset();
        if self.last_error.take().is_some() && self.online == Some(true) {
            out.push(Transition::Recovered);
        }
        if self.online != Some(true) {
            out.push(Transition::Online {
                back: self.online == Some(false),
            });
            self.online = Some(true);
        }
        out
    }

    /// A poll failed with `message`. `answered`: the device answered (an exception, a garbled
    /// answer on a noisy line), so it is there and this is no step towards offline.
    /// `line_fault`: the line itself is down (adapter gone): offline devices are probed every
    /// `min` so the bus is back within seconds of the line.
    pub fn failed(&mut self, message: String, answered: bool, line_fault: bool) -> Verdict {
        let mut transitions = Vec::new();
        if self.last_error.as_deref() != Some(message.as_str()) {
            self.last_error = Some(message.clone());
            transitions.push(Transition::Error(message));
        }
        if answered {
            self.failures = 0;
            self.heard = true;
            return Verdict {
                transitions,
                wait: None,
            };
        }
        self.failures += 1;
        if self.failures < self.offline_after {
            return Verdict {
                transitions,
                wait: None,
            };
        }
        if self.online != Some(false) {
            self.online = Some(false);
            self.heard = false;
            transitions.push(Transition::Offline {
                failures: self.failures,
            });
        }
        let wait = if line_fault {
            self.backoff.min
        } else {
            self.backoff.next_wait()
        };
        Verdict {
            transitions,
            wait: Some(wait),
        }
    }

    /// Taken out of service (the wrong model answers): neither online nor offline.
    pub fn out_of_service(&mut self) {
        self.online = None;
        self.failures = 0;
    }

    /// The line is answering again: an offline device is probed at once (`true`).
    pub fn line_back(&mut self) -> bool {
        let offline = self.online == Some(false);
        if offline {
            self.backoff.reset();
        }
        offline
    }
}

#[cfg(test)]
#[path = "availability_tests.rs"]
mod tests;
