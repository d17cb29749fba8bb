//! One bus's health as a typed event (the bus counts it in `bus/stats.rs`, the output format
//! writes it; in JSON the keys are these field names), and the wire counters a driver keeps.
//! Values only.

use std::collections::BTreeMap;

use serde::Serialize;

/// Counters of what happened on the wire, kept by the driver (for health stats). The names are
/// the ones the stats have always published; every protocol has these events.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WireCounters {
    pub transactions: u64,
    pub timeouts: u64,
    /// Answers to another request (late ones), dropped (`stale_dropped` in the stats).
    pub mismatches: u64,
    pub io_errors: u64,
    /// Requests the device refused (Modbus: exception answers).
    pub exceptions: u64,
    pub reconnects: u64,
    /// Answers that arrived garbled (bad CRC, cut short).
    pub garbled: u64,
}

/// One bus's health over the last stats interval.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BusStats {
    /// Share of the interval the line was busy.
    pub utilisation: f64,
    pub transactions: u64,
    pub transactions_per_s: f64,
    pub timeouts: u64,
    pub garbled: u64,
    /// Answers to another request (late ones), dropped.
    pub stale_dropped: u64,
    pub io_errors: u64,
    pub exceptions: u64,
    pub reconnects: u64,
    pub devices: BTreeMap<String, DeviceStats>,
}

/// One device's part of [`BusStats`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceStats {
    pub online: Option<bool>,
    pub poll_ms: f64,
    pub achieved_poll_ms: Option<f64>,
    pub missed: u64,
    pub turnaround_ms: Option<f64>,
    pub latency_p50_ms: Option<f64>,
    pub latency_p99_ms: Option<f64>,
    pub last_error: Option<String>,
    /// The longest read the device's poll may use now, in registers: 125 on a clean line,
    /// fewer after answers lost to noise (`null` for a protocol that does not plan reads).
    pub request_limit: Option<u16>,
    /// Requests of one count poll now (more while reads are shortened).
    pub requests_per_poll: Option<usize>,
    /// The longest of those requests, in registers.
    pub longest_request: Option<u16>,
}

/// How a device's count poll is cut into requests now (a driver that plans its reads).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct RequestSize {
    /// The longest read allowed, in registers.
    pub limit: u16,
    /// Requests of one count poll.
    pub requests: usize,
    /// The longest of them, in registers.
    pub longest: u16,
}
