//! The status API's JSON (`GET /api/v1/status`), as types: what docs/http.md documents field by
//! field. Version 1 only grows: a field may be added, none is renamed, removed or changes its
//! meaning. Times are Unix milliseconds; durations say their unit in their name.

use serde::Serialize;

/// The whole answer.
#[derive(Debug, Clone, Serialize)]
pub struct Status {
    /// The API's version: 1.
    pub api: u32,
    /// The gateway's clock when this was made.
    pub now_ms: u64,
    pub gateway: GatewayView,
    pub outputs: Vec<OutputView>,
    pub buses: Vec<BusView>,
    pub devices: Vec<DeviceView>,
    /// The last 100 things that happened, newest first.
    pub events: Vec<EventView>,
    /// The scan that runs now, or the last one, while its report is fresh.
    pub scan: Option<ScanView>,
}

/// This gateway.
#[derive(Debug, Clone, Serialize)]
pub struct GatewayView {
    pub id: String,
    pub version: String,
    pub started_ms: u64,
    pub uptime_s: u64,
    /// The config file it was started with.
    pub config_file: String,
    /// SHA-256 of the config in force (`config::ConfigHash`), 64 hex digits.
    pub config_hash: String,
}

/// One MQTT connection (an output, or the gateway's own).
#[derive(Debug, Clone, Serialize)]
pub struct OutputView {
    pub name: String,
    /// The output's format, `null` for the gateway's own connection.
    pub format: Option<String>,
    /// `host:port` or the socket path.
    pub broker: String,
    pub connected: bool,
    /// Why it holds what it would publish, while it does.
    pub held: Option<String>,
    /// Seconds it has been disconnected or held (`null` while connected and not held).
    pub down_s: Option<f64>,
    /// Messages wait in its spool.
    pub spooling: bool,
    pub spool_messages: u64,
    pub spool_bytes: u64,
    /// The spool's bound (`spool_bytes` of its MQTT settings).
    pub spool_limit_bytes: u64,
    /// The last connection error (kept after it reconnected), and when.
    pub last_error: Option<String>,
    pub last_error_ms: Option<u64>,
    /// Why it stopped trying (a broker that refuses the protocol).
    pub problem: Option<String>,
}

/// One bus.
#[derive(Debug, Clone, Serialize)]
pub struct BusView {
    pub name: String,
    /// `RTU /dev/ttyUSB0 at 9600 baud` or `TCP host:port`.
    pub link: String,
    /// Its line is open and answering.
    pub up: bool,
    /// Why it does not poll (a state file moved aside), while it does not.
    pub problem: Option<String>,
    /// Since the gateway started.
    pub transactions: u64,
    pub reconnects: u64,
    pub line_faults: u64,
    /// The last stats interval's figures (`gateway.stats_interval`), once there is one.
    pub stats: Option<BusStatsView>,
}

/// A bus's stats interval.
#[derive(Debug, Clone, Serialize)]
pub struct BusStatsView {
    /// When the interval ended.
    pub at_ms: u64,
    /// Share of the interval the line was busy (0..1).
    pub utilisation: f64,
    pub transactions_per_s: f64,
    /// Since the bus task started (the published bus stats' counters).
    pub timeouts: u64,
    pub garbled: u64,
    pub stale_dropped: u64,
    pub io_errors: u64,
    pub exceptions: u64,
    pub reconnects: u64,
}

