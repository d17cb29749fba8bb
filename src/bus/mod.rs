//! One task per bus: one transaction at a time, devices polled earliest deadline first, offline
//! devices probed with backoff so a silent one costs the others at most one timeout per probe.

mod availability;
mod book;
pub mod device;
pub mod driver;
mod durable;
mod emit;
mod ledger;
mod meter;
mod saver;
pub mod schedule;
#[cfg(feature = "test-hooks")]
mod stall;
pub mod stats;
mod status;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};
use tokio::sync::oneshot;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use crate::bus_health::WireCounters;
use crate::command::{CommandError, Request};
use crate::config::{Bus, Gateway};
use crate::health::Heart;
use crate::metrics::BusMetrics;
use crate::reading::Output;
use crate::state::{BusState, bus_path};
use device::DeviceRt;
pub use device::PollError;
use driver::{DeviceState, Driver};
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
        }
    }

    /// Records into the gateway's metrics (without: into a registry nobody serves).
    pub fn with_metrics(mut self, metrics: BusMetrics) -> BusTask {
        self.metrics = metrics;
        self
    }

    /// Polls over `driver` (the bus's protocol, built by the caller; a scripted one in tests)
    /// until `shutdown`, then finishes the transaction in flight and saves state.
    /// Commands go ahead of polls: a poll gives way after its transaction in flight.
    pub async fn run<D: Driver>(self, driver: D, shutdown: CancellationToken) {
        // The watchdog test's stall is a driver around the real one, not a step of the loop.
        #[cfg(feature = "test-hooks")]
        let driver = stall::Stalling::wrap(driver, &self.bus.name, &shutdown);
        self.serve(driver, shutdown).await;
    }

    /// The poll loop of [`BusTask::run`].
    async fn serve<D: Driver>(mut self, driver: D, shutdown: CancellationToken) {
        let Some(mut core) = self.start(driver, &shutdown).await else {
            return;
        };
        while let Some(i) = earliest(&core.slots, Instant::now(), core.after_boundary) {
            self.heart.beat();
            match self.between_polls(&mut core, i, &shutdown).await {
                Next::Loop => continue,
                Next::Stop => break,
                Next::Poll => {}
            }
            core.after_boundary = core.slots[i].boundary_due(Instant::now());
            let commands = &self.commands;
            let owed = core.poll_owed;
            // A poll owed after a command runs to its end; otherwise it gives way to a command.
            let before = core.driver.wire().0;
            let d = &mut core.devices[i];
            let result = core.driver.poll(d, &|| !owed && !commands.is_empty()).await;
            // The core counts: the samples become readings here, for every protocol alike.
            let result = result.map(|samples| d.book_poll(samples));
            let (counters, busy) = core.driver.wire();
            d.metrics.wire(&before, &counters);
            self.metrics.wire(&counters, busy);
            self.after_poll(&mut core, i, result);
            let d = &core.devices[i];
            d.metrics.up(d.online());
        }
        self.finish(core).await;
    }

    /// Loads the state and builds the devices, their slots and the driver.
    async fn start<D: Driver>(
        &mut self,
        driver: D,
        shutdown: &CancellationToken,
    ) -> Option<Core<D>> {
        let bus = &self.bus;
        let name: Arc<str> = Arc::from(bus.name.as_str());
        let mut saved = self.load_state(&name, shutdown).await?;
        let unsent = durable::take_unsent(&mut saved.channels);
        let resume = ledger::resume(&mut saved.channels, !saved.clean);
        let mut durable = durable::Durable::new(
            saver::Saver::new(self.state_path.clone(), name.clone()),
            &saved.channels,
            resume,
        );
        if saved.clean {
            durable.trust(&saved);
        }
        let devices: Vec<DeviceRt<D::Device>> = bus
            .devices
            .iter()
            .filter(|d| d.enabled)
            .map(|d| {
                DeviceRt::new(bus, d, &saved.channels, driver.device(bus, d, &saved))
                    .with_metrics(self.metrics.device(&d.name))
            })
            .collect();
        durable.orphans = unclaimed(&name, &saved, &devices);
        tracing::info!(bus = %name, devices = devices.len(), "bus started");
        let mut core = Core::new(
            name,
            driver,
            devices,
            durable,
            self.state_flush,
            self.stats_interval,
        );
        self.resend(&mut core, unsent);
        Some(core)
    }

    /// Sends again the interval records the state file held as unsent (a crash came between
    /// their save and their hand-over to the MQTT side): same seq, same content, before
    /// anything of this run; a consumer that has one already knows it by its seq.
    fn resend<D: Driver>(&mut self, core: &mut Core<D>, mut unsent: durable::Unsent) {
        for from in 0..core.devices.len() {
            let d = &core.devices[from];
            let prefix = d.channel_key("");
            let mut outputs = Vec::new();
            for key in unsent
                .keys()
                .filter(|k| k.starts_with(&prefix))
                .cloned()
                .collect::<Vec<_>>()
            {
                for (period, record) in unsent.remove(&key).unwrap_or_default() {
                    outputs.push(
                        self.emitter
                            .record(d, &key[prefix.len()..], &period, record),
                    );
                }
            }
            if !outputs.is_empty() {
                tracing::info!(bus = %core.name, device = %d.name, records = outputs.len(), "interval records saved but not sent before a crash: sent again");
                core.durable
                    .publish(outputs, from, &core.devices, &self.out);
            }
        }
        let lost: usize = unsent.values().map(Vec::len).sum();
        if lost > 0 {
            tracing::warn!(bus = %core.name, records = lost, "interval records of devices no longer configured were not sent before a crash: dropped");
        }
    }

    /// Between polls: commands (one at a time), idle-time scans, the state flush and the bus
    /// stats; then waits for the next poll. `Next::Poll` when device `i` is due now.
    async fn between_polls<D: Driver>(
        &mut self,
        core: &mut Core<D>,
        i: usize,
        shutdown: &CancellationToken,
    ) -> Next {
        while let Ok(c) = self.commands.try_recv() {
            core.pending.push(c);
        }
        // After a command, polls that are due go first for as long as the command held the
        // line: commands and polls share a busy line at least half and half, so a burst of
        // commands slows polling at most by half, and a lone command waits for one poll at most
        // (not for every device that is overdue on a saturated line).
        let now = Instant::now();
        core.poll_owed = core
            .owed
            .is_some_and(|until| now < until && core.slots[i].next_at() <= now);
        core.durable.collect(&core.devices, &self.out).await;
        if !core.poll_owed {
            core.owed = None;
            // A meter reading set now is saved at once, not at the next periodic flush.
            let op = |c: &BusCommand| matches!(c.request.op, crate::command::Op::SetReading(_));
            if core.pending.iter().any(op) {
                core.flush_at = Instant::now();
            }
            let started = Instant::now();
            if let Some((from, readings)) =
                run_one_command(&mut core.pending, &mut core.devices, &mut core.driver).await
            {
                let held = started.elapsed();
                let outputs = self.emitter.emit(&mut core.devices[from], readings);
                core.durable
                    .publish(outputs, from, &core.devices, &self.out);
                core.owed = Some(Instant::now() + held);
                return Next::Loop;
            }
            let idle = driver::Idle {
                until: core.slots[i].next_at(),
                bus: &core.name,
                out: &self.out,
                shutdown,
            };
            if core.driver.idle(idle).await {
                return Next::Loop;
            }
        }
        let wake = core.wake(i);
        tokio::select! {
            biased;
            () = shutdown.cancelled() => return Next::Stop,
            Some(c) = self.commands.recv(), if !core.poll_owed => {
                core.pending.push(c);
                return Next::Loop;
            }
            () = tokio::time::sleep_until(wake) => {}
        }
        self.after_wait(core, i)
    }

    /// After the wait between polls: the state flush and the bus stats when due; `Next::Poll`
    /// when device `i` is due now.
    fn after_wait<D: Driver>(&mut self, core: &mut Core<D>, i: usize) -> Next {
        let now = Instant::now();
        if now >= core.flush_at {
            let state = core.durable.snapshot(&core.devices, false);
            core.durable.saver.start(state, &self.out);
            core.flush_at = now + self.state_flush;
        }
        if now >= core.stats_at {
            self.report_stats(core, now);
        }
        if core.slots[i].next_at() > now {
            Next::Loop
        } else {
            Next::Poll
        }
    }

    /// Publishes the bus health of the interval that ends `now`.
    fn report_stats<D: Driver>(&mut self, core: &mut Core<D>, now: Instant) {
        let (counters, busy) = core.driver.wire();
        let wall = now - core.stats_since;
        let stats = stats::of(
            (&counters, &core.counters_at_stats),
            &core.devices,
            &core.slots,
            wall,
            busy - core.busy_at_stats,
        );
        core.counters_at_stats = counters;
        let text = serde_json::to_string(&stats).unwrap_or_default();
        tracing::info!(bus = %core.name, stats = %text, "bus stats");
        self.metrics.utilisation(stats.utilisation);
        let _ = self.out.send(Output::BusStats {
            bus: core.name.clone(),
            stats: Box::new(stats),
        });
        core.stats_since = now;
        core.busy_at_stats = busy;
        core.stats_at = now + self.stats_interval;
    }

    /// What a poll of device `i` means: readings out, availability, the next deadline.
    fn after_poll<D: Driver>(
        &mut self,
        core: &mut Core<D>,
        i: usize,
        result: Result<Vec<crate::reading::Reading>, driver::Failure<D>>,
    ) {
        let now = Instant::now();
        let name = core.name.clone();
        match result {
            Err(e) if e.is_preempted() => {}
            Ok(readings) => {
                if std::mem::take(&mut core.line_down) {
                    tracing::info!(bus = %name, "line is answering again");
                    // Devices that went offline with the line are probed at once.
                    for (j, other) in core.devices.iter_mut().enumerate() {
                        if other.availability.line_back() {
                            core.slots[j].defer_to(now);
                        }
                    }
                }
                self.heart.set_up(true);
                let d = &mut core.devices[i];
                d.note_good_poll();
                status::answered(d, &name, &self.out);
                status::status_change(d, &self.out);
                let outputs = self.emitter.emit(d, readings);
                core.durable.publish(outputs, i, &core.devices, &self.out);
                core.slots[i].advance_if_due(now);
                self.rearm(core, i);
            }
            Err(e) if e.out_of_service().is_some() => {
                let why = e.out_of_service().unwrap_or_default().to_string();
                status::out_of_service(&mut core.devices[i], why, &name, &self.out);
                core.slots[i].defer_to(now + self.bus.backoff_max);
                self.rearm(core, i);
            }
            Err(e) => {
                let line_fault = core.driver.is_line_fault(&e);
                self.heart.set_up(!line_fault);
                if line_fault && !std::mem::replace(&mut core.line_down, true) {
                    tracing::error!(bus = %name, "line fault: {e}");
                    self.metrics.line_fault();
                }
                let d = &mut core.devices[i];
                match status::failed(d, &e, line_fault, &name, &self.out) {
                    Some(wait) => core.slots[i].defer_to(now + wait),
                    None => core.slots[i].advance_if_due(now),
                }
                self.rearm(core, i);
            }
        }
    }

    /// Sets device `i`'s next interval boundary read (none while it is offline: its probes
    /// follow the backoff, and a boundary it misses makes a `merged` record, never a guess).
    fn rearm<D: Driver>(&self, core: &mut Core<D>, i: usize) {
        let d = &core.devices[i];
        core.slots[i].boundary = if d.online() == Some(false) {
            None
        } else {
            let now_ms = crate::reading::unix_ms(std::time::SystemTime::now()) as i64;
            self.emitter.next_boundary(d, now_ms).map(|b| {
                Instant::now() + Duration::from_millis(u64::try_from(b - now_ms).unwrap_or(0))
            })
        };
    }

    /// Saves the state (clean), says the devices are offline, closes the line.
    async fn finish<D: Driver>(&mut self, mut core: Core<D>) {
        if core.durable.finish(&core.devices, &self.out).await {
            tracing::info!(bus = %core.name, "state saved");
        }
        for d in &core.devices {
            if d.online() == Some(true) {
                let _ = self.out.send(Output::DeviceStatus {
                    device: d.name.clone(),
                    online: false,
                });
            }
        }
        core.driver.close();
    }
}

