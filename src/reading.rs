//! What flows from the buses to MQTT.

use std::sync::Arc;
use std::time::SystemTime;

use crate::counter::Update;

/// One channel's reading from one poll.
#[derive(Debug, Clone, PartialEq)]
pub struct Reading {
    pub device: Arc<str>,
    pub channel: Arc<str>,
    /// When the answer arrived.
    pub ts: SystemTime,
    /// The module's count (signed for encoders, unsigned for inputs counting on their own).
    pub count: i64,
    pub freq_hz: Option<f64>,
    pub rpm: Option<f64>,
    pub update: Update,
    /// On the first reading after a crash: the seq its delta counts from. Readings of the
    /// crashed run with a higher seq are superseded (their pulses are in this delta).
    pub after_seq: Option<u64>,
    /// What the channel counts in the module's current work mode (a ZH-YX1600 `di1` is an
    /// input counter in one mode and an encoder in another).
    pub kind: crate::profile::ChannelKind,
    /// Engineering units of the channel, when it has a `scale`.
    pub units: Option<Arc<crate::config::channel::ChannelUnits>>,
}

/// Everything a bus task reports.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    Reading(Reading),
    /// The readings of one device's poll, published as one message (`payload = "device"`).
    DeviceReadings {
        device: Arc<str>,
        readings: Vec<Reading>,
    },
    /// A device became available (first good read) or stopped answering.
    DeviceStatus {
        device: Arc<str>,
        online: bool,
    },
    /// The device has a problem that stops some or all of its readings:
    /// `<root>/<device>/status` = `status` (`wrong_model`, `mode_mismatch`).
    DeviceProblem {
        device: Arc<str>,
        status: &'static str,
    },
    /// Health of a bus.
    BusStats {
        bus: Arc<str>,
        stats: Box<crate::bus::stats::BusStats>,
    },
    /// The answer to a command, as JSON, and the topics it goes to.
    CommandResult {
        topics: Vec<String>,
        correlation: Option<bytes::Bytes>,
        payload: serde_json::Value,
    },
    /// A module a bus scan found, as it answered (`<root>/bus/<bus>/scan/progress`).
    ScanProgress {
        topic: String,
        progress: Box<crate::bus::survey::ScanProgress>,
    },
    /// A state save of the bus is starting: it records the seq of every reading sent before
    /// this, so those go to the broker now, not at the end of a batch (`mqtt.batch`). After a
    /// crash the next run's first readings count from the saved seqs (`after_seq`): a reading
    /// up to them must not be one that died in memory. Publishes nothing.
    Checkpoint,
}

/// Milliseconds since the Unix epoch.
pub fn unix_ms(t: SystemTime) -> u64 {
    t.duration_since(SystemTime::UNIX_EPOCH)
        .map(|d| d.as_millis() as u64)
        .unwrap_or(0)
}

/// The process's monotonic epoch: monotonic milliseconds are counted from the first use.
fn epoch() -> std::time::Instant {
    static EPOCH: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    *EPOCH.get_or_init(std::time::Instant::now)
}

/// The stamp of an answer that arrived at wall time `wall` and monotonic time `mono`.
pub fn stamp(wall: SystemTime, mono: std::time::Instant) -> crate::counter::Stamp {
    crate::counter::Stamp {
        wall_ms: unix_ms(wall),
        mono_ms: mono.saturating_duration_since(epoch()).as_millis() as u64,
    }
}

/// Now, on both clocks.
pub fn now() -> (SystemTime, std::time::Instant) {
    epoch();
    (SystemTime::now(), std::time::Instant::now())
}
