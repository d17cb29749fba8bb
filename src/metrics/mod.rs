//! Prometheus metrics: what the buses, devices, channels and the MQTT side did, served over HTTP
//! (`[metrics] listen`) so that health stays visible exactly when the broker is the problem.
//!
//! Families follow Prometheus's conventions: base units (seconds, hertz), `_total` for counters,
//! labels `bus`, `device`, `channel`. The metric handles are atomics (the `prometheus` crate);
//! each bus task holds the handles of its own bus and devices, so recording costs no lookup.
//! Counters that the bus already keeps (its [`WireCounters`]) are carried over as differences,
//! so a restarted bus task (config reload) never makes a counter go backwards.
//!
//! Without `[metrics]` the handles are empty: nothing is registered or recorded, so a gateway
//! of a thousand devices pays no memory for series nobody scrapes.

mod families;
mod look;

use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;
use std::time::Duration;

use prometheus::{Encoder, Gauge, Histogram, IntCounter, IntGauge, Registry, TextEncoder};

use crate::bus_health::WireCounters;
use crate::config::Config;
use crate::reading::Reading;
pub use families::LoginFailure;
use families::{Families, Gone};
pub use look::{BusLook, DeviceLook};

/// The gateway's metrics: one registry, handed to the buses and the MQTT task; or nothing.
#[derive(Clone, Default)]
pub struct Metrics {
    inner: Option<Arc<Enabled>>,
}

struct Enabled {
    registry: Registry,
    families: Arc<Families>,
}

impl Metrics {
    /// Metrics that record nothing (no `[metrics]` section).
    pub fn disabled() -> Metrics {
        Metrics { inner: None }
    }

    /// [`Metrics::with_servers`] with the gateway's serving outputs, for tests.
    #[cfg(test)]
    pub(crate) fn new() -> Metrics {
        Metrics::with_servers(crate::protocols::SERVER_FAMILIES)
    }

    /// A fresh registry with every family registered (the serving outputs' three, requests,
    /// connections and connections closed, named by `server`), the start time and the build
    /// info set.
    pub fn with_servers(server: [(&'static str, &'static str); 3]) -> Metrics {
        let registry = Registry::new();
        let families = Arc::new(Families::register(&registry, server));
        let start = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs_f64())
            .unwrap_or(0.0);
        families.start_time.set(start);
        families
            .build_info
            .with_label_values(&[env!("CARGO_PKG_VERSION")])
            .set(1);
        Metrics {
            inner: Some(Arc::new(Enabled { registry, families })),
        }
    }

    /// The handles of one bus.
    pub fn bus(&self, bus: &str) -> BusMetrics {
        let Some(e) = &self.inner else {
            return BusMetrics { inner: None };
        };
        let f = &e.families;
        BusMetrics {
            inner: Some(BusHandles {
                families: e.families.clone(),
                name: bus.to_string(),
                transactions: f.bus_transactions.with_label_values(&[bus]),
                reconnects: f.bus_reconnects.with_label_values(&[bus]),
                line_faults: f.bus_line_faults.with_label_values(&[bus]),
                busy: f.bus_busy.with_label_values(&[bus]),
                utilisation: f.bus_utilisation.with_label_values(&[bus]),
                last: WireCounters::default(),
                last_busy: Duration::ZERO,
            }),
        }
    }

    /// The config in force is the one with `hash`: `pulsegate_config_info{hash} 1`, alone.
    pub fn config(&self, hash: &str) {
        if let Some(e) = &self.inner {
            e.families.config_info.reset();
            e.families.config_info.with_label_values(&[hash]).set(1);
        }
    }

    /// The handles of one output's connection (`output` label: its name, or `gateway` for the
    /// gateway's own connection).
    pub fn output(&self, name: &str) -> OutputMetrics {
        OutputMetrics {
            inner: self
                .inner
                .as_ref()
                .map(|e| (e.families.clone(), name.to_string())),
        }
    }

    /// A command or scan was answered: counted, and its refusal by code.
    pub fn command_result(&self, outcome: &crate::outcome::Outcome) {
        let Some(e) = &self.inner else { return };
        // A pushed config is no command (its steps are in the log and on config/result).
        if matches!(outcome, crate::outcome::Outcome::Config(_)) {
            return;
        }
        let f = &e.families;
        f.commands_received.inc();
        if let Some(code) = outcome.refusal() {
            f.commands_refused.with_label_values(&[code]).inc();
        }
    }

    /// A token the status page or its API refused.
    pub fn login_failure(&self, failure: LoginFailure) {
        if let Some(e) = &self.inner {
            let f = &e.families.http_login_failures;
            f.with_label_values(&[failure.label()]).inc();
        }
    }

    /// Forgets every series of a bus, device or channel `config` no longer has (or no longer
    /// polls: disabled), after a reload: a removed device must not show on a dashboard as it
    /// was last seen, online. Series of what stays are kept (counters never go backwards).
    pub fn retain(&self, config: &Config) {
        let Some(e) = &self.inner else { return };
        let present = Present::of(config);
        let mut gone = Gone::default();
        for family in e.registry.gather() {
            for m in family.get_metric() {
                let label = |name: &str| {
                    m.get_label()
                        .iter()
                        .find(|l| l.name() == name)
                        .map(|l| l.value().to_string())
                };
                gone.note(&present, label("bus"), label("device"), label("channel"));
            }
        }
        e.families.forget(&gone);
    }

    /// The exposition in Prometheus's text format (version 0.0.4).
    pub fn encode(&self) -> String {
        let Some(e) = &self.inner else {
            return String::new();
        };
        let mut out = Vec::new();
        // Encoding our own, well-formed families into a Vec cannot fail.
        let _ = TextEncoder::new().encode(&e.registry.gather(), &mut out);
        String::from_utf8(out).unwrap_or_default()
    }
}

