//! Wires a checked config into running tasks: one per bus, one for MQTT, the command router,
//! the systemd supervisor; and applies a reloaded config to the buses that changed.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use crate::bus::{BusCommand, BusTask};
use crate::config::{Bus, Config};
use crate::dispatch::Router;
use crate::health::{Health, Loop};
use crate::metrics::Metrics;
use crate::reading::Output;

#[path = "app/north.rs"]
mod north;
#[path = "app/pushed.rs"]
mod pushed;
use crate::scan::ScanRequest;
use north::Northbound;

/// A bus task and what it takes to stop it or talk to it.
struct Running {
    config: Bus,
    stop: CancellationToken,
    task: JoinHandle<()>,
    commands: UnboundedSender<BusCommand>,
    scans: tokio::sync::mpsc::Sender<ScanRequest>,
}

/// How a run of the gateway ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// Asked to stop (SIGTERM, SIGINT).
    Stopped,
    /// An output's protocol asked for a reboot (Sparkplug's `Node Control/Reboot`): the
    /// process exits with [`REBOOT_STATUS`] after its orderly stop, so the service restarts it.
    Reboot,
    /// A pushed config changes what only a new start applies (`[gateway]`, `[metrics]`): the
    /// process starts itself again on it, and its watch goes on there.
    Restart,
}

/// What the gateway does after a step of a pushed config ([`pushed`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Next {
    Run,
    /// The process starts again (the push's watch or result kept for the new start).
    Restart,
}

/// The exit status of a reboot: not 0 (systemd's `Restart=on-failure` restarts on it) and not
/// 2, which `RestartPreventExitStatus=` keeps for a bad config. `EX_TEMPFAIL`.
pub const REBOOT_STATUS: u8 = 75;

/// A running gateway: its config in force, its buses, its outputs, and what wires them.
struct Gateway {
    current: Config,
    running: BTreeMap<String, Running>,
    health: Arc<Health>,
    metrics: Metrics,
    out: UnboundedSender<Output>,
    shutdown: CancellationToken,
    /// A reload's buses and devices, to the router.
    rewire: UnboundedSender<crate::dispatch::Wiring>,
    /// Ends the router once the buses have stopped (it answers what they still had).
    router_stop: CancellationToken,
    north: Northbound,
    status: Option<Arc<crate::status::Live>>,
    router: JoinHandle<()>,
    supervisor: JoinHandle<()>,
    endpoint: Option<JoinHandle<()>>,
}

/// What the gateway's loop hears besides signals: its outputs' protocols' requests, pushed
/// configs.
struct Inbox {
    controls: UnboundedReceiver<crate::publish::lifecycle::Control>,
    pushes: tokio::sync::mpsc::Receiver<crate::dispatch::Incoming>,
}

/// Runs the gateway until `shutdown` is cancelled. Configs arriving on `reloads` (SIGHUP) are
/// applied: buses whose config did not change keep running with their counters; changed ones
/// restart (their counter state goes through the state file); removed ones stop; outputs whose
/// connection or kind changed are rebuilt. Configs pushed from the broker (`[remote]`) are
/// applied the same way and watched ([`pushed`]).
pub async fn run_with_reloads(
    config: Config,
    shutdown: CancellationToken,
    mut reloads: UnboundedReceiver<Config>,
) -> Ended {
    let _state_lock = claim_state_dir(&config.gateway.state_dir).await;
    let (mut gateway, mut inbox) = Gateway::start(config, shutdown).await;
    let mut watch = None;
    let mut next = gateway.resume_watch(&mut watch).await;
    let mut tick = tokio::time::interval(std::time::Duration::from_secs(1));
    let mut ended = Ended::Stopped;
    while next == Next::Run {
        tokio::select! {
            () = gateway.shutdown.cancelled() => break,
            Some(crate::publish::lifecycle::Control::Reboot) = inbox.controls.recv() => {
                tracing::warn!("rebooting as asked: an orderly stop (state saved), then exit status {REBOOT_STATUS} for the service to start the gateway again");
                ended = Ended::Reboot;
                gateway.shutdown.cancel();
            }
            new = reloads.recv() => {
                let Some(new) = new else {
                    gateway.shutdown.cancelled().await;
                    break;
                };
                gateway.take(new).await;
            }
            Some(push) = inbox.pushes.recv() => next = gateway.push(push, &mut watch).await,
            _ = tick.tick(), if watch.is_some() => next = gateway.watch(&mut watch).await,
        }
    }
    if next == Next::Restart {
        ended = Ended::Restart;
        // Pushes already queued would be lost with this process: each is answered now, and
        // those arriving until it stops are answered by the router.
        inbox.pushes.close();
        let mut queued = Vec::new();
        while let Ok(msg) = inbox.pushes.try_recv() {
            queued.push(msg);
        }
        gateway.refuse_queued(queued);
        gateway.shutdown.cancel();
    }
    gateway.stop().await;
    ended
}