/// One device.
#[derive(Debug, Clone, Serialize)]
pub struct DeviceView {
    pub name: String,
    pub bus: String,
    pub unit: u8,
    /// Where it is on its bus, as a person says it: `unit 3` (Modbus), `primary address 5` or
    /// `id 12345678` (an M-Bus meter, whose `unit` means nothing).
    pub address: String,
    /// The model configured.
    pub model: String,
    /// `unknown` (not yet answered), `online`, `offline`, or a problem: `wrong_model`,
    /// `mode_mismatch`, … (the device's MQTT status).
    pub status: String,
    pub status_since_ms: Option<u64>,
    pub poll_ms: u64,
    /// The last good answer, and its latency.
    pub last_answer_ms: Option<u64>,
    pub latency_ms: Option<f64>,
    /// The mean latency of every good answer since start.
    pub mean_latency_ms: Option<f64>,
    /// Over the answers of the last stats interval.
    pub latency_p50_ms: Option<f64>,
    pub latency_p99_ms: Option<f64>,
    /// Since the gateway started.
    pub transactions: u64,
    pub timeouts: u64,
    pub garbled: u64,
    pub exceptions: u64,
    /// Polls missed in the last stats interval (the line could not keep up).
    pub missed: Option<u64>,
    /// The last error (cleared when it answers well again), as of the last stats interval.
    pub last_error: Option<String>,
    /// How its count poll is cut into requests on a noisy line.
    pub request: Option<RequestView>,
    pub channels: Vec<ChannelView>,
}

/// How a device's count poll is cut now.
#[derive(Debug, Clone, Serialize)]
pub struct RequestView {
    /// The longest read allowed, in registers (125 on a clean line).
    pub limit: u16,
    pub requests_per_poll: usize,
    pub longest: u16,
}

/// One channel, as of its last published reading.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelView {
    pub name: String,
    /// `counter` (an input counting on its own), `encoder` (a signed position) or `gauge` (a
    /// meter's value: a temperature, a power, a date; its `value` and `unit`, no counts).
    pub kind: &'static str,
    /// The reading's fields, as published on MQTT.
    pub count: i64,
    pub total: i64,
    pub delta: i64,
    pub seq: u64,
    pub rate_hz: Option<f64>,
    /// `rollover`, `reset`, `cleared`, `preset`, `gap` on the last reading, if any.
    pub event: Option<crate::event::Event>,
    pub at_ms: u64,
    /// Engineering units (with `scale`): the unit, the scaled total (exact decimal text), the
    /// rate's unit and the scaled rate. A gauge's value as the meter gave it, in its unit.
    pub unit: Option<String>,
    pub value: Option<String>,
    pub rate_unit: Option<String>,
    pub rate: Option<f64>,
    pub history: HistoryView,
    pub intervals: Vec<IntervalView>,
}

/// A channel's rate over the last 15 minutes.
#[derive(Debug, Clone, Serialize)]
pub struct HistoryView {
    pub bucket_s: u64,
    /// The end of the newest bucket.
    pub end_ms: u64,
    /// Pulses a second in each bucket, oldest first (its deltas over its length); `null` before
    /// the channel's first reading.
    pub rates: Vec<Option<f64>>,
}

/// An interval in progress (`intervals` on).
#[derive(Debug, Clone, Serialize)]
pub struct IntervalView {
    pub period: String,
    pub start_ms: i64,
    pub end_ms: i64,
    /// Pulses booked in it so far (the record published at its end is the figure of record).
    pub delta: i64,
    /// The last closed interval's record, if one closed since start.
    pub last: Option<ClosedView>,
}

/// A closed interval.
#[derive(Debug, Clone, Serialize)]
pub struct ClosedView {
    pub start_ms: i64,
    pub end_ms: i64,
    pub delta: i64,
    pub status: crate::metering::Status,
}

/// One thing that happened.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EventView {
    pub at_ms: u64,
    /// `device`, `channel`, `command`, `scan`.
    pub kind: &'static str,
    pub device: Option<String>,
    pub channel: Option<String>,
    /// For people: `went offline`, `reset: the count started over`, …
    pub text: String,
}

/// A bus scan.
#[derive(Debug, Clone, Serialize)]
pub struct ScanView {
    pub bus: String,
    pub id: Option<String>,
    pub running: bool,
    pub asked: usize,
    /// Units still to ask (0 once it ended).
    pub pending: usize,
    pub elapsed_ms: u64,
    pub found: Vec<crate::outcome::Found>,
    pub updated_ms: u64,
}
