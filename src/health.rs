//! Liveness of the gateway's loops, for the systemd watchdog and status line.
//!
//! Every bus loop and the MQTT task beat a heart at least once a second while they make
//! progress; the watchdog is fed only while every heart is fresh, so a stuck bus gets the service
//! restarted. The status line counts buses up and devices online.

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
}

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
    }

    /// The loop refuses to work, and why (for `systemctl status`).
    pub fn set_problem(&self, problem: Option<String>) {
        *lock(&self.beat.problem) = problem;
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Health {
    /// Registers a loop (`bus/<name>` or `mqtt`) and returns its heart.
    pub fn heart(&self, name: &str) -> Heart {
        let beat = Arc::new(Beat {
            at_ms: AtomicU64::new(self.start.elapsed().as_millis() as u64),
            up: AtomicBool::new(false),
            started: AtomicBool::new(false),
            problem: Mutex::new(None),
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

    /// Forgets devices not in `keep` (after a reload).
    pub fn retain_devices(&self, keep: &[String]) {
        lock(&self.devices).retain(|k, _| keep.contains(k));
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

    /// One line for `systemctl status`.
    pub fn status_line(&self) -> String {
        let loops = lock(&self.loops);
        let buses: Vec<_> = loops
            .iter()
            .filter(|(n, _)| n.starts_with("bus/"))
            .collect();
        let up = buses
            .iter()
            .filter(|(_, b)| b.up.load(Ordering::Relaxed))
            .count();
        let mqtt = loops
            .get("mqtt")
            .map(|b| {
                if b.up.load(Ordering::Relaxed) {
                    "MQTT connected"
                } else {
                    "MQTT disconnected"
                }
            })
            .unwrap_or("MQTT not started");
        let devices = lock(&self.devices);
        let online = devices.values().filter(|o| **o).count();
        let mut line = format!(
            "{up}/{} buses up, {online}/{} devices online, {mqtt}",
            buses.len(),
            devices.len()
        );
        for (name, b) in loops.iter() {
            if let Some(p) = lock(&b.problem).as_ref() {
                line += &format!("; {name}: {p}");
            }
        }
        line
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
        h.heart("mqtt").set_up(true);
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
}
