//! What the status page reads of the metrics: a device's and a bus's series as they stand,
//! the last good answer included (a series too, `pulsegate_device_last_answer_timestamp_seconds`,
//! which an alert on a silent device wants as much as the page). The page keeps no state in
//! the metrics: it reads what Prometheus reads.

use std::collections::HashMap;

use prometheus::core::Collector;
use prometheus::proto::Metric;

use super::families::Families;

/// A series' `bus` and `device` labels.
fn device_of(m: &Metric) -> Option<(String, String)> {
    let label = |name: &str| {
        m.get_label()
            .iter()
            .find(|l| l.name() == name)
            .map(|l| l.value().to_string())
    };
    Some((label("bus")?, label("device")?))
}

/// Every device series of `family`, by bus and device, as `value` reads it.
fn per_device(
    family: &dyn Collector,
    value: impl Fn(&Metric) -> f64,
) -> HashMap<(String, String), f64> {
    let mut out = HashMap::new();
    for f in family.collect() {
        for m in f.get_metric() {
            if let Some(key) = device_of(m) {
                out.insert(key, value(m));
            }
        }
    }
    out
}

/// Every device whose bus made its series, with its look: one read of each family.
pub(super) fn devices(f: &Families) -> HashMap<(String, String), DeviceLook> {
    let counter = |m: &Metric| m.get_counter().get_value();
    let gauge = |m: &Metric| m.get_gauge().get_value();
    let transactions = per_device(&f.device_transactions, counter);
    let timeouts = per_device(&f.device_timeouts, counter);
    let garbled = per_device(&f.device_garbled, counter);
    let exceptions = per_device(&f.device_exceptions, counter);
    let answered = per_device(&f.device_last_answer, gauge);
    let last_latency = per_device(&f.device_last_latency, gauge);
    let sums = per_device(&f.device_latency, |m| m.get_histogram().get_sample_sum());
    let counts = per_device(&f.device_latency, |m| {
        m.get_histogram().get_sample_count() as f64
    });
    let at =
        |t: &HashMap<(String, String), f64>, k: &(String, String)| t.get(k).copied().unwrap_or(0.0);
    let mut out = HashMap::new();
    for key in transactions.keys() {
        let answered_ms = (at(&answered, key) * 1000.0) as u64;
        let count = at(&counts, key);
        let look = DeviceLook {
            transactions: at(&transactions, key) as u64,
            timeouts: at(&timeouts, key) as u64,
            garbled: at(&garbled, key) as u64,
            exceptions: at(&exceptions, key) as u64,
            last_answer_ms: (answered_ms > 0).then_some(answered_ms),
            last_latency_ms: (answered_ms > 0).then(|| at(&last_latency, key) * 1000.0),
            mean_latency_ms: (count > 0.0).then(|| at(&sums, key) / count * 1000.0),
        };
        out.insert(key.clone(), look);
    }
    out
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