impl Metrics {
    /// Every device's counters and last answer, by bus and device: the devices whose bus
    /// made their series (none without metrics).
    pub fn device_looks(&self) -> std::collections::HashMap<(String, String), DeviceLook> {
        self.inner
            .as_ref()
            .map(|e| look::devices(&e.families))
            .unwrap_or_default()
    }

    /// A bus's counters; `None` without metrics.
    pub fn bus_look(&self, bus: &str) -> Option<BusLook> {
        let f = &self.inner.as_ref()?.families;
        let l = [bus];
        Some(BusLook {
            transactions: f.bus_transactions.with_label_values(&l).get(),
            reconnects: f.bus_reconnects.with_label_values(&l).get(),
            line_faults: f.bus_line_faults.with_label_values(&l).get(),
            utilisation: f.bus_utilisation.with_label_values(&l).get(),
        })
    }
}

/// What a config polls: enabled buses, their enabled devices and those devices' enabled
/// channels.
struct Present {
    buses: BTreeSet<String>,
    devices: BTreeSet<(String, String)>,
    channels: BTreeSet<(String, String, String)>,
    /// Devices whose channels are what they answer (M-Bus meters): any channel of theirs
    /// may be present, except one the config disables.
    open: BTreeSet<(String, String)>,
    disabled: BTreeSet<(String, String, String)>,
}

impl Present {
    fn of(config: &Config) -> Present {
        let devices = || config.enabled_devices();
        Present {
            buses: config
                .buses
                .iter()
                .filter(|b| b.enabled)
                .map(|b| b.name.clone())
                .collect(),
            devices: devices()
                .map(|(b, d)| (b.name.clone(), d.name.clone()))
                .collect(),
            channels: devices()
                .flat_map(|(b, d)| {
                    d.profile
                        .all_channels()
                        .into_iter()
                        .filter(|c| d.channels.get(&c.name).is_none_or(|cc| cc.enabled))
                        .map(move |c| (b.name.clone(), d.name.clone(), c.name))
                })
                .collect(),
            open: devices()
                .filter(|(_, d)| d.channels_from_device())
                .map(|(b, d)| (b.name.clone(), d.name.clone()))
                .collect(),
            disabled: devices()
                .flat_map(|(b, d)| {
                    d.channels
                        .iter()
                        .filter(|(_, c)| !c.enabled)
                        .map(move |(c, _)| (b.name.clone(), d.name.clone(), c.clone()))
                })
                .collect(),
        }
    }