/// What the loop does after the work between polls.
enum Next {
    /// Start over (a command ran, a scan step ran, a command arrived, nothing is due yet).
    Loop,
    /// Poll the device that is due.
    Poll,
    /// Shut down.
    Stop,
}

/// The running bus: devices, their slots, the driver and the loop's bookkeeping.
struct Core<D: Driver> {
    name: Arc<str>,
    driver: D,
    devices: Vec<DeviceRt<D::Device>>,
    slots: Vec<Slot>,
    durable: durable::Durable,
    flush_at: Instant,
    stats_at: Instant,
    stats_since: Instant,
    busy_at_stats: Duration,
    counters_at_stats: WireCounters,
    line_down: bool,
    pending: Vec<BusCommand>,
    /// Until when due polls go ahead of commands (as long again as the last command held the
    /// line): a burst of commands slows polling at most by half, never starves it.
    owed: Option<Instant>,
    poll_owed: bool,
    /// The last poll was an interval boundary read (see [`schedule::earliest`]).
    after_boundary: bool,
}

impl<D: Driver> Core<D> {
    fn new(
        name: Arc<str>,
        driver: D,
        devices: Vec<DeviceRt<D::Device>>,
        durable: durable::Durable,
        state_flush: Duration,
        stats_interval: Duration,
    ) -> Core<D> {
        let start = Instant::now();
        let slots = devices
            .iter()
            .map(|d| Slot::new(start, d.config.poll))
            .collect();
        Core {
            name,
            driver,
            devices,
            slots,
            durable,
            flush_at: start + state_flush,
            stats_at: start + stats_interval,
            stats_since: start,
            busy_at_stats: Duration::ZERO,
            counters_at_stats: WireCounters::default(),
            line_down: false,
            pending: Vec::new(),
            owed: None,
            poll_owed: false,
            after_boundary: false,
        }
    }

