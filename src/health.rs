//! Liveness and truth of the gateway's loops, for the systemd watchdog and status line and for
//! `/healthz`.
//!
//! Every bus loop (`bus/<name>`) and every output's MQTT task (`output/<name>`) beat a heart at
//! least once a second while they make progress; the watchdog is fed only while every heart is
//! fresh, so a stuck bus gets the service restarted. The status line counts buses up, devices
//! online and the outputs' connections, and names every problem; [`Health::verdict`] says
//! whether all is well: every bus polling, and no output held or disconnected for longer than
//! [`OUTPUT_GRACE`].

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// One loop's heartbeat and state.
#[derive(Debug)]
pub struct Beat {
    /// Milliseconds since the gateway started, at the last beat.
    at_ms: AtomicU64,
    /// The bus's line is up (port open, answering), or MQTT is connected.
    up: AtomicBool,
    /// The loop has made its first attempt (opened its port or tried to).
    started: AtomicBool,
    /// Why the loop refuses to work (shown in the status line), e.g. a state file moved aside.
    problem: Mutex<Option<String>>,
    /// Why an output holds what it would publish (Sparkplug: its primary host is offline).
    held: Mutex<Option<String>>,
    /// What the status line should say of the loop that is no fault yet (a certificate that
    /// expires soon).
    note: Mutex<Option<String>>,
    /// Milliseconds since the gateway started at which the loop went down, or was held;
    /// [`UP`] while it is up and not held.
    down_since_ms: AtomicU64,
    /// An output's last connection error and when it happened (Unix ms); kept after it
    /// reconnects, for the status page.
    last_error: Mutex<Option<(String, u64)>>,
    /// An output's spool: messages and bytes waiting.
    spool_messages: AtomicU64,
    spool_bytes: AtomicU64,
}

/// One loop as the status page shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoopView {
    /// `bus/<name>` or `output/<name>`.
    pub name: String,
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

/// [`Beat::down_since_ms`] of a loop that is up.
const UP: u64 = u64::MAX;

/// How long an output may be disconnected or held before the gateway is not well (a broker
/// restart, a reconnect with back-off, is not a fault).
pub const OUTPUT_GRACE: Duration = Duration::from_secs(30);

/// Shared health of a running gateway.
#[derive(Debug)]
pub struct Health {
    start: Instant,
    loops: Mutex<BTreeMap<String, Arc<Beat>>>,
    /// Devices online, by name.
    devices: Mutex<BTreeMap<String, bool>>,
}

impl Default for Health {
    fn default() -> Health {
        Health {
            start: Instant::now(),
            loops: Mutex::default(),
            devices: Mutex::default(),
        }
    }
}

/// A handle a loop beats with.
#[derive(Debug, Clone)]
pub struct Heart {
    beat: Arc<Beat>,
    start: Instant,
}

impl Heart {
    /// The loop is alive and making progress.
    pub fn beat(&self) {
        let ms = self.start.elapsed().as_millis() as u64;
        self.beat.at_ms.store(ms, Ordering::Relaxed);
    }

    /// The line (or broker connection) is up or down; either way the loop has made its first
    /// attempt.
    pub fn set_up(&self, up: bool) {
        self.beat.up.store(up, Ordering::Relaxed);
        self.beat.started.store(true, Ordering::Relaxed);
        self.mark();
    }

    /// The loop refuses to work, and why (for `systemctl status`).
    pub fn set_problem(&self, problem: Option<String>) {
        *lock(&self.beat.problem) = problem;
    }

    /// A warning for the status line that is no fault (yet); `None` to clear it.
    pub fn set_note(&self, note: Option<String>) {
        *lock(&self.beat.note) = note;
    }

    /// The output holds what it would publish, and why; `None` when it no longer does.
    pub fn set_held(&self, why: Option<String>) {
        *lock(&self.beat.held) = why;
        self.mark();
    }

    /// The connection failed, and why (kept until the next failure).
    pub fn set_error(&self, why: String) {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        *lock(&self.beat.last_error) = Some((why, now));
    }

    /// What the output's spool holds.
    pub fn set_spool(&self, messages: u64, bytes: u64) {
        self.beat.spool_messages.store(messages, Ordering::Relaxed);
        self.beat.spool_bytes.store(bytes, Ordering::Relaxed);
    }