    fn has_channel(&self, key: &(String, String, String)) -> bool {
        self.channels.contains(key)
            || (self.open.contains(&(key.0.clone(), key.1.clone())) && !self.disabled.contains(key))
    }
}

impl Gone {
    /// A series labelled `bus`, `device`, `channel` (as far as it has them): remembered when
    /// what it describes is not present.
    fn note(
        &mut self,
        present: &Present,
        bus: Option<String>,
        device: Option<String>,
        channel: Option<String>,
    ) {
        match (bus, device, channel) {
            (Some(b), Some(d), Some(c)) => {
                let key = (b, d, c);
                if !present.has_channel(&key) {
                    self.channels.insert(key);
                }
            }
            (Some(b), Some(d), None) => {
                let key = (b, d);
                if !present.devices.contains(&key) {
                    self.devices.insert(key);
                }
            }
            (Some(b), None, None) if !present.buses.contains(&b) => {
                self.buses.insert(b);
            }
            _ => {}
        }
    }
}

/// One bus's handles (none when metrics are off); owned by its bus task.
#[derive(Default)]
pub struct BusMetrics {
    inner: Option<BusHandles>,
}

struct BusHandles {
    families: Arc<Families>,
    name: String,
    transactions: IntCounter,
    reconnects: IntCounter,
    line_faults: IntCounter,
    busy: prometheus::Counter,
    utilisation: Gauge,
    /// The link's counters when last carried over.
    last: WireCounters,
    last_busy: Duration,
}

impl BusMetrics {
    /// The handles of a device on this bus.
    pub fn device(&self, device: &str) -> DeviceMetrics {
        let Some(b) = &self.inner else {
            return DeviceMetrics { inner: None };
        };
        let f = &b.families;
        let l = [b.name.as_str(), device];
        DeviceMetrics {
            inner: Some(DeviceHandles {
                families: b.families.clone(),
                bus: b.name.clone(),
                device: device.to_string(),
                up: f.device_up.with_label_values(&l),
                wrong_model: f.device_wrong_model.with_label_values(&l),
                transactions: f.device_transactions.with_label_values(&l),
                timeouts: f.device_timeouts.with_label_values(&l),
                garbled: f.device_garbled.with_label_values(&l),
                exceptions: f.device_exceptions.with_label_values(&l),
                latency: f.device_latency.with_label_values(&l),
                last_answer: f.device_last_answer.with_label_values(&l),
                last_latency: f.device_last_latency.with_label_values(&l),
                request_limit: f.device_request_limit.with_label_values(&l),
                requests_per_poll: f.device_requests_per_poll.with_label_values(&l),
                channels: HashMap::new(),
            }),
        }
    }

    /// Carries the link's cumulative counters and busy time over.
    pub fn wire(&mut self, now: &WireCounters, busy: Duration) {
        let Some(b) = &mut self.inner else { return };
        let d = diff(&b.last, now);
        b.transactions.inc_by(d.transactions);
        b.reconnects.inc_by(d.reconnects);
        b.last = *now;
        if busy > b.last_busy {
            b.busy.inc_by((busy - b.last_busy).as_secs_f64());
            b.last_busy = busy;
        }
    }

    /// The line failed (adapter gone, port cannot be opened): counted once per fault.
    pub fn line_fault(&self) {
        if let Some(b) = &self.inner {
            b.line_faults.inc();
        }
    }

    /// The share of the last stats interval the line was busy.
    pub fn utilisation(&self, ratio: f64) {
        if let Some(b) = &self.inner {
            b.utilisation.set(ratio);
        }
    }
}

/// What changed between two readings of the link's counters (zero where one went backwards).
fn diff(before: &WireCounters, after: &WireCounters) -> WireCounters {
    WireCounters {
        transactions: after.transactions.saturating_sub(before.transactions),
        timeouts: after.timeouts.saturating_sub(before.timeouts),
        mismatches: after.mismatches.saturating_sub(before.mismatches),
        io_errors: after.io_errors.saturating_sub(before.io_errors),
        exceptions: after.exceptions.saturating_sub(before.exceptions),
        reconnects: after.reconnects.saturating_sub(before.reconnects),
        garbled: after.garbled.saturating_sub(before.garbled),
    }
}

