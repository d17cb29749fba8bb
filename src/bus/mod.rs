//! One task per bus: one transaction at a time, devices polled earliest deadline first, offline
//! devices probed with backoff so a silent one costs the others at most one timeout per probe.

mod availability;
pub mod device;
mod emit;
mod execute;
mod identity;
mod ledger;
pub mod link;
mod run;
mod saver;
pub mod schedule;
pub mod survey;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};
use tokio::sync::oneshot;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use crate::command::{CommandError, Request};
use crate::config::{Bus, Gateway};
use crate::health::Heart;
use crate::metrics::BusMetrics;
use crate::plan::Wire;
use crate::reading::Output;
use crate::state::{BusState, bus_path};
use device::DeviceRt;
pub use device::PollError;
use link::{Link, WireCounters};
use schedule::{Slot, earliest};

/// A checked command for a device on this bus, and where its outcome goes.
pub struct BusCommand {
    pub request: Request,
    pub done: oneshot::Sender<Result<Option<i64>, CommandError>>,
}

/// A running bus: its config and what it needs from the gateway.
pub struct BusTask {
    bus: Bus,
    state_path: PathBuf,
    state_flush: Duration,
    stats_interval: Duration,
    out: UnboundedSender<Output>,
    commands: UnboundedReceiver<BusCommand>,
    heart: Heart,
    metrics: BusMetrics,
    /// Scan requests from MQTT, asked in idle line time.
    scans: Option<tokio::sync::mpsc::Receiver<survey::ScanRequest>>,
    emitter: emit::Emitter,
}

impl BusTask {
    pub fn new(
        bus: Bus,
        gateway: &Gateway,
        out: UnboundedSender<Output>,
        commands: UnboundedReceiver<BusCommand>,
        heart: Heart,
    ) -> BusTask {
        BusTask {
            state_path: bus_path(&gateway.state_dir, &bus.name),
            state_flush: gateway.state_flush,
            stats_interval: gateway.stats_interval,
            emitter: emit::Emitter::new(gateway),
            bus,
            out,
            commands,
            heart,
            metrics: BusMetrics::default(),
            scans: None,
        }
    }

    /// Records into the gateway's metrics (without: into a registry nobody serves).
    pub fn with_metrics(mut self, metrics: BusMetrics) -> BusTask {
        self.metrics = metrics;
        self
    }

    /// Takes scan requests from `scans` (see [`survey`]).
    pub fn with_scans(mut self, scans: tokio::sync::mpsc::Receiver<survey::ScanRequest>) -> Self {
        self.scans = Some(scans);
        self
    }

