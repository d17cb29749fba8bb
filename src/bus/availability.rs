//! Device availability: online at the first good answer, offline after `offline_after`
//! consecutive failures, then probed with backoff. [`Availability`] is the state machine (no
//! I/O: events in, [`Transition`]s out); the functions below it are the bus task's shell, which
//! logs each transition once and publishes the status changes.

use std::time::Duration;

use tokio::sync::mpsc::UnboundedSender;
use tokio::time::Instant;

use super::device::{DeviceRt, PollError};
use super::driver::DeviceState;
use super::schedule::Backoff;
use crate::reading::Output;

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
    log: LogBudget,
}

/// How often a device that stays online may write an error line: a noisy line answers garbled
/// or not at all several times a minute, and each would otherwise be a journal line (and its
/// recovery another). State changes (offline, back online) are always logged.
pub const ERROR_LOG_EVERY: Duration = Duration::from_secs(60);

/// The log budget of one device: one error line per [`ERROR_LOG_EVERY`], the rest counted.
#[derive(Debug, Clone, Default)]
struct LogBudget {
    next: Option<Instant>,
    suppressed: u32,
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
            log: LogBudget::default(),
        }
    }

    /// Whether an error line may be written at `now`: `Some(n)` with the number of errors not
    /// logged since the last line, `None` to count this one silently.
    pub fn may_log_error(&mut self, now: Instant) -> Option<u32> {
        let budget = &mut self.log;
        if budget.next.is_some_and(|next| now < next) {
            budget.suppressed = budget.suppressed.saturating_add(1);
            budget.logged = false;
            return None;
        }
        budget.next = Some(now + ERROR_LOG_EVERY);
        budget.logged = true;
        Some(std::mem::take(&mut budget.suppressed))
    }

    /// Whether a recovery is worth a line: only after an error that was logged.
    pub fn may_log_recovery(&mut self) -> bool {
        std::mem::take(&mut self.log.logged)
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

/// The device answered a whole poll.
pub(super) fn answered<P>(d: &mut DeviceRt<P>, bus: &str, out: &UnboundedSender<Output>) {
    for t in d.availability.answered() {
        match t {
            Transition::Recovered => {
                if d.availability.may_log_recovery() {
                    tracing::info!(bus, device = %d.name, "device answering again");
                }
            }
            Transition::Online { back } => {
                if back {
                    tracing::info!(bus, device = %d.name, "device back online");
                }
                let _ = out.send(Output::DeviceStatus {
                    device: d.name.clone(),
                    online: true,
                });
            }
            Transition::Error(_) | Transition::Offline { .. } => {}
        }
    }
}

/// A poll failed. Returns how long to wait before probing the device again when it is (now)
/// offline; `None` to keep its schedule.
pub(super) fn failed<P: DeviceState>(
    d: &mut DeviceRt<P>,
    e: &PollError<P::Error>,
    line_fault: bool,
    bus: &str,
    out: &UnboundedSender<Output>,
) -> Option<Duration> {
    let verdict = d
        .availability
        .failed(e.to_string(), e.device_answered(), line_fault);
    for t in verdict.transitions {
        match t {
            Transition::Error(message) => {
                match d.availability.may_log_error(Instant::now()) {
                    Some(0) => {
                        tracing::warn!(bus, device = %d.name, unit = d.config.unit, "{message}")
                    }
                    Some(more) => tracing::warn!(
                        bus, device = %d.name, unit = d.config.unit,
                        "{message} ({more} more errors since the last line, not logged one by one)"
                    ),
                    None => {}
                }
                d.proto.poll_failed(e);
            }
            Transition::Offline { failures } => {
                tracing::warn!(bus, device = %d.name, failures, "device offline");
                d.mark_gap();
                d.proto.went_offline();
                let _ = out.send(Output::DeviceStatus {
                    device: d.name.clone(),
                    online: false,
                });
            }
            Transition::Recovered | Transition::Online { .. } => {}
        }
    }
    verdict.wait
}

/// The module is not the configured model: out of service with status `wrong_model` (logged and
/// published once per change); its counters' next deltas cover the time out of service.
pub(super) fn wrong_model<P>(
    d: &mut DeviceRt<P>,
    why: String,
    bus: &str,
    out: &UnboundedSender<Output>,
) {
    if d.wrong_model.as_deref() == Some(why.as_str()) {
        return;
    }
    tracing::error!(bus, device = %d.name, unit = d.config.unit, "module taken out of service: {why}");
    d.wrong_model = Some(why);
    d.metrics.wrong_model(true);
    d.availability.out_of_service();
    d.mark_gap();
    let _ = out.send(Output::DeviceProblem {
        device: d.name.clone(),
        status: "wrong_model",
    });
}

/// A problem of the device's own began or ended (Modbus: a quadrature pair's mode words
/// disagree): its status while it lasts, `online` again after.
pub(super) fn status_change<P: DeviceState>(d: &mut DeviceRt<P>, out: &UnboundedSender<Output>) {
    let Some(now) = d.proto.status_change() else {
        return;
    };
    let status = match now {
        Some(status) => Output::DeviceProblem {
            device: d.name.clone(),
            status,
        },
        None => Output::DeviceStatus {
            device: d.name.clone(),
            online: true,
        },
    };
    let _ = out.send(status);
}

#[cfg(test)]
#[path = "availability_tests.rs"]
mod tests;