/// A channel's handles: a counter for inputs counting on their own, a gauge for encoder
/// positions (their total goes both ways), and the last rate.
struct ChannelMetrics {
    pulses: Option<IntCounter>,
    position: Option<IntGauge>,
    rate: Gauge,
}

/// One device's handles (none when metrics are off); owned by its bus task.
pub struct DeviceMetrics {
    inner: Option<DeviceHandles>,
}

struct DeviceHandles {
    families: Arc<Families>,
    bus: String,
    device: String,
    up: IntGauge,
    wrong_model: IntGauge,
    transactions: IntCounter,
    timeouts: IntCounter,
    garbled: IntCounter,
    exceptions: IntCounter,
    latency: Histogram,
    last_answer: Gauge,
    last_latency: Gauge,
    request_limit: IntGauge,
    requests_per_poll: IntGauge,
    channels: HashMap<Arc<str>, ChannelMetrics>,
}

impl DeviceMetrics {
    /// Handles that record nothing.
    pub fn disabled() -> DeviceMetrics {
        DeviceMetrics { inner: None }
    }

    /// The transactions this device took: the link's counters before and after them.
    pub fn wire(&self, before: &WireCounters, after: &WireCounters) {
        let Some(h) = &self.inner else { return };
        let d = diff(before, after);
        h.transactions.inc_by(d.transactions);
        h.timeouts.inc_by(d.timeouts);
        h.garbled.inc_by(d.garbled);
        h.exceptions.inc_by(d.exceptions);
    }

    /// One transaction's latency (request sent → answer decoded).
    pub fn latency(&self, d: Duration) {
        if let Some(h) = &self.inner {
            h.latency.observe(d.as_secs_f64());
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap_or_default();
            h.last_answer.set(now.as_secs_f64());
            h.last_latency.set(d.as_secs_f64());
        }
    }

    /// How the count poll is cut now: the longest read allowed and the requests it takes.
    pub fn request_size(&self, limit: u16, requests: usize) {
        if let Some(h) = &self.inner {
            h.request_limit.set(i64::from(limit));
            h.requests_per_poll.set(requests as i64);
        }
    }

    /// Availability: 1 online, 0 offline or not yet seen.
    pub fn up(&self, online: Option<bool>) {
        if let Some(h) = &self.inner {
            h.up.set((online == Some(true)) as i64);
        }
    }

    /// The module is not the model configured (set by the identification check).
    pub fn wrong_model(&self, wrong: bool) {
        if let Some(h) = &self.inner {
            h.wrong_model.set(wrong as i64);
        }
    }

    /// A reading that is being published (an encoder's total is a position; a gauge's value
    /// is no pulse count).
    pub fn reading(&mut self, r: &Reading) {
        if r.is_gauge() {
            return;
        }
        let encoder = r.kind == crate::profile::ChannelKind::Encoder;
        let Some(h) = &mut self.inner else { return };
        let ch = h.channels.entry(r.channel.clone()).or_insert_with(|| {
            let f = &h.families;
            let l = [h.bus.as_str(), h.device.as_str(), &r.channel];
            ChannelMetrics {
                pulses: (!encoder).then(|| f.channel_pulses.with_label_values(&l)),
                position: encoder.then(|| f.channel_position.with_label_values(&l)),
                rate: f.channel_rate.with_label_values(&l),
            }
        });
        if let Some(c) = &ch.pulses {
            // The total of an input counting on its own never goes down; it starts from the
            // saved total after a restart.
            let total = r.update.total.max(0) as u64;
            if total > c.get() {
                c.inc_by(total - c.get());
            }
        }
        if let Some(g) = &ch.position {
            g.set(r.update.total);
        }
        if let Some(rate) = r.update.rate_hz {
            ch.rate.set(rate);
        }
    }
}

#[cfg(test)]
mod tests;