impl Gateway {
    /// Every task of `config`: the systemd supervisor, the HTTP endpoint, the buses, the
    /// command router, the outputs.
    async fn start(config: Config, shutdown: CancellationToken) -> (Gateway, Inbox) {
        let health = Arc::new(Health::default());
        let (out, out_rx) = unbounded_channel();
        let (incoming_tx, incoming_rx) =
            tokio::sync::mpsc::channel(crate::dispatch::INCOMING_QUEUE);
        let supervisor = tokio::spawn(crate::systemd::supervise(health.clone(), shutdown.clone()));
        let metrics = match config.metrics {
            Some(_) => Metrics::with_servers(crate::protocols::SERVER_FAMILIES),
            None => Metrics::disabled(),
        };
        // The status page's board: fed by the fan-out, read by the HTTP endpoint.
        let status = config.metrics.as_ref().map(|_| {
            Arc::new(crate::status::Live::start(
                &config,
                health.clone(),
                metrics.clone(),
            ))
        });
        let endpoint = start_http(&config, &metrics, &health, status.clone(), &shutdown).await;
        metrics.config(&config.hash().to_string());
        let mut running: BTreeMap<String, Running> = BTreeMap::new();
        for bus in config.buses.iter().filter(|b| b.enabled) {
            let r = start_bus(bus, &config, &health, &metrics, &out, &shutdown);
            running.insert(bus.name.clone(), r);
        }
        let (pushes_tx, pushes) = tokio::sync::mpsc::channel(1);
        let wiring = wiring(&config, &running);
        let router = Router::new(&config, &running.keys().cloned().collect()).with_remote();
        let (rewire, rewired) = unbounded_channel();
        let router_stop = CancellationToken::new();
        let router = tokio::spawn(crate::dispatch::run(
            router,
            wiring,
            incoming_rx,
            rewired,
            Some(pushes_tx),
            out.clone(),
            router_stop.clone(),
        ));
        let (controls_tx, controls) = unbounded_channel();
        let wires = (health.clone(), metrics.clone(), status.clone());
        let lines = (incoming_tx, controls_tx);
        let north = Northbound::start(&config, wires, lines, out_rx, &shutdown).await;
        let gateway = Gateway {
            current: config,
            running,
            health,
            metrics,
            out,
            shutdown,
            rewire,
            router_stop,
            north,
            status,
            router,
            supervisor,
            endpoint,
        };
        (gateway, Inbox { controls, pushes })
    }

    /// A new config in force: the buses that changed restart, the outputs' formats hear it,
    /// outputs whose connection or kind changed are rebuilt. `[gateway]` and `[metrics]` stay
    /// as started (a new start applies them).
    async fn take(&mut self, new: Config) {
        let rebuild = new.mqtt != self.current.mqtt || new.outputs != self.current.outputs;
        self.north.reload(&new);
        let (h, m, o, s) = (&self.health, &self.metrics, &self.out, &self.shutdown);
        apply(
            &mut self.current,
            new.clone(),
            &mut self.running,
            h,
            m,
            o,
            s,
        )
        .await;
        if rebuild {
            self.current.mqtt = new.mqtt;
            self.current.outputs = new.outputs;
            self.north.rebuild(&self.current).await;
        }
        if let Some(board) = &self.status {
            board.reconfigure(&self.current);
        }
        self.metrics.config(&self.current.hash().to_string());
        let _ = self.rewire.send(wiring(&self.current, &self.running));
    }

    /// The orderly stop: the buses (their state saved), the router, then the outputs (what
    /// they hold to their spools), the supervisor and the endpoint.
    async fn stop(mut self) {
        drop(self.out);
        for (_, r) in std::mem::take(&mut self.running) {
            if let Err(e) = r.task.await {
                tracing::error!("bus task failed: {e}");
            }
        }
        // The router answers what the buses still had, then ends; it holds a sender of the
        // bus output: the fan-out ends once it is gone too.
        self.router_stop.cancel();
        if let Err(e) = self.router.await {
            tracing::error!("command router failed: {e}");
        }
        self.north.finish().await;
        let _ = self.supervisor.await;
        if let Some(e) = self.endpoint {
            let _ = e.await;
        }
    }
}

/// Holds the state directory for the run (see [`crate::state_lock`]), so `pulsegate state prune
/// --apply` refuses while the gateway runs. A directory that cannot be locked is logged, and the
/// gateway runs on: polling matters more than the tool's guard.
async fn claim_state_dir(dir: &std::path::Path) -> Option<crate::state::lock::StateLock> {
    let dir = dir.to_path_buf();
    let taken =
        tokio::task::spawn_blocking(move || crate::state::lock::StateLock::take(&dir)).await;
    match taken {
        Ok(Ok(lock)) => Some(lock),
        Ok(Err(e @ crate::state::lock::LockError::Held { .. })) => {
            tracing::error!(
                "{e}: two gateways on one state directory overwrite each other's counter state; give each its own gateway.state_dir"
            );
            None
        }
        Ok(Err(e)) => {
            tracing::warn!(
                "{e}; `pulsegate state prune --apply` cannot tell that this gateway runs"
            );
            None
        }
        Err(_) => None,
    }
}

