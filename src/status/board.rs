//! The status board: every event the gateway hands its outputs comes in here too, and a
//! snapshot goes out, as the status page and `/api/v1/status` show it. Pure: events and the
//! time in, values out; what the running gateway measures (its loops' health, the metrics'
//! counters) is handed to [`Board::status`] as [`Measured`].
//!
//! Bounded: the devices of the config in force (events of others are left out), at most
//! [`MAX_CHANNELS`] channels each (a profile has at most 16), a fixed 15-minute rate history
//! per channel, the last 100 events, one scan.

use std::collections::BTreeMap;

use super::history::{BUCKET_MS, History};
use super::log::{self, Log};
use super::view::*;
use crate::bus_health::BusStats;
use crate::config::{Config, Device};
use crate::health::{Loop, LoopView};
use crate::metering::{Clock, Period, Record};
use crate::metrics::{BusLook, DeviceLook};
use crate::outcome::Outcome;
use crate::reading::{Output, Reading, unix_ms};

/// Channels kept per device.
pub const MAX_CHANNELS: usize = 64;
/// A scan's report stays on the board this long after it ended.
const SCAN_SHOWN_MS: u64 = 10 * 60 * 1000;

/// What the running gateway measured, handed in when a snapshot is made.
#[derive(Debug, Clone, Default)]
pub struct Measured {
    pub uptime_s: u64,
    /// Every loop (`bus/<name>`, `output/<name>`).
    pub loops: Vec<LoopView>,
    /// By device name.
    pub devices: BTreeMap<String, DeviceLook>,
    /// By bus name.
    pub buses: BTreeMap<String, BusLook>,
}

/// The gateway's events, kept for the page.
#[derive(Debug)]
pub struct Board {
    gateway: GatewayView,
    clock: Clock,
    intervals: Option<Vec<Period>>,
    /// Enabled buses in name order: name and link.
    buses: Vec<(String, String)>,
    /// Outputs by name: format, broker, spool bound.
    outputs: BTreeMap<String, (Option<String>, String, u64)>,
    /// Devices in bus and name order.
    devices: Vec<DeviceEntry>,
    stats: BTreeMap<String, (u64, BusStats)>,
    log: Log,
    scan: Option<ScanView>,
}

#[derive(Debug)]
struct DeviceEntry {
    bus: String,
    config: Device,
    status: Option<(String, u64)>,
    channels: Vec<ChannelEntry>,
}

#[derive(Debug)]
struct ChannelEntry {
    last: Reading,
    history: History,
    intervals: Vec<Progress>,
}

/// An interval in progress.
#[derive(Debug)]
struct Progress {
    period: Period,
    start_ms: i64,
    delta: i64,
    last: Option<ClosedView>,
}

impl Board {
    /// A board for `config`, started at `started_ms`.
    pub fn new(config: &Config, started_ms: u64) -> Board {
        let mut b = Board {
            gateway: GatewayView {
                id: String::new(),
                version: env!("CARGO_PKG_VERSION").to_string(),
                started_ms,
                uptime_s: 0,
                config_file: String::new(),
                config_hash: String::new(),
            },
            clock: config.gateway.clock.clone(),
            intervals: None,
            buses: Vec::new(),
            outputs: BTreeMap::new(),
            devices: Vec::new(),
            stats: BTreeMap::new(),
            log: Log::default(),
            scan: None,
        };
        b.reconfigure(config);
        b
    }

    /// The config in force changed (a reload): devices that stay keep what the board knows of
    /// them; others are forgotten.
    pub fn reconfigure(&mut self, config: &Config) {
        self.gateway.id = config.gateway.id.clone();
        self.gateway.config_file = config.source.display().to_string();
        self.gateway.config_hash = config.hash().to_string();
        self.clock = config.gateway.clock.clone();
        self.intervals = config.gateway.intervals.clone();
        self.buses = config
            .buses
            .iter()
            .filter(|b| b.enabled)
            .map(|b| (b.name.clone(), b.link.to_string()))
            .collect();
        self.outputs = outputs(config);
        let mut old: BTreeMap<String, DeviceEntry> = std::mem::take(&mut self.devices)
            .into_iter()
            .map(|d| (d.config.name.clone(), d))
            .collect();
        for (bus, d) in config.enabled_devices() {
            let mut entry = old.remove(&d.name).unwrap_or_else(|| DeviceEntry {
                bus: bus.name.clone(),
                config: d.clone(),
                status: None,
                channels: Vec::new(),
            });
            if entry.config != *d || entry.bus != bus.name {
                entry.channels.clear();
            }
            entry.bus = bus.name.clone();
            entry.config = d.clone();
            self.devices.push(entry);
        }
        self.stats
            .retain(|bus, _| self.buses.iter().any(|(b, _)| b == bus));
    }