    /// Polls until `shutdown`, then finishes the transaction in flight and saves state.
    /// Commands go ahead of polls: a poll gives way after its transaction in flight.
    pub async fn run(mut self, shutdown: CancellationToken) {
        let bus = &self.bus;
        let name: Arc<str> = Arc::from(bus.name.as_str());
        let Some(mut saved) = self.load_state(&name, &shutdown).await else {
            return;
        };
        let after_seq = if saved.clean {
            Default::default()
        } else {
            ledger::after_crash(&mut saved.channels)
        };
        let mut durable = saver::Durable::new(
            saver::Saver::new(self.state_path.clone(), name.clone()),
            after_seq,
        );
        let mut link = Link::new(bus.link.clone(), bus.guard);
        for d in &bus.devices {
            if let Some(baud) = d.baud {
                link.set_unit_baud(d.unit, baud);
            }
        }
        let wire = match link.timing() {
            Some(t) => Wire::rtu(&t, Duration::from_millis(2)),
            None => Wire::tcp(),
        };
        let mut devices: Vec<DeviceRt> = bus
            .devices
            .iter()
            .filter(|d| d.enabled)
            .map(|d| {
                DeviceRt::new(
                    bus,
                    d,
                    wire,
                    &saved.channels,
                    saved.holes_of(&crate::state::device_key(d.unit, &d.model)),
                )
                .with_metrics(self.metrics.device(&d.name))
            })
            .collect();
        let configured: Vec<_> = bus.devices.iter().map(|d| d.profile.clone()).collect();
        let known = identity::known(&configured);
        for d in &mut devices {
            d.known = known.clone();
        }
        durable.orphans = unclaimed(&name, &saved, &devices);

        let start = Instant::now();
        let mut slots: Vec<Slot> = devices
            .iter()
            .map(|d| Slot::new(start, d.config.poll))
            .collect();
        let mut flush_at = start + self.state_flush;
        let mut stats_at = start + self.stats_interval;
        let mut stats_since = start;
        let mut busy_at_stats = Duration::ZERO;
        let mut counters_at_stats = link::WireCounters::default();
        let mut line_down = false;
        tracing::info!(bus = %name, devices = devices.len(), "bus started");

        let mut pending: Vec<BusCommand> = Vec::new();
        // Polls due when the last command ended: they go before the next command, so a burst
        // of commands slows commands, never polling (each poll waits for at most one command).
        let mut owed: Option<Instant> = None;
        let mut scan: Option<survey::Survey> = None;
        let configured: Vec<u8> = bus.devices.iter().map(|d| d.unit).collect();
        let stall = stall_hook(&bus.name);
        while let Some(i) = earliest(&slots) {
            self.heart.beat();
            if stall.is_some_and(|at| start.elapsed() >= at) {
                tracing::error!(bus = %name, "test hook: this bus loop now stalls");
                shutdown.cancelled().await;
                break;
            }
            while let Ok(c) = self.commands.try_recv() {
                pending.push(c);
            }
            let poll_owed = owed.is_some_and(|at| slots[i].due <= at);
            durable.collect(&devices, &self.out).await;
            if !poll_owed {
                owed = None;
                if let Some((from, readings)) =
                    run_one_command(&mut pending, &mut devices, &mut link).await
                {
                    let outputs = self.emitter.emit(&mut devices[from], readings);
                    durable.publish(outputs, from, &devices, &self.out);
                    owed = Some(Instant::now());
                    continue;
                }
            }
            let idle_until = slots[i].due;
            if !poll_owed
                && survey::idle_step(
                    &mut scan,
                    &mut self.scans,
                    &mut link,
                    idle_until,
                    &configured,
                    &name,
                    &self.out,
                    &shutdown,
                )
                .await
            {
                continue;
            }
            let expiry = pending.iter().map(|c| c.request.expires).min();
            // Wake at least every second so the heart beats while the devices are slow.
            // Held readings are released as soon as their save is done.
            let soon = if durable.holding() { 20 } else { 1000 };
            let wake = slots[i]
                .due
                .min(Instant::now() + Duration::from_millis(soon))
                .min(flush_at)
                .min(stats_at)
                .min(expiry.unwrap_or(flush_at));
            tokio::select! {
                biased;
                () = shutdown.cancelled() => break,
                Some(c) = self.commands.recv(), if !poll_owed => {
                    pending.push(c);
                    continue;
                }
                () = tokio::time::sleep_until(wake) => {}
            }
            let now = Instant::now();
            if now >= flush_at {
                durable
                    .saver
                    .start(snapshot(&devices, &durable.orphans, false));
                flush_at = now + self.state_flush;
            }
            if now >= stats_at {
                let wall = now - stats_since;
                let stats = stats_json(
                    &link,
                    &counters_at_stats,
                    &devices,
                    &slots,
                    wall,
                    link.busy - busy_at_stats,
                );
                counters_at_stats = link.counters;
                tracing::info!(bus = %name, %stats, "bus stats");
                self.metrics
                    .utilisation(stats["utilisation"].as_f64().unwrap_or(0.0));
                let _ = self.out.send(Output::BusStats {
                    bus: name.clone(),
                    stats,
                });
                stats_since = now;
                busy_at_stats = link.busy;
                stats_at = now + self.stats_interval;
            }
            if slots[i].due > now {
                continue;
            }
            let d = &mut devices[i];
            let commands = &self.commands;
            // A poll owed after a command runs to its end; otherwise it gives way to a command.
            let before = link.counters;
            let result = d
                .poll(&mut link, &|| !poll_owed && !commands.is_empty())
                .await;
            d.metrics.wire(&before, &link.counters);
            self.metrics.wire(&link.counters, link.busy);
            let now = Instant::now();
            match result {
                Err(e) if e.is_preempted() => continue,
                Ok(readings) => {
                    if std::mem::take(&mut line_down) {
                        tracing::info!(bus = %name, "line is answering again");
                        // Devices that went offline with the line are probed at once.
                        for (j, other) in devices.iter_mut().enumerate() {
                            if other.availability.line_back() {
                                slots[j].defer_to(now);
                            }
                        }
                    }
                    self.heart.set_up(true);
                    let d = &mut devices[i];
                    availability::answered(d, &name, &self.out);
                    availability::mode_mismatch(d, &self.out);
                    let outputs = self.emitter.emit(d, readings);
                    durable.publish(outputs, i, &devices, &self.out);
                    slots[i].advance(now);
                }
                Err(PollError::WrongModel(why)) => {
                    availability::wrong_model(d, why, &name, &self.out);
                    slots[i].defer_to(now + bus.backoff_max);
                }
                Err(e) => {
                    let line_fault = matches!(&e, PollError::Link(l) if l.is_line_fault());
                    self.heart.set_up(!line_fault);
                    if line_fault && !std::mem::replace(&mut line_down, true) {
                        tracing::error!(bus = %name, "line fault: {e}");
                        self.metrics.line_fault();
                    }
                    match availability::failed(d, &e, line_fault, &name, &self.out) {
                        Some(wait) => slots[i].defer_to(now + wait),
                        None => slots[i].advance(now),
                    }
                }
            }
            devices[i].metrics.up(devices[i].online());
        }
        if durable.finish(&devices, &self.out).await {
            tracing::info!(bus = %name, "state saved");
        }
        for d in &devices {
            if d.online() == Some(true) {
                let _ = self.out.send(Output::DeviceStatus {
                    device: d.name.clone(),
                    online: false,
                });
            }
        }
        link.close();
    }
}