    /// Notes when the loop stopped being up and unheld (kept while it stays so).
    fn mark(&self) {
        let well = self.beat.up.load(Ordering::Relaxed) && lock(&self.beat.held).is_none();
        let since = &self.beat.down_since_ms;
        if well {
            since.store(UP, Ordering::Relaxed);
        } else if since.load(Ordering::Relaxed) == UP {
            since.store(self.start.elapsed().as_millis() as u64, Ordering::Relaxed);
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Health {
    /// Registers a loop (`bus/<name>` or `output/<name>`) and returns its heart.
    pub fn heart(&self, name: &str) -> Heart {
        let now = self.start.elapsed().as_millis() as u64;
        let beat = Arc::new(Beat {
            at_ms: AtomicU64::new(now),
            up: AtomicBool::new(false),
            started: AtomicBool::new(false),
            problem: Mutex::new(None),
            held: Mutex::new(None),
            note: Mutex::new(None),
            down_since_ms: AtomicU64::new(now),
            last_error: Mutex::new(None),
            spool_messages: AtomicU64::new(0),
            spool_bytes: AtomicU64::new(0),
        });
        lock(&self.loops).insert(name.to_string(), beat.clone());
        Heart {
            beat,
            start: self.start,
        }
    }

    /// Forgets a loop that was stopped on purpose (a bus removed by a reload).
    pub fn forget(&self, name: &str) {
        lock(&self.loops).remove(name);
    }

    /// Records a device's availability.
    pub fn device(&self, name: &str, online: bool) {
        lock(&self.devices).insert(name.to_string(), online);
    }

    /// The devices online now.
    pub fn online_devices(&self) -> Vec<String> {
        lock(&self.devices)
            .iter()
            .filter(|(_, up)| **up)
            .map(|(name, _)| name.clone())
            .collect()
    }

    /// Whether the loop `name` (`output/<name>`, `bus/<name>`) is up now.
    pub fn is_up(&self, name: &str) -> bool {
        lock(&self.loops)
            .get(name)
            .is_some_and(|b| b.up.load(Ordering::Relaxed))
    }

    /// Forgets devices not in `keep` (after a reload).
    pub fn retain_devices(&self, keep: &[String]) {
        lock(&self.devices).retain(|k, _| keep.contains(k));
    }

    /// How long the gateway has run.
    pub fn uptime(&self) -> Duration {
        self.start.elapsed()
    }

    /// Every loop, by name.
    pub fn loops(&self) -> Vec<LoopView> {
        let now = self.start.elapsed().as_millis() as u64;
        lock(&self.loops)
            .iter()
            .map(|(name, b)| {
                let since = b.down_since_ms.load(Ordering::Relaxed);
                LoopView {
                    name: name.clone(),
                    up: b.up.load(Ordering::Relaxed),
                    held: lock(&b.held).clone(),
                    problem: lock(&b.problem).clone(),
                    last_error: lock(&b.last_error).clone(),
                    down_for_ms: (since != UP).then(|| now.saturating_sub(since)),
                    spool_messages: b.spool_messages.load(Ordering::Relaxed),
                    spool_bytes: b.spool_bytes.load(Ordering::Relaxed),
                }
            })
            .collect()
    }

    /// Loops that have not beaten within `limit`.
    pub fn stale(&self, limit: Duration) -> Vec<String> {
        let now = self.start.elapsed().as_millis() as u64;
        lock(&self.loops)
            .iter()
            .filter(|(_, b)| {
                now.saturating_sub(b.at_ms.load(Ordering::Relaxed)) > limit.as_millis() as u64
            })
            .map(|(n, _)| n.clone())
            .collect()
    }

    /// Whether every loop has made its first attempt.
    pub fn all_started(&self) -> bool {
        lock(&self.loops)
            .values()
            .all(|b| b.started.load(Ordering::Relaxed))
    }

    /// One line for `systemctl status` and `/healthz`: buses up, devices online, the outputs'
    /// connections, and every problem a loop has (a refused state file, a held output).
    pub fn status_line(&self) -> String {
        let loops = lock(&self.loops);
        let of = |prefix: &str| -> Vec<(&String, &Arc<Beat>)> {
            loops
                .iter()
                .filter(|(n, _)| n.starts_with(prefix))
                .collect()
        };
        let (buses, outputs) = (of("bus/"), of("output/"));
        let up = |list: &[(&String, &Arc<Beat>)]| {
            list.iter()
                .filter(|(_, b)| b.up.load(Ordering::Relaxed))
                .count()
        };
        let mqtt = match (up(&outputs), outputs.len()) {
            (_, 0) => "MQTT not started".to_string(),
            (n, all) if n == all => "MQTT connected".to_string(),
            (0, _) => "MQTT disconnected".to_string(),
            (n, all) => format!("MQTT {n}/{all} outputs connected"),
        };
        let devices = lock(&self.devices);
        let online = devices.values().filter(|o| **o).count();
        let mut line = format!(
            "{}/{} buses up, {online}/{} devices online, {mqtt}",
            up(&buses),
            buses.len(),
            devices.len()
        );
        for (name, b) in loops.iter() {
            if let Some(p) = lock(&b.problem).as_ref() {
                line += &format!("; {name}: {p}");
            }
            if let Some(h) = lock(&b.held).as_ref() {
                line += &format!("; {name} held: {h}");
            }
            if let Some(n) = lock(&b.note).as_ref() {
                line += &format!("; {name}: {n}");
            }
            if name.starts_with("output/") && !b.up.load(Ordering::Relaxed) {
                line += &format!("; {name} disconnected");
            }
        }
        line
    }

    /// `Ok` with the status line when all is well; `Err` with what is not: a loop that makes no
    /// progress, a bus that is not polling (its line down, its state file refused), an output
    /// held or disconnected for more than [`OUTPUT_GRACE`].
    pub fn verdict(&self, stale_after: Duration) -> Result<String, String> {
        let stale = self.stale(stale_after);
        if !stale.is_empty() {
            return Err(format!("not making progress: {}", stale.join(", ")));
        }
        let now = self.start.elapsed().as_millis() as u64;
        let grace = OUTPUT_GRACE.as_millis() as u64;
        let loops = lock(&self.loops);
        let mut faults = Vec::new();
        for (name, b) in loops.iter() {
            let since = b.down_since_ms.load(Ordering::Relaxed);
            let down = since != UP;
            if name.starts_with("bus/") && (down || lock(&b.problem).is_some()) {
                faults.push(format!("{name} not polling"));
            } else if name.starts_with("output/") && down && now.saturating_sub(since) > grace {
                let what = if lock(&b.held).is_some() {
                    "held"
                } else {
                    "disconnected"
                };
                let secs = now.saturating_sub(since) / 1000;
                faults.push(format!("{name} {what} for {secs} s"));
            }
        }
        drop(loops);
        let line = self.status_line();
        if faults.is_empty() {
            Ok(line)
        } else {
            Err(format!("{}: {line}", faults.join(", ")))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loop_that_stops_beating_is_stale() {
        let h = Health::default();
        let a = h.heart("bus/a");
        let _b = h.heart("bus/b");
        a.beat();
        assert!(h.stale(Duration::from_secs(60)).is_empty());
        std::thread::sleep(Duration::from_millis(300));
        a.beat();
        // Wide margins: a loaded machine may pause this thread between the beat and the look.
        assert_eq!(
            h.stale(Duration::from_millis(200)),
            vec!["bus/b".to_string()]
        );
    }

    #[test]
    fn the_status_line_counts_buses_devices_and_mqtt() {
        let h = Health::default();
        h.heart("bus/a").set_up(true);
        h.heart("bus/b");
        h.heart("output/json").set_up(true);
        h.device("press", true);
        h.device("doors", false);
        assert_eq!(
            h.status_line(),
            "1/2 buses up, 1/2 devices online, MQTT connected"
        );
    }

    #[test]
    fn ready_waits_for_every_loop_to_start() {
        let h = Health::default();
        let a = h.heart("bus/a");
        a.beat();
        assert!(!h.all_started(), "running is not yet having tried the line");
        a.set_up(false);
        assert!(h.all_started());
    }

    #[test]
    fn a_bus_that_is_not_polling_is_not_well() {
        let h = Health::default();
        h.heart("output/json").set_up(true);
        let bus = h.heart("bus/a");
        bus.set_up(true);
        assert!(h.verdict(Duration::from_secs(60)).is_ok());
        bus.set_problem(Some("state file refused, not polling".into()));
        let why = h.verdict(Duration::from_secs(60)).unwrap_err();
        assert!(why.contains("bus/a not polling"), "{why}");
        assert!(why.contains("state file refused"), "{why}");
        bus.set_problem(None);
        bus.set_up(false);
        assert!(
            h.verdict(Duration::from_secs(60)).is_err(),
            "its line is down"
        );
    }

    #[test]
    fn an_output_held_or_down_is_not_well_after_the_grace_only() {
        let h = Health::default();
        let out = h.heart("output/scada");
        out.set_up(true);
        h.heart("bus/a").set_up(true);
        out.set_held(Some("primary host offline".into()));
        let line = h
            .verdict(Duration::from_secs(60))
            .expect("within the grace");
        assert!(
            line.contains("output/scada held: primary host offline"),
            "{line}"
        );
        // Held since long ago: the mark is what the verdict reads.
        out.beat.down_since_ms.store(0, Ordering::Relaxed);
        std::thread::sleep(Duration::from_millis(5));
        let h2 = Health {
            start: h.start - OUTPUT_GRACE - Duration::from_secs(1),
            loops: Mutex::new(lock(&h.loops).clone()),
            devices: Mutex::default(),
        };
        let why = h2.verdict(Duration::from_secs(3600)).unwrap_err();
        assert!(why.contains("output/scada held for"), "{why}");
        out.set_held(None);
        assert!(h2.verdict(Duration::from_secs(3600)).is_ok(), "well again");
    }

    #[test]
    fn an_outputs_last_error_and_spool_are_kept_for_the_page() {
        let h = Health::default();
        let out = h.heart("output/json");
        out.set_up(false);
        out.set_error("connection refused".into());
        out.set_spool(12, 3400);
        out.set_up(true);
        let view = h.loops().pop().unwrap();
        assert_eq!(view.name, "output/json");
        assert!(view.up && view.down_for_ms.is_none());
        assert_eq!(
            view.last_error.unwrap().0,
            "connection refused",
            "kept once up again"
        );
        assert_eq!((view.spool_messages, view.spool_bytes), (12, 3400));
    }
}