    /// One event, as it passes to the outputs.
    pub fn hand(&mut self, event: &Output, now_ms: u64) {
        match event {
            Output::DeviceReadings { readings, .. } => {
                readings.iter().for_each(|r| self.reading(r))
            }
            Output::DeviceStatus { device, online } => {
                let status = if *online { "online" } else { "offline" };
                self.device_status(device, status, now_ms);
            }
            Output::DeviceProblem { device, status } => self.device_status(device, status, now_ms),
            Output::BusStats { bus, stats } => {
                if self.buses.iter().any(|(b, _)| **b == **bus) {
                    self.stats
                        .insert(bus.to_string(), (now_ms, (**stats).clone()));
                }
            }
            Output::CommandResult { outcome, .. } => self.outcome(outcome, now_ms),
            Output::ScanProgress { progress, .. } => self.scan_progress(progress, now_ms),
            Output::Interval(record) => self.interval(
                &record.device,
                &record.channel,
                &record.period,
                &record.record,
            ),
            Output::Checkpoint(_) => {}
        }
    }

    /// Every device as (bus, device), in bus and name order.
    pub fn devices(&self) -> Vec<(String, String)> {
        self.devices
            .iter()
            .map(|d| (d.bus.clone(), d.config.name.clone()))
            .collect()
    }

    fn device(&mut self, name: &str) -> Option<&mut DeviceEntry> {
        self.devices.iter_mut().find(|d| d.config.name == name)
    }

    fn device_status(&mut self, device: &str, status: &str, now_ms: u64) {
        let Some(d) = self.device(device) else { return };
        if d.status.as_ref().is_some_and(|(s, _)| s == status) {
            return;
        }
        d.status = Some((status.to_string(), now_ms));
        self.log.push(EventView {
            at_ms: now_ms,
            kind: "device",
            device: Some(device.to_string()),
            channel: None,
            text: log::status_text(status),
        });
    }

    fn reading(&mut self, r: &Reading) {
        let (clock, gateway) = (self.clock.clone(), self.intervals.clone());
        let Some(d) = self.device(&r.device) else {
            return;
        };
        let at = unix_ms(r.ts) as i64;
        let i = match d.channels.iter().position(|c| c.last.channel == r.channel) {
            Some(i) => i,
            None if d.channels.len() < MAX_CHANNELS => {
                let periods = d.config.intervals_of(gateway.as_deref(), &r.channel);
                d.channels.push(ChannelEntry {
                    last: r.clone(),
                    history: History::new(at),
                    intervals: periods
                        .iter()
                        .map(|p| Progress::new(p, &clock, at))
                        .collect(),
                });
                d.channels.len() - 1
            }
            None => return,
        };
        let c = &mut d.channels[i];
        c.last = r.clone();
        c.history.add(at, r.update.delta);
        for p in &mut c.intervals {
            p.add(&clock, at, r.update.delta);
        }
        if let Some(event) = r.update.event {
            let (device, channel) = (r.device.to_string(), r.channel.to_string());
            self.log.push(EventView {
                at_ms: at as u64,
                kind: "channel",
                device: Some(device),
                channel: Some(channel),
                text: log::channel_text(event).to_string(),
            });
        }
    }

    fn interval(&mut self, device: &str, channel: &str, period: &str, record: &Record) {
        let clock = self.clock.clone();
        let Some(d) = self.device(device) else { return };
        let Some(c) = d.channels.iter_mut().find(|c| &*c.last.channel == channel) else {
            return;
        };
        if let Some(p) = c.intervals.iter_mut().find(|p| p.period.text() == period) {
            p.closed(&clock, record);
        }
    }

    fn outcome(&mut self, outcome: &Outcome, now_ms: u64) {
        let (kind, text) = match outcome {
            Outcome::Command(c) => ("command", log::command_text(c)),
            Outcome::Scan(s) => {
                if let crate::outcome::ScanOutcome::Report(r) = s {
                    self.scan = Some(ScanView {
                        bus: r.bus.clone(),
                        id: r.id.clone(),
                        running: false,
                        asked: r.asked,
                        pending: 0,
                        elapsed_ms: r.elapsed_ms,
                        found: r.found.clone(),
                        updated_ms: now_ms,
                    });
                }
                ("scan", log::scan_text(s))
            }
            Outcome::Config(c) => {
                let what = match c.error {
                    None => format!("pushed config {}", c.status),
                    Some(e) => format!("pushed config {}: {e}", c.status),
                };
                ("config", format!("{what}: {}", c.message))
            }
        };
        self.log.push(EventView {
            at_ms: now_ms,
            kind,
            device: None,
            channel: None,
            text,
        });
    }

