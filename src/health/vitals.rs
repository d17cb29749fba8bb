//! The gateway's vitals as a plain value: what each loop last said of itself and which devices
//! are online. Events go in with the time they happened ([`Vitals::handle`]); every question
//! takes the time it is asked, so the tests are sentences on made-up instants and never sleep.
//! Pure: no clock, no locks (the shell in `mod.rs` shares it).

use std::collections::BTreeMap;
use std::fmt;
use std::time::{Duration, Instant};

/// How long an output may be disconnected or held before the gateway is not well (a broker
/// restart, a reconnect with back-off, is not a fault).
pub const OUTPUT_GRACE: Duration = Duration::from_secs(30);

/// A loop whose health is watched: a bus's poll loop or an output's task.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Loop {
    Bus(String),
    Output(String),
}

impl fmt::Display for Loop {
    /// `bus/<name>`, `output/<name>`: how the status line and the page name it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Loop::Bus(n) => write!(f, "bus/{n}"),
            Loop::Output(n) => write!(f, "output/{n}"),
        }
    }
}

/// What a loop or the fan-out says.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A loop starts (again): fresh, not yet up, not yet started.
    Registered(Loop),
    /// A loop stopped on purpose (a bus removed by a reload).
    Forgotten(Loop),
    /// The loop is alive and making progress.
    Beat(Loop),
    /// Its line (or broker connection) is up or down; either way it made its first attempt.
    Up(Loop, bool),
    /// Why the loop refuses to work (shown in the status line); `None` when it works again.
    Problem(Loop, Option<String>),
    /// A warning for the status line that is no fault (yet).
    Note(Loop, Option<String>),
    /// Why an output holds what it would publish.
    Held(Loop, Option<String>),
    /// An output's connection failed, and why, at this Unix time in ms (kept for the page).
    Failed(Loop, String, u64),
    /// What an output's spool holds: messages and bytes.
    Spool(Loop, u64, u64),
    /// A device's availability.
    Device(String, bool),
    /// Devices not in this list are gone (a reload).
    DevicesKept(Vec<String>),
}

/// One loop as it last said.
#[derive(Debug, Clone)]
struct Said {
    beat: Instant,
    up: bool,
    started: bool,
    problem: Option<String>,
    held: Option<String>,
    note: Option<String>,
    /// When it stopped being up and unheld; `None` while it is.
    down_since: Option<Instant>,
    last_error: Option<(String, u64)>,
    spool: (u64, u64),
}

impl Said {
    fn new(now: Instant) -> Said {
        Said {
            beat: now,
            up: false,
            started: false,
            problem: None,
            held: None,
            note: None,
            down_since: Some(now),
            last_error: None,
            spool: (0, 0),
        }
    }

    /// Notes when the loop stopped being up and unheld (kept while it stays so).
    fn mark(&mut self, now: Instant) {
        if self.up && self.held.is_none() {
            self.down_since = None;
        } else if self.down_since.is_none() {
            self.down_since = Some(now);
        }
    }
}

/// One loop as the status page shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoopView {
    /// The loop.
    pub of: Loop,
    pub up: bool,
    pub held: Option<String>,
    pub problem: Option<String>,
    /// The last connection error and when (Unix ms).
    pub last_error: Option<(String, u64)>,
    /// How long it has been down or held, in milliseconds (`None` while up and unheld).
    pub down_for_ms: Option<u64>,
    pub spool_messages: u64,
    pub spool_bytes: u64,
}

/// The vitals of a running gateway.
#[derive(Debug, Clone)]
pub struct Vitals {
    start: Instant,
    loops: BTreeMap<Loop, Said>,
    /// Devices online, by name.
    devices: BTreeMap<String, bool>,
}