/// Serves `/metrics`, `/healthz` and the status page when `[metrics]` is configured. A port
/// that cannot be bound is logged and the gateway runs on without the endpoint: polling matters
/// more.
async fn start_http(
    config: &Config,
    metrics: &Metrics,
    health: &Arc<Health>,
    status: Option<Arc<crate::status::Live>>,
    shutdown: &CancellationToken,
) -> Option<JoinHandle<()>> {
    let m = config.metrics.as_ref()?;
    let listen = m.listen;
    if !listen.ip().is_loopback() {
        tracing::warn!(%listen, "HTTP endpoint is not on loopback: the status page asks for metrics.token, /metrics and /healthz do not; keep it behind a firewall");
    }
    match crate::http::bind(listen).await {
        Ok(l) => {
            tracing::info!(%listen, "HTTP endpoint: the status page at http://{listen}/, /api/v1/status, /api/v1/events, /metrics, /healthz");
            let endpoint = crate::http::Endpoint {
                metrics: metrics.clone(),
                health: health.clone(),
                status,
                token: m.token.clone(),
            };
            Some(tokio::spawn(crate::http::serve(
                l,
                endpoint,
                shutdown.clone(),
            )))
        }
        Err(e) => {
            tracing::error!("{e}; running without it");
            None
        }
    }
}

/// Runs the gateway until `shutdown` (no reloads).
pub async fn run(config: Config, shutdown: CancellationToken) -> Ended {
    let (_keep, reloads) = unbounded_channel();
    run_with_reloads(config, shutdown, reloads).await
}

fn start_bus(
    bus: &Bus,
    config: &Config,
    health: &Health,
    metrics: &Metrics,
    out: &UnboundedSender<Output>,
    shutdown: &CancellationToken,
) -> Running {
    let (cmd_tx, cmd_rx) = unbounded_channel();
    // One scan runs, one may wait: further requests are answered "busy" (bounded).
    let (scan_tx, scan_rx) = tokio::sync::mpsc::channel(1);
    let stop = shutdown.child_token();
    let heart = health.heart(Loop::Bus(bus.name.clone()));
    let task = BusTask::new(bus.clone(), &config.gateway, out.clone(), cmd_rx, heart)
        .with_metrics(metrics.bus(&bus.name));
    Running {
        config: bus.clone(),
        task: crate::protocols::spawn(task, bus, scan_rx, stop.clone()),
        stop,
        commands: cmd_tx,
        scans: scan_tx,
    }
}

fn scan_senders(
    running: &BTreeMap<String, Running>,
) -> HashMap<String, tokio::sync::mpsc::Sender<ScanRequest>> {
    running
        .iter()
        .map(|(n, r)| (n.clone(), r.scans.clone()))
        .collect()
}

fn senders(running: &BTreeMap<String, Running>) -> HashMap<String, UnboundedSender<BusCommand>> {
    running
        .iter()
        .map(|(n, r)| (n.clone(), r.commands.clone()))
        .collect()
}

/// The router's channels to the running buses, and the devices on them.
fn wiring(config: &Config, running: &BTreeMap<String, Running>) -> crate::dispatch::Wiring {
    let names = running.keys().cloned().collect();
    crate::dispatch::Wiring {
        buses: senders(running),
        scans: scan_senders(running),
        targets: crate::dispatch::targets_of(config, &names),
    }
}

async fn apply(
    current: &mut Config,
    new: Config,
    running: &mut BTreeMap<String, Running>,
    health: &Health,
    metrics: &Metrics,
    out: &UnboundedSender<Output>,
    shutdown: &CancellationToken,
) {
    if new.gateway != current.gateway || new.metrics != current.metrics {
        tracing::warn!("changes to [gateway] or [metrics] take effect at the next start");
    }
    let mut kept = 0;
    let names: Vec<String> = running.keys().cloned().collect();
    for name in names {
        let same = new
            .buses
            .iter()
            .any(|b| b.name == name && *b == running[&name].config);
        if same {
            kept += 1;
            continue;
        }
        let r = running.remove(&name).expect("listed above");
        r.stop.cancel();
        let _ = r.task.await;
        health.forget(Loop::Bus(name.clone()));
        tracing::info!(bus = %name, "bus stopped for the new config");
    }
    for bus in new.buses.iter().filter(|b| b.enabled) {
        if !running.contains_key(&bus.name) {
            // The gateway and MQTT settings stay those the gateway started with.
            let mut cfg = new.clone();
            cfg.gateway = current.gateway.clone();
            running.insert(
                bus.name.clone(),
                start_bus(bus, &cfg, health, metrics, out, shutdown),
            );
            tracing::info!(bus = %bus.name, "bus started for the new config");
        }
    }
    let devices: Vec<String> = new.devices().map(|(_, d)| d.name.clone()).collect();
    health.retain_devices(&devices);
    metrics.retain(&new);
    tracing::info!(unchanged = kept, buses = new.buses.len(), "config reloaded");
    let gateway = current.gateway.clone();
    let mqtt = current.mqtt.clone();
    *current = new;
    current.gateway = gateway;
    current.mqtt = mqtt;
}