    fn scan_progress(&mut self, p: &crate::outcome::ScanProgress, now_ms: u64) {
        let same = self
            .scan
            .as_ref()
            .is_some_and(|s| s.running && s.bus == p.bus && s.id == p.id);
        let mut found = if same {
            self.scan.take().map(|s| s.found).unwrap_or_default()
        } else {
            Vec::new()
        };
        if !found
            .iter()
            .any(|f| f.unit == p.found.unit && f.baud == p.found.baud)
        {
            found.push(p.found.clone());
        }
        let model = p.found.model.as_deref().unwrap_or("an unknown model");
        self.log.push(EventView {
            at_ms: now_ms,
            kind: "scan",
            device: None,
            channel: None,
            text: format!(
                "scan of bus {}: unit {} answers, {model}",
                p.bus, p.found.unit
            ),
        });
        self.scan = Some(ScanView {
            bus: p.bus.clone(),
            id: p.id.clone(),
            running: p.pending > 0,
            asked: p.asked,
            pending: p.pending,
            elapsed_ms: p.elapsed_ms,
            found,
            updated_ms: now_ms,
        });
    }
}

impl Board {
    /// The snapshot at `now_ms`, with what the running gateway `measured`.
    pub fn status(&self, now_ms: u64, measured: &Measured) -> Status {
        let loop_of = |of: &Loop| measured.loops.iter().find(|l| l.of == *of);
        let mut gateway = self.gateway.clone();
        gateway.uptime_s = measured.uptime_s;
        let outputs = measured
            .loops
            .iter()
            .filter_map(|l| match &l.of {
                Loop::Output(name) => Some(self.output_view(name, l)),
                Loop::Bus(_) => None,
            })
            .collect();
        let buses = self
            .buses
            .iter()
            .map(|(name, link)| {
                let l = loop_of(&Loop::Bus(name.clone()));
                let look = measured.buses.get(name).copied().unwrap_or_default();
                BusView {
                    name: name.clone(),
                    link: link.clone(),
                    up: l.is_some_and(|l| l.up),
                    problem: l.and_then(|l| l.problem.clone()),
                    transactions: look.transactions,
                    reconnects: look.reconnects,
                    line_faults: look.line_faults,
                    stats: self.stats.get(name).map(|(at, s)| bus_stats_view(*at, s)),
                }
            })
            .collect();
        let devices = self
            .devices
            .iter()
            .map(|d| self.device_view(d, measured.devices.get(&d.config.name), now_ms))
            .collect();
        let scan = self
            .scan
            .clone()
            .filter(|s| s.running || now_ms.saturating_sub(s.updated_ms) < SCAN_SHOWN_MS);
        Status {
            api: 1,
            now_ms,
            gateway,
            outputs,
            buses,
            devices,
            events: self.log.newest_first(),
            scan,
        }
    }

    fn output_view(&self, name: &str, l: &LoopView) -> OutputView {
        let (format, broker, limit) = self.outputs.get(name).cloned().unwrap_or_default();
        OutputView {
            name: name.to_string(),
            format,
            broker,
            connected: l.up,
            held: l.held.clone(),
            down_s: l.down_for_ms.map(|ms| ms as f64 / 1000.0),
            spooling: l.spool_messages > 0,
            spool_messages: l.spool_messages,
            spool_bytes: l.spool_bytes,
            spool_limit_bytes: limit,
            last_error: l.last_error.as_ref().map(|e| e.0.clone()),
            last_error_ms: l.last_error.as_ref().map(|e| e.1),
            problem: l.problem.clone(),
        }
    }

    fn device_view(&self, d: &DeviceEntry, look: Option<&DeviceLook>, now_ms: u64) -> DeviceView {
        let look = look.copied().unwrap_or_default();
        let stats = self
            .stats
            .get(&d.bus)
            .and_then(|(_, s)| s.devices.get(&d.config.name));
        DeviceView {
            name: d.config.name.clone(),
            bus: d.bus.clone(),
            unit: d.config.unit,
            address: address(&d.config),
            model: d.config.model.clone(),
            status: d
                .status
                .as_ref()
                .map_or("unknown", |s| s.0.as_str())
                .to_string(),
            status_since_ms: d.status.as_ref().map(|s| s.1),
            poll_ms: d.config.poll.as_millis() as u64,
            last_answer_ms: look.last_answer_ms,
            latency_ms: look.last_latency_ms.map(milli),
            mean_latency_ms: look.mean_latency_ms.map(milli),
            latency_p50_ms: stats.and_then(|s| s.latency_p50_ms),
            latency_p99_ms: stats.and_then(|s| s.latency_p99_ms),
            transactions: look.transactions,
            timeouts: look.timeouts,
            garbled: look.garbled,
            exceptions: look.exceptions,
            missed: stats.map(|s| s.missed),
            last_error: stats.and_then(|s| s.last_error.clone()),
            request: stats.and_then(|s| {
                Some(RequestView {
                    limit: s.request_limit?,
                    requests_per_poll: s.requests_per_poll?,
                    longest: s.longest_request?,
                })
            }),
            channels: d
                .channels
                .iter()
                .map(|c| channel_view(c, &self.clock, now_ms))
                .collect(),
        }
    }
}

