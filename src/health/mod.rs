//! Liveness and truth of the gateway's loops, for the systemd watchdog and status line and for
//! `/healthz`.
//!
//! Every bus loop and every output's task beat a heart at least once a second while they make
//! progress; the watchdog is fed only while every heart is fresh, so a stuck bus gets the
//! service restarted. The status line counts buses up, devices online and the outputs'
//! connections, and names every problem; [`Health::verdict`] says whether all is well: every
//! bus polling, and no output held or disconnected for longer than [`OUTPUT_GRACE`].
//!
//! What is known is one plain value, [`Vitals`] (`vitals.rs`): events in with their time,
//! questions with theirs. This file only shares it: a heart sends its event into a tokio
//! `watch` channel (`send_modify`: one change at a time, in the order they happen), readers
//! borrow the value and ask it with the time now. No state lives here.

mod vitals;

use std::time::{Duration, Instant};

use tokio::sync::watch;

pub use vitals::{Event, Loop, LoopView, OUTPUT_GRACE, Vitals};

/// Shared health of a running gateway.
#[derive(Debug)]
pub struct Health {
    vitals: watch::Sender<Vitals>,
}

impl Default for Health {
    fn default() -> Health {
        Health {
            vitals: watch::Sender::new(Vitals::new(Instant::now())),
        }
    }
}

/// A handle a loop tells its health with.
#[derive(Debug, Clone)]
pub struct Heart {
    vitals: watch::Sender<Vitals>,
    of: Loop,
}

impl Heart {
    fn tell(&self, event: Event) {
        let now = Instant::now();
        self.vitals.send_modify(|v| v.handle(event, now));
    }

    /// The loop is alive and making progress.
    pub fn beat(&self) {
        self.tell(Event::Beat(self.of.clone()));
    }

    /// The line (or broker connection) is up or down; either way the loop has made its first
    /// attempt.
    pub fn set_up(&self, up: bool) {
        self.tell(Event::Up(self.of.clone(), up));
    }

    /// The loop refuses to work, and why (for `systemctl status`).
    pub fn set_problem(&self, problem: Option<String>) {
        self.tell(Event::Problem(self.of.clone(), problem));
    }

    /// A warning for the status line that is no fault (yet); `None` to clear it.
    pub fn set_note(&self, note: Option<String>) {
        self.tell(Event::Note(self.of.clone(), note));
    }

    /// The output holds what it would publish, and why; `None` when it no longer does.
    pub fn set_held(&self, why: Option<String>) {
        self.tell(Event::Held(self.of.clone(), why));
    }

    /// The connection failed, and why (kept until the next failure).
    pub fn set_error(&self, why: String) {
        let at = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX));
        self.tell(Event::Failed(self.of.clone(), why, at));
    }

    /// What the output's spool holds.
    pub fn set_spool(&self, messages: u64, bytes: u64) {
        self.tell(Event::Spool(self.of.clone(), messages, bytes));
    }
}

impl Health {
    fn tell(&self, event: Event) {
        let now = Instant::now();
        self.vitals.send_modify(|v| v.handle(event, now));
    }

    /// Registers a loop and returns its heart.
    pub fn heart(&self, of: Loop) -> Heart {
        self.tell(Event::Registered(of.clone()));
        Heart {
            vitals: self.vitals.clone(),
            of,
        }
    }

    /// Forgets a loop that was stopped on purpose (a bus removed by a reload).
    pub fn forget(&self, of: Loop) {
        self.tell(Event::Forgotten(of));
    }

    /// Records a device's availability.
    pub fn device(&self, name: &str, online: bool) {
        self.tell(Event::Device(name.to_string(), online));
    }

    /// Forgets devices not in `keep` (after a reload).
    pub fn retain_devices(&self, keep: &[String]) {
        self.tell(Event::DevicesKept(keep.to_vec()));
    }

    /// The devices online now.
    pub fn online_devices(&self) -> Vec<String> {
        self.vitals.borrow().online_devices()
    }

    /// Whether loop `of` is up now.
    pub fn is_up(&self, of: &Loop) -> bool {
        self.vitals.borrow().is_up(of)
    }

    /// How long the gateway has run.
    pub fn uptime(&self) -> Duration {
        self.vitals.borrow().uptime(Instant::now())
    }

    /// Every loop, by name.
    pub fn loops(&self) -> Vec<LoopView> {
        self.vitals.borrow().loops(Instant::now())
    }

    /// Loops that have not beaten within `limit`.
    pub fn stale(&self, limit: Duration) -> Vec<String> {
        self.vitals.borrow().stale(Instant::now(), limit)
    }

    /// Whether every loop has made its first attempt.
    pub fn all_started(&self) -> bool {
        self.vitals.borrow().all_started()
    }

    /// The status line now (see [`Vitals::status_line`]).
    pub fn status_line(&self) -> String {
        self.vitals.borrow().status_line()
    }

    /// Whether all is well now (see [`Vitals::verdict`]).
    pub fn verdict(&self, stale_after: Duration) -> Result<String, String> {
        self.vitals.borrow().verdict(Instant::now(), stale_after)
    }
}
