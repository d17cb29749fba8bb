//! Bus health: the bus counts, [`crate::bus_health`] holds the values, the output format writes
//! them. Pure.

use std::collections::BTreeMap;
use std::time::Duration;

use super::device::DeviceRt;
use super::driver::DeviceState;
use super::schedule::Slot;
use crate::bus_health::{BusStats, DeviceStats, WireCounters};

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