impl BusTask {
    /// Loads the bus's state off the runtime thread. A state file that cannot be trusted (moved
    /// aside, see [`crate::state`]) halts the bus with a clear log and status until shutdown:
    /// it does not start from zero totals on a guess.
    async fn load_state(&self, name: &Arc<str>, shutdown: &CancellationToken) -> Option<BusState> {
        let path = self.state_path.clone();
        let loaded = tokio::task::spawn_blocking(move || BusState::load(&path)).await;
        let error = match loaded {
            Ok(Ok(s)) => return Some(s),
            Ok(Err(e)) => e.to_string(),
            Err(e) => format!("state load task failed: {e}"),
        };
        tracing::error!(bus = %name, "{error}");
        tracing::error!(bus = %name, "bus not started: its counter state cannot be trusted");
        self.heart
            .set_problem(Some("state file refused, not polling (see the log)".into()));
        self.heart.set_up(false);
        loop {
            self.heart.beat();
            tokio::select! {
                () = shutdown.cancelled() => return None,
                () = tokio::time::sleep(Duration::from_secs(1)) => {}
            }
        }
    }
}

/// Fault injection for the watchdog test: `PULSEGATE_TEST_STALL_BUS=<bus>:<seconds>` makes that
/// bus loop stop making progress after so long, as a stuck loop would.
fn stall_hook(bus: &str) -> Option<Duration> {
    let v = std::env::var("PULSEGATE_TEST_STALL_BUS").ok()?;
    let (name, secs) = v.split_once(':')?;
    (name == bus).then(|| Duration::from_secs_f64(secs.parse().unwrap_or(0.0)))
}

/// Carries out the first pending command whose device can take it (one command, so polls get
/// the line between commands); answers expired ones with `offline`; keeps the rest waiting for
/// their device. Returns the device and readings of the command that went on the line, if one
/// did.
async fn run_one_command(
    pending: &mut Vec<BusCommand>,
    devices: &mut [DeviceRt],
    link: &mut Link,
) -> Option<(usize, Vec<crate::reading::Reading>)> {
    let now = Instant::now();
    let mut waiting = Vec::new();
    let mut ran = None;
    for c in pending.drain(..) {
        let Some((i, d)) = devices
            .iter_mut()
            .enumerate()
            .find(|(_, d)| *d.name == c.request.device)
        else {
            let _ = c
                .done
                .send(Err(CommandError::UnknownDevice(c.request.device.clone())));
            continue;
        };
        if ran.is_none() && d.online() == Some(true) && d.discovered() {
            let before = link.counters;
            let executed = d.execute(link, &c.request).await;
            d.metrics.wire(&before, &link.counters);
            ran = Some((i, executed.readings));
            if let Err(e) = &executed.result {
                tracing::warn!(device = %d.name, op = c.request.op.name(), "command failed: {e}");
            } else {
                tracing::info!(device = %d.name, channel = ?c.request.channel, op = c.request.op.name(), "command carried out");
            }
            let _ = c.done.send(executed.result);
        } else if now >= c.request.expires {
            let _ = c
                .done
                .send(Err(CommandError::Offline(c.request.device.clone())));
        } else {
            waiting.push(c);
        }
    }
    *pending = waiting;
    ran
}

