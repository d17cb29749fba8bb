//! What the status page reads of the metrics: a device's and a bus's counters as they stand,
//! and the time and latency of a device's last good answer (kept here because the page needs
//! them and Prometheus does not: they are no series).

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// A device's last good answer: when (Unix ms; 0 before the first) and how long it took (µs).
#[derive(Debug, Default)]
pub(super) struct Live {
    pub(super) answered_ms: AtomicU64,
    pub(super) latency_us: AtomicU64,
}

impl Live {
    pub(super) fn answered(&self, latency: Duration) {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        self.answered_ms.store(now, Ordering::Relaxed);
        self.latency_us
            .store(latency.as_micros() as u64, Ordering::Relaxed);
    }
}

/// Every device's [`Live`], by bus and device.
#[derive(Debug, Default)]
pub(super) struct LiveTable(std::sync::Mutex<HashMap<(String, String), Arc<Live>>>);

impl LiveTable {
    pub(super) fn of(&self, bus: &str, device: &str) -> Arc<Live> {
        let mut t = self.0.lock().unwrap_or_else(|e| e.into_inner());
        t.entry((bus.to_string(), device.to_string()))
            .or_default()
            .clone()
    }

    pub(super) fn get(&self, bus: &str, device: &str) -> Option<Arc<Live>> {
        let t = self.0.lock().unwrap_or_else(|e| e.into_inner());
        t.get(&(bus.to_string(), device.to_string())).cloned()
    }

    pub(super) fn forget(&self, bus: &str, device: &str) {
        let mut t = self.0.lock().unwrap_or_else(|e| e.into_inner());
        t.remove(&(bus.to_string(), device.to_string()));
    }
}

/// A device's counters since the gateway started, and its last good answer.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DeviceLook {
    pub transactions: u64,
    pub timeouts: u64,
    pub garbled: u64,
    pub exceptions: u64,
    /// Unix ms of the last good answer.
    pub last_answer_ms: Option<u64>,
    /// Its latency, in milliseconds.
    pub last_latency_ms: Option<f64>,
    /// The mean latency of every good answer since start, in milliseconds.
    pub mean_latency_ms: Option<f64>,
}

/// A bus's counters since the gateway started.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BusLook {
    pub transactions: u64,
    pub reconnects: u64,
    pub line_faults: u64,
    /// The share of the last stats interval the line was busy.
    pub utilisation: f64,
}
