//! Bus health as a typed event: the bus counts, the output format writes it (in JSON the keys
//! are these field names). Pure.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::Serialize;

use super::device::DeviceRt;
use super::driver::DeviceState;
use super::schedule::Slot;

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

fn percentile(sorted: &[f64], p: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let idx = ((sorted.len() - 1) as f64 * p).round() as usize;
    Some(sorted[idx])
}

/// Bus health since the last report: the wire's counters now and then, the devices and their
/// slots, the interval and the time the line was busy in it.
pub(super) fn of<P: DeviceState>(
    (c, since): (&WireCounters, &WireCounters),
    devices: &[DeviceRt<P>],
    slots: &[Slot],
    wall: Duration,
    busy: Duration,
) -> BusStats {
    let ms = |v: f64| v * 1000.0;
    let mut per_device = BTreeMap::new();
    for (d, s) in devices.iter().zip(slots) {
        let mut lat: Vec<f64> = d.latencies.iter().copied().collect();
        lat.sort_by(f64::total_cmp);
        let size = d.proto.request_size();
        let stats = DeviceStats {
            online: d.online(),
            poll_ms: ms(d.config.poll.as_secs_f64()),
            achieved_poll_ms: d.achieved_interval.map(ms),
            missed: s.missed,
            turnaround_ms: d.proto.turnaround().map(ms),
            latency_p50_ms: percentile(&lat, 0.5).map(ms),
            latency_p99_ms: percentile(&lat, 0.99).map(ms),
            last_error: d.availability.last_error().map(str::to_string),
            request_limit: size.map(|s| s.limit),
            requests_per_poll: size.map(|s| s.requests),
            longest_request: size.map(|s| s.longest),
        };
        per_device.insert(d.name.to_string(), stats);
    }
    let wall = wall.as_secs_f64().max(1e-9);
    BusStats {
        utilisation: busy.as_secs_f64() / wall,
        transactions: c.transactions,
        transactions_per_s: (c.transactions - since.transactions) as f64 / wall,
        timeouts: c.timeouts,
        garbled: c.garbled,
        stale_dropped: c.mismatches,
        io_errors: c.io_errors,
        exceptions: c.exceptions,
        reconnects: c.reconnects,
        devices: per_device,
    }
}