    /// When to wake: the poll of `i`, a flush, the stats, a command's expiry, or a second at
    /// most so the heart beats while the devices are slow (20 ms while readings are held for a
    /// save, so they go out as soon as it is done).
    fn wake(&self, i: usize) -> Instant {
        let expiry = self.pending.iter().map(|c| c.request.expires).min();
        let soon = if self.durable.holding() { 20 } else { 1000 };
        self.slots[i]
            .next_at()
            .min(Instant::now() + Duration::from_millis(soon))
            .min(self.flush_at)
            .min(self.stats_at)
            .min(expiry.unwrap_or(self.flush_at))
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

/// Carries out the first pending command whose device can take it (one command, so polls get
/// the line between commands); answers expired ones with `offline`; keeps the rest waiting for
/// their device. Returns the device and readings of the command that went on the line, if one
/// did.
async fn run_one_command<D: driver::Driver>(
    pending: &mut Vec<BusCommand>,
    devices: &mut [DeviceRt<D::Device>],
    driver: &mut D,
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
        if let crate::command::Op::SetReading(display) = c.request.op {
            let channel = c.request.channel.as_deref();
            let _ = c.done.send(meter::set_reading(d, channel, &display));
            continue;
        }
        if ran.is_none() && d.online() == Some(true) && driver.ready_for_commands(d) {
            let before = driver.wire().0;
            let executed = driver.execute(d, &c.request).await;
            d.metrics.wire(&before, &driver.wire().0);
            let (readings, result) = d.book_command(executed);
            ran = Some((i, readings));
            if let Err(e) = &result {
                tracing::warn!(device = %d.name, op = c.request.op.name(), "command failed: {e}");
            } else {
                tracing::info!(device = %d.name, channel = ?c.request.channel, op = c.request.op.name(), "command carried out");
            }
            let _ = c.done.send(result);
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

/// Saved state that no configured (and enabled) device can have: kept as it is, so a device
/// taken out of the config or disabled resumes its total, with a gap, when it comes back.
/// `pulsegate state prune` removes it.
fn unclaimed<P: DeviceState>(bus: &str, saved: &BusState, devices: &[DeviceRt<P>]) -> BusState {
    let claimed: std::collections::BTreeSet<String> = devices
        .iter()
        .flat_map(|d| d.counter_states().into_keys())
        .collect();
    let holes: std::collections::BTreeSet<String> =
        devices.iter().filter_map(|d| d.proto.saved_key()).collect();
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

#[cfg(test)]
#[path = "core_tests.rs"]
mod core_tests;
