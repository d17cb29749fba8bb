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
    pub units: Option<Arc<crate::config::units::ChannelUnits>>,
    /// The offset `set_reading` gave the channel's meter reading, if any.
    pub meter: Option<crate::metering::meter::MeterOffset>,
    /// A gauge's value (a temperature, a power, a date), in the unit of `units`; `None` for a
    /// count, whose `count` and `update` are what it says. A gauge's `count` is 0 and its
    /// `update` books nothing.
    pub measured: Option<Measure>,
}

/// A measured value as the device gave it: an exact decimal where it sent one (an M-Bus
/// record's raw value × 10^exponent), a real number, or text (a date, an identification).
#[derive(Debug, Clone, PartialEq)]
pub enum Measure {
    Exact(crate::decimal::Decimal),
    Real(f64),
    Text(Arc<str>),
}

impl Measure {
    /// The value as a number, where it is one.
    pub fn to_f64(&self) -> Option<f64> {
        match self {
            Measure::Exact(d) => Some(d.to_f64()),
            Measure::Real(v) => Some(*v),
            Measure::Text(_) => None,
        }
    }
}

impl std::fmt::Display for Measure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Measure::Exact(d) => write!(f, "{d}"),
            Measure::Real(v) => write!(f, "{v}"),
            Measure::Text(t) => f.write_str(t),
        }
    }
}

impl Reading {
    /// Whether this is a gauge's value rather than a count.
    pub fn is_gauge(&self) -> bool {
        self.measured.is_some()
    }
}

/// A closed interval of one channel and period (`<root>/<device>/<channel>/interval/<period>`).
#[derive(Debug, Clone, PartialEq)]
pub struct IntervalRecord {
    pub device: Arc<str>,
    pub channel: Arc<str>,
    /// The period as the config writes it (`15min`).
    pub period: Arc<str>,
    pub record: crate::metering::Record,
    /// Engineering units of the channel, when it has a `scale` (the record's `value`).
    pub units: Option<Arc<crate::config::units::ChannelUnits>>,
}

#[cfg(test)]
impl Reading {
    /// A reading of an encoder channel for tests: count 1, delta 1, total 1, at `seq`.
    pub(crate) fn sample(device: &str, channel: &str, seq: u64) -> Reading {
        Reading {
            device: device.into(),
            channel: channel.into(),
            ts: SystemTime::UNIX_EPOCH,
            count: 1,
            freq_hz: None,
            rpm: None,
            update: Update {
                delta: 1,
                total: 1,
                seq,
                rate_hz: None,
                event: None,
            },
            after_seq: None,
            meter: None,
            kind: crate::profile::ChannelKind::Encoder,
            units: None,
            measured: None,
        }
    }
}

/// Everything a bus task reports.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// The readings of one device's poll (or command) that its publish policy lets through;
    /// the format decides whether they go as one message (`payload = "device"`) or one each.
    DeviceReadings {
        device: Arc<str>,
        readings: Vec<Reading>,
    },
    /// A device became available (first good read) or stopped answering.
    DeviceStatus { device: Arc<str>, online: bool },
    /// The device has a problem that stops some or all of its readings:
    /// `<root>/<device>/status` = `status` (`wrong_model`, `mode_mismatch`).
    DeviceProblem {
        device: Arc<str>,
        status: &'static str,
    },
    /// Health of a bus.
    BusStats {
        bus: Arc<str>,
        stats: Box<crate::bus_health::BusStats>,
    },
    /// The answer to a command or a scan, and where it goes.
    CommandResult {
        reply: crate::command::Reply,
        outcome: crate::outcome::Outcome,
    },
    /// A module a bus scan found, as it answered (`<root>/bus/<bus>/scan/progress`).
    ScanProgress {
        topic: String,
        progress: Box<crate::outcome::ScanProgress>,
    },
    /// A state save of the bus is waiting: it may record the seq of every reading sent before
    /// this only once those are durable (acknowledged by the broker, or fsynced in the spool),
    /// which the MQTT task says through the checkpoint. After a crash the next run's first
    /// readings count from the saved seqs (`after_seq`): a reading up to them must not be one
    /// that died in memory. Publishes nothing.
    Checkpoint(Checkpoint),
    /// A closed interval record: owed like a reading (spooled, in order).
    Interval(Box<IntervalRecord>),
}

impl Output {
    /// The readings of one poll of `r`'s device that has only `r`.
    pub fn single(r: Reading) -> Output {
        Output::DeviceReadings {
            device: r.device.clone(),
            readings: vec![r],
        }
    }
}

/// A state save's question to the MQTT task: "is everything sent before me durable?" Answered
/// once (`true`: acknowledged or fsynced; `false`: it cannot be made so); dropped unanswered
/// (no MQTT task) means there is no one to lose readings to.
#[derive(Debug, Clone)]
pub struct Checkpoint(Arc<std::sync::Mutex<Option<tokio::sync::oneshot::Sender<bool>>>>);

impl Checkpoint {
    /// A checkpoint and the receiver of its answer.
    pub fn new() -> (Checkpoint, tokio::sync::oneshot::Receiver<bool>) {
        let (tx, rx) = tokio::sync::oneshot::channel();
        (Checkpoint(Arc::new(std::sync::Mutex::new(Some(tx)))), rx)
    }

    /// Answers the save (once; later answers are ignored).
    pub fn answer(&self, durable: bool) {
        let mut slot = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(tx) = slot.take() {
            let _ = tx.send(durable);
        }
    }
}

impl PartialEq for Checkpoint {
    fn eq(&self, other: &Checkpoint) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
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