fn ms(d: Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

impl Vitals {
    /// A gateway started at `start`, with no loop yet.
    pub fn new(start: Instant) -> Vitals {
        Vitals {
            start,
            loops: BTreeMap::new(),
            devices: BTreeMap::new(),
        }
    }

    /// Takes what happened at `now`.
    pub fn handle(&mut self, event: Event, now: Instant) {
        match event {
            Event::Registered(l) => {
                self.loops.insert(l, Said::new(now));
            }
            Event::Forgotten(l) => {
                self.loops.remove(&l);
            }
            Event::Device(name, online) => {
                self.devices.insert(name, online);
            }
            Event::DevicesKept(keep) => self.devices.retain(|k, _| keep.contains(k)),
            said => self.said(said, now),
        }
    }

    /// What a loop says of itself. A word from a loop that is not registered is dropped (a
    /// late word from a bus a reload removed).
    fn said(&mut self, event: Event, now: Instant) {
        let (Event::Beat(l)
        | Event::Up(l, _)
        | Event::Problem(l, _)
        | Event::Note(l, _)
        | Event::Held(l, _)
        | Event::Failed(l, ..)
        | Event::Spool(l, ..)) = &event
        else {
            return;
        };
        let Some(s) = self.loops.get_mut(l) else {
            return;
        };
        match event {
            Event::Beat(_) => s.beat = now,
            Event::Up(_, up) => {
                (s.up, s.started) = (up, true);
                s.mark(now);
            }
            Event::Problem(_, p) => s.problem = p,
            Event::Note(_, n) => s.note = n,
            Event::Held(_, h) => {
                s.held = h;
                s.mark(now);
            }
            Event::Failed(_, why, at) => s.last_error = Some((why, at)),
            Event::Spool(_, messages, bytes) => s.spool = (messages, bytes),
            Event::Registered(_)
            | Event::Forgotten(_)
            | Event::Device(..)
            | Event::DevicesKept(_) => {}
        }
    }

    /// The devices online.
    pub fn online_devices(&self) -> Vec<String> {
        let online = self.devices.iter().filter(|(_, up)| **up);
        online.map(|(name, _)| name.clone()).collect()
    }

    /// Whether loop `l` is up.
    pub fn is_up(&self, l: &Loop) -> bool {
        self.loops.get(l).is_some_and(|s| s.up)
    }

    /// How long the gateway has run at `now`.
    pub fn uptime(&self, now: Instant) -> Duration {
        now.saturating_duration_since(self.start)
    }

    /// When the gateway started.
    pub fn start(&self) -> Instant {
        self.start
    }

    /// Every loop, by name, as at `now`.
    pub fn loops(&self, now: Instant) -> Vec<LoopView> {
        let view = |(l, s): (&Loop, &Said)| LoopView {
            of: l.clone(),
            up: s.up,
            held: s.held.clone(),
            problem: s.problem.clone(),
            last_error: s.last_error.clone(),
            down_for_ms: s.down_since.map(|t| ms(now.saturating_duration_since(t))),
            spool_messages: s.spool.0,
            spool_bytes: s.spool.1,
        };
        self.loops.iter().map(view).collect()
    }

    /// Loops that have not beaten within `limit` of `now`.
    pub fn stale(&self, now: Instant, limit: Duration) -> Vec<String> {
        let silent = |s: &&Said| now.saturating_duration_since(s.beat) > limit;
        let stale = self.loops.iter().filter(|(_, s)| silent(s));
        stale.map(|(l, _)| l.to_string()).collect()
    }

    /// Whether every loop has made its first attempt.
    pub fn all_started(&self) -> bool {
        self.loops.values().all(|s| s.started)
    }

    /// One line for `systemctl status` and `/healthz`: buses up, devices online, the outputs'
    /// connections, and every problem a loop has (a refused state file, a held output).
    pub fn status_line(&self) -> String {
        let count = |bus: bool| {
            let of = self
                .loops
                .iter()
                .filter(|(l, _)| matches!(l, Loop::Bus(_)) == bus);
            let (all, up) = of.fold((0, 0), |(a, u), (_, s)| (a + 1, u + usize::from(s.up)));
            (up, all)
        };
        let ((buses_up, buses), (outputs_up, outputs)) = (count(true), count(false));
        let mqtt = match (outputs_up, outputs) {
            (_, 0) => "MQTT not started".to_string(),
            (n, all) if n == all => "MQTT connected".to_string(),
            (0, _) => "MQTT disconnected".to_string(),
            (n, all) => format!("MQTT {n}/{all} outputs connected"),
        };
        let online = self.devices.values().filter(|o| **o).count();
        let mut line = format!(
            "{buses_up}/{buses} buses up, {online}/{} devices online, {mqtt}",
            self.devices.len()
        );
        for (l, s) in &self.loops {
            if let Some(p) = &s.problem {
                line += &format!("; {l}: {p}");
            }
            if let Some(h) = &s.held {
                line += &format!("; {l} held: {h}");
            }
            if let Some(n) = &s.note {
                line += &format!("; {l}: {n}");
            }
            if matches!(l, Loop::Output(_)) && !s.up {
                line += &format!("; {l} disconnected");
            }
        }
        line
    }

    /// `Ok` with the status line when all is well at `now`; `Err` with what is not: a loop
    /// silent for `stale_after`, a bus that is not polling (its line down, its state file
    /// refused), an output held or disconnected for more than [`OUTPUT_GRACE`].
    pub fn verdict(&self, now: Instant, stale_after: Duration) -> Result<String, String> {
        let stale = self.stale(now, stale_after);
        if !stale.is_empty() {
            return Err(format!("not making progress: {}", stale.join(", ")));
        }
        let faults: Vec<String> = self
            .loops
            .iter()
            .filter_map(|(l, s)| fault(l, s, now))
            .collect();
        let line = self.status_line();
        if faults.is_empty() {
            Ok(line)
        } else {
            Err(format!("{}: {line}", faults.join(", ")))
        }
    }
}

/// What is wrong with loop `l` at `now`, if anything.
fn fault(l: &Loop, s: &Said, now: Instant) -> Option<String> {
    match l {
        Loop::Bus(_) if s.down_since.is_some() || s.problem.is_some() => {
            Some(format!("{l} not polling"))
        }
        Loop::Bus(_) => None,
        Loop::Output(_) => {
            let down = now.saturating_duration_since(s.down_since?);
            if down <= OUTPUT_GRACE {
                return None;
            }
            let what = if s.held.is_some() {
                "held"
            } else {
                "disconnected"
            };
            Some(format!("{l} {what} for {} s", down.as_secs()))
        }
    }
}

#[cfg(test)]
#[path = "vitals_tests.rs"]
mod tests;