/// The bus's state now: every device's, plus the saved state no configured device claims
/// (kept, never attached to another meter); `clean` only for the save after the last reading
/// at shutdown.
fn snapshot(devices: &[DeviceRt], orphans: &BusState, clean: bool) -> BusState {
    let mut s = BusState {
        clean,
        ..orphans.clone()
    };
    for d in devices {
        s.channels.extend(d.counter_states());
        if !d.holes.is_empty() {
            s.holes.insert(
                d.holes_key(),
                d.holes.iter().map(|h| (h.start, h.end)).collect(),
            );
        }
    }
    s
}

/// Saved state that no configured (and enabled) device can have: kept as it is, so a device
/// taken out of the config or disabled resumes its total, with a gap, when it comes back.
/// `pulsegate state prune` removes it.
fn unclaimed(bus: &str, saved: &BusState, devices: &[DeviceRt]) -> BusState {
    let claimed: std::collections::BTreeSet<String> = devices
        .iter()
        .flat_map(|d| d.counter_states().into_keys())
        .collect();
    let holes: std::collections::BTreeSet<String> = devices.iter().map(|d| d.holes_key()).collect();
    let mut out = BusState::default();
    for (key, state) in &saved.channels {
        if !claimed.contains(key) {
            tracing::info!(bus, channel = %key, total = state.total, "saved counter state matches no configured device; kept for when it comes back");
            out.channels.insert(key.clone(), state.clone());
        }
    }
    for (key, h) in &saved.holes {
        if !holes.contains(key) {
            out.holes.insert(key.clone(), h.clone());
        }
    }
    out
}

fn percentile(sorted: &[f64], p: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let idx = ((sorted.len() - 1) as f64 * p).round() as usize;
    Some(sorted[idx])
}

/// Bus health since the last report (`since`: the counters then).
fn stats_json(
    link: &Link,
    since: &WireCounters,
    devices: &[DeviceRt],
    slots: &[Slot],
    wall: Duration,
    busy: Duration,
) -> serde_json::Value {
    let c = link.counters;
    let mut per_device = BTreeMap::new();
    for (d, s) in devices.iter().zip(slots) {
        let mut lat: Vec<f64> = d.latencies.iter().copied().collect();
        lat.sort_by(f64::total_cmp);
        per_device.insert(
            d.name.to_string(),
            serde_json::json!({
                "online": d.online(),
                "poll_ms": d.config.poll.as_secs_f64() * 1000.0,
                "achieved_poll_ms": d.achieved_interval.map(|v| v * 1000.0),
                "missed": s.missed,
                "turnaround_ms": d.turnaround().map(|v| v * 1000.0),
                "latency_p50_ms": percentile(&lat, 0.5).map(|v| v * 1000.0),
                "latency_p99_ms": percentile(&lat, 0.99).map(|v| v * 1000.0),
                "last_error": d.availability.last_error(),
            }),
        );
    }
    serde_json::json!({
        "utilisation": busy.as_secs_f64() / wall.as_secs_f64().max(1e-9),
        "transactions": c.transactions,
        "transactions_per_s": (c.transactions - since.transactions) as f64 / wall.as_secs_f64().max(1e-9),
        "timeouts": c.timeouts,
        "garbled": c.garbled,
        "stale_dropped": c.mismatches,
        "io_errors": c.io_errors,
        "exceptions": c.exceptions,
        "reconnects": c.reconnects,
        "devices": per_device,
    })
}