/// What one output's MQTT task records, sampled at its beat.
#[derive(Clone, Default)]
pub struct OutputMetrics {
    inner: Option<(Arc<Families>, String)>,
}

/// One beat's look at an output: its connection, hold, spool and chatter.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct OutputSample {
    pub connected: bool,
    pub held: bool,
    pub spool_messages: u64,
    pub spool_bytes: u64,
    /// Messages the spool dropped since start (its bound), and bytes it wrote to disk.
    pub spool_dropped: u64,
    pub spool_written: u64,
    /// Writes (or syncs) of spool files that failed, and spool lines that could not be read,
    /// since start.
    pub spool_write_failures: u64,
    pub spool_unreadable_lines: u64,
    pub chatter_waiting: usize,
    pub chatter_dropped: u64,
}

impl OutputMetrics {
    /// Records `s`; counters move by what they gained since the last sample.
    pub fn sample(&self, s: &OutputSample) {
        let Some((f, name)) = &self.inner else { return };
        let l = [name.as_str()];
        f.mqtt_connected
            .with_label_values(&l)
            .set(s.connected as i64);
        f.mqtt_held.with_label_values(&l).set(s.held as i64);
        f.spool_messages
            .with_label_values(&l)
            .set(s.spool_messages as i64);
        f.spool_bytes
            .with_label_values(&l)
            .set(s.spool_bytes as i64);
        f.chatter_messages
            .with_label_values(&l)
            .set(s.chatter_waiting as i64);
        for (counter, now) in [
            (&f.spool_dropped, s.spool_dropped),
            (&f.spool_written, s.spool_written),
            (&f.spool_write_failures, s.spool_write_failures),
            (&f.spool_unreadable_lines, s.spool_unreadable_lines),
            (&f.chatter_dropped, s.chatter_dropped),
        ] {
            let c = counter.with_label_values(&l);
            let seen = c.get();
            if now > seen {
                c.inc_by(now - seen);
            }
        }
    }

    /// An incoming message was dropped unread, for `reason` (`too_large`: over the largest
    /// packet the gateway takes).
    pub fn message_dropped(&self, reason: &'static str) {
        if let Some((f, name)) = &self.inner {
            f.messages_dropped
                .with_label_values(&[name.as_str(), reason])
                .inc();
        }
    }

    /// A server output answered a request of `function` with `result`.
    pub fn server_request(&self, function: u8, result: &str) {
        if let Some((f, name)) = &self.inner {
            let function = function.to_string();
            f.server_requests
                .with_label_values(&[name.as_str(), function.as_str(), result])
                .inc();
        }
    }

    /// The client connections a server output holds open.
    pub fn server_connections(&self, open: usize) {
        if let Some((f, name)) = &self.inner {
            f.server_connections
                .with_label_values(&[name.as_str()])
                .set(open as i64);
        }
    }

    /// A server output closed a client connection itself, for `reason`.
    pub fn server_closed(&self, reason: &'static str) {
        if let Some((f, name)) = &self.inner {
            f.server_closed
                .with_label_values(&[name.as_str(), reason])
                .inc();
        }
    }

    /// When the TLS certificate in `file` expires (seconds since the epoch).
    pub fn tls_expiry(&self, file: &str, not_after: i64) {
        if let Some((f, name)) = &self.inner {
            f.tls_expiry
                .with_label_values(&[name.as_str(), file])
                .set(not_after);
        }
    }

    /// The output's protocol events counted since start (see `Lifecycle::tallies`).
    pub fn tallies(&self, tallies: &[(&'static str, u64)]) {
        let Some((f, name)) = &self.inner else { return };
        for (event, now) in tallies {
            let c = f.output_events.with_label_values(&[name.as_str(), event]);
            let seen = c.get();
            if *now > seen {
                c.inc_by(now - seen);
            }
        }
    }

    /// Whether the spool fell back to a private temporary directory (see
    /// `publish::spool_place`).
    pub fn spool_fallback(&self, fallback: bool) {
        if let Some((f, name)) = &self.inner {
            f.spool_fallback
                .with_label_values(&[name])
                .set(fallback as i64);
        }
    }
}