fn bus_stats_view(at_ms: u64, s: &BusStats) -> BusStatsView {
    BusStatsView {
        at_ms,
        utilisation: s.utilisation,
        transactions_per_s: s.transactions_per_s,
        timeouts: s.timeouts,
        garbled: s.garbled,
        stale_dropped: s.stale_dropped,
        io_errors: s.io_errors,
        exceptions: s.exceptions,
        reconnects: s.reconnects,
    }
}

impl Progress {
    fn new(period: &Period, clock: &Clock, at_ms: i64) -> Progress {
        Progress {
            period: period.clone(),
            start_ms: clock.floor(period, at_ms),
            delta: 0,
            last: None,
        }
    }

    /// A reading's delta at `at_ms`: a reading in a later period starts it afresh.
    fn add(&mut self, clock: &Clock, at_ms: i64, delta: i64) {
        let start = clock.floor(&self.period, at_ms);
        if start > self.start_ms {
            self.start_ms = start;
            self.delta = 0;
        }
        self.delta += delta;
    }

    fn closed(&mut self, clock: &Clock, r: &Record) {
        self.last = Some(ClosedView {
            start_ms: r.start_ms,
            end_ms: r.end_ms,
            delta: r.delta,
            status: r.status,
        });
        let start = clock.floor(&self.period, r.end_ms);
        if start > self.start_ms {
            self.start_ms = start;
            self.delta = 0;
        }
    }

    fn view(&self, clock: &Clock) -> IntervalView {
        IntervalView {
            period: self.period.text().to_string(),
            start_ms: self.start_ms,
            end_ms: clock.next(&self.period, self.start_ms),
            delta: self.delta,
            last: self.last.clone(),
        }
    }
}

/// Every connection of `config` by name: format, broker and spool bound.
fn outputs(config: &Config) -> BTreeMap<String, (Option<String>, String, u64)> {
    use crate::config::outputs::{VOICE_NAME, VoiceHome};
    let mut out: BTreeMap<_, _> = config
        .outputs
        .list
        .iter()
        .map(|o| {
            let value = (
                Some(o.kind.to_string()),
                o.mqtt.broker(),
                o.mqtt.spool_bytes,
            );
            (o.name.clone(), value)
        })
        .collect();
    if config.outputs.voice == VoiceHome::Own {
        let m = &config.mqtt;
        out.insert(VOICE_NAME.to_string(), (None, m.broker(), m.spool_bytes));
    }
    for (name, kind, listen) in config.outputs.servers() {
        out.insert(name.to_string(), (Some(kind.to_string()), listen, 0));
    }
    out
}

/// Where `device` is on its bus, as a person says it.
fn address(device: &crate::config::Device) -> String {
    device.address.to_string()
}

/// `v` to three decimals: a chart needs no more, and the answer stays short.
fn milli(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// A channel's last reading, history and intervals as the API shows them.
fn channel_view(c: &ChannelEntry, clock: &Clock, now_ms: u64) -> ChannelView {
    let r = &c.last;
    let units = r.units.as_deref();
    ChannelView {
        name: r.channel.to_string(),
        kind: match (&r.measured, r.kind) {
            (Some(_), _) => "gauge",
            (None, crate::profile::ChannelKind::Encoder) => "encoder",
            (None, crate::profile::ChannelKind::Counter) => "counter",
        },
        count: r.count,
        total: r.update.total,
        delta: r.update.delta,
        seq: r.update.seq,
        rate_hz: r.update.rate_hz,
        event: r.update.event,
        at_ms: unix_ms(r.ts),
        unit: units.and_then(|u| u.unit.clone()),
        value: match &r.measured {
            Some(m) => Some(m.to_string()),
            None => units
                .and_then(|u| crate::config::units::value(u, r.update.total))
                .map(|v| v.to_string()),
        },
        rate_unit: units.and_then(|u| u.rate_unit.clone()),
        rate: units
            .zip(r.update.rate_hz)
            .and_then(|(u, hz)| crate::config::units::rate(u, hz)),
        history: HistoryView {
            bucket_s: (BUCKET_MS / 1000) as u64,
            end_ms: History::end_ms(now_ms as i64) as u64,
            rates: c
                .history
                .rates(now_ms as i64)
                .into_iter()
                .map(|r| r.map(milli))
                .collect(),
        },
        intervals: c.intervals.iter().map(|p| p.view(clock)).collect(),
    }
}
