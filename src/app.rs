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
use crate::health::Health;
use crate::metrics::Metrics;
use crate::reading::Output;
use crate::scan::ScanRequest;

/// A bus task and what it takes to stop it or talk to it.
struct Running {
    config: Bus,
    stop: CancellationToken,
    task: JoinHandle<()>,
    commands: UnboundedSender<BusCommand>,
    scans: tokio::sync::mpsc::Sender<ScanRequest>,
}

/// Runs the gateway until `shutdown` is cancelled. Configs arriving on `reloads` (SIGHUP) are
/// applied: buses whose config did not change keep running with their counters; changed ones
/// restart (their counter state goes through the state file); removed ones stop.
pub async fn run_with_reloads(
    config: Config,
    shutdown: CancellationToken,
    mut reloads: UnboundedReceiver<Config>,
) {
    let _state_lock = claim_state_dir(&config.gateway.state_dir).await;
    let health = Arc::new(Health::default());
    let (out_tx, out_rx) = unbounded_channel();
    let (incoming_tx, incoming_rx) = tokio::sync::mpsc::channel(crate::dispatch::INCOMING_QUEUE);
    let supervisor = tokio::spawn(crate::systemd::supervise(health.clone(), shutdown.clone()));
    let metrics = match config.metrics {
        Some(_) => Metrics::new(),
        None => Metrics::disabled(),
    };
    // The status page's board: fed by the fan-out, read by the HTTP endpoint.
    let status = config.metrics.as_ref().map(|_| {
        Arc::new(crate::status::Live::new(
            &config,
            health.clone(),
            metrics.clone(),
        ))
    });
    let endpoint = start_http(&config, &metrics, &health, status.clone(), &shutdown).await;

    let mut running: BTreeMap<String, Running> = BTreeMap::new();
    for bus in config.buses.iter().filter(|b| b.enabled) {
        let r = start_bus(bus, &config, &health, &metrics, &out_tx, &shutdown);
        running.insert(bus.name.clone(), r);
    }
    let router = Router::new(&config, &senders(&running), out_tx.clone());
    let targets = router.targets();
    let scans = router.scans();
    *scans.write().unwrap_or_else(|e| e.into_inner()) = scan_senders(&running);
    let router = tokio::spawn(router.run(incoming_rx));

    let wires = (health.clone(), metrics.clone(), status.clone());
    let north = Northbound::start(&config, wires, incoming_tx, out_rx, &shutdown).await;

    let mut current = config;
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            new = reloads.recv() => {
                let Some(new) = new else {
                    shutdown.cancelled().await;
                    break;
                };
                // The output stages (Home Assistant discovery describes the config).
                north.reload(&new);
                apply(&mut current, new, &mut running, &health, &metrics, &out_tx, &shutdown).await;
                if let Some(board) = &status {
                    board.reconfigure(&current);
                }
                Router::set_targets(&targets, &current, &senders(&running));
                *scans.write().unwrap_or_else(|e| e.into_inner()) = scan_senders(&running);
            }
        }
    }
    drop(out_tx);
    for (_, r) in std::mem::take(&mut running) {
        if let Err(e) = r.task.await {
            tracing::error!("bus task failed: {e}");
        }
    }
    // The router holds a sender of the bus output: the fan-out ends once it is gone too.
    router.abort();
    north.finish().await;
    let _ = supervisor.await;
    if let Some(e) = endpoint {
        let _ = e.await;
    }
}

/// The outputs and the fan-out that feeds them.
struct Northbound {
    fanout: JoinHandle<()>,
    tasks: Vec<JoinHandle<()>>,
    reloads: Vec<UnboundedSender<Config>>,
}

impl Northbound {
    /// One task per output and the fan-out from `events` (the buses' and the router's output).
    async fn start(
        config: &Config,
        (health, metrics, status): (Arc<Health>, Metrics, Option<Arc<crate::status::Live>>),
        incoming: tokio::sync::mpsc::Sender<crate::dispatch::Incoming>,
        events: UnboundedReceiver<Output>,
        shutdown: &CancellationToken,
    ) -> Northbound {
        let boot_dir = config.gateway.state_dir.clone();
        let boot = tokio::task::spawn_blocking(move || crate::boot::Boot::start(&boot_dir))
            .await
            .unwrap_or_default();
        let (answers, answers_rx) = unbounded_channel();
        let wiring = Wiring {
            health: &health,
            metrics: &metrics,
            boot,
            answers,
            incoming,
            shutdown,
        };
        let outputs = start_outputs(config, &wiring);
        let fanout = crate::publish::fanout::Fanout {
            outputs: outputs.iter().map(|o| o.events.clone()).collect(),
            health: health.clone(),
            metrics: metrics.clone(),
            status,
        };
        Northbound {
            reloads: outputs.iter().map(|o| o.reloads.clone()).collect(),
            tasks: outputs.into_iter().map(|o| o.task).collect(),
            fanout: tokio::spawn(fanout.run(events, answers_rx)),
        }
    }

    /// A reloaded config to every output's stage (Home Assistant discovery describes it).
    fn reload(&self, config: &Config) {
        for r in &self.reloads {
            let _ = r.send(config.clone());
        }
    }

    /// Waits for the fan-out (it ends when the buses and the router are gone) and then for the
    /// outputs, which end when it closes their channels.
    async fn finish(self) {
        let _ = self.fanout.await;
        for t in self.tasks {
            if let Err(e) = t.await {
                tracing::error!("MQTT output task failed: {e}");
            }
        }
    }
}

/// What every output task is wired to.
struct Wiring<'a> {
    health: &'a Arc<Health>,
    metrics: &'a Metrics,
    boot: crate::boot::Boot,
    /// The fan-out's input, for the answers an output gives itself.
    answers: UnboundedSender<Output>,
    /// The command router's bounded queue.
    incoming: tokio::sync::mpsc::Sender<crate::dispatch::Incoming>,
    shutdown: &'a CancellationToken,
}

/// A running output: its task, where its events and reloads go.
struct OutputTask {
    task: JoinHandle<()>,
    events: UnboundedSender<Output>,
    reloads: UnboundedSender<Config>,
}

/// One task per output, and the gateway's own connection when no output carries its voice
/// on the `[mqtt]` broker (`config::outputs::VoiceHome`).
fn start_outputs(config: &Config, w: &Wiring<'_>) -> Vec<OutputTask> {
    use crate::config::outputs::{VOICE_NAME, VoiceHome};
    adopt_legacy_spool(config);
    let mut out = Vec::new();
    for o in &config.outputs.list {
        let formats = crate::publish::formats::build(config, o);
        let voice = o.kind.carries_gateway_topics();
        out.push(start_output(config, &o.name, &o.mqtt, formats, voice, w));
    }
    if config.outputs.voice == VoiceHome::Own {
        let voice = crate::publish::voice::Voice::new(&config.mqtt.topic_root, VOICE_NAME);
        let formats: Vec<Box<dyn crate::publish::format::Format>> = vec![Box::new(voice)];
        out.push(start_output(
            config,
            VOICE_NAME,
            &config.mqtt,
            formats,
            true,
            w,
        ));
    }
    out
}

/// What an earlier version spooled in `<state_dir>/spool` goes to the output that now carries
/// the gateway's JSON topics on its broker (else the first output, else its own connection).
fn adopt_legacy_spool(config: &Config) {
    use crate::config::outputs::{VOICE_NAME, VoiceHome};
    let name = match config.outputs.voice {
        VoiceHome::Output(i) => config.outputs.list[i].name.as_str(),
        VoiceHome::Own => config
            .outputs
            .list
            .first()
            .map_or(VOICE_NAME, |o| o.name.as_str()),
    };
    let state_dir = &config.gateway.state_dir;
    let into = crate::publish::spool_place::output_dir(state_dir, name);
    match crate::publish::spool_place::adopt_legacy(state_dir, &into) {
        Ok(0) => {}
        Ok(n) => tracing::info!(
            files = n,
            output = name,
            "spool files of an earlier version handed to this output"
        ),
        Err(e) => tracing::error!(
            "cannot move the spool files of an earlier version into {}: {e}; they stay where they are, unsent",
            into.display()
        ),
    }
}

fn start_output(
    config: &Config,
    name: &str,
    mqtt: &crate::config::Mqtt,
    formats: Vec<Box<dyn crate::publish::format::Format>>,
    voice: bool,
    w: &Wiring<'_>,
) -> OutputTask {
    let (events, events_rx) = unbounded_channel();
    let (reloads, reloads_rx) = unbounded_channel();
    let task = crate::publish::mqtt::Task {
        name: name.to_string(),
        config: mqtt.clone(),
        spool_dir: crate::publish::spool_place::output_dir(&config.gateway.state_dir, name),
        flush_every: config.gateway.state_flush,
        heart: w.health.heart(&format!("output/{name}")),
        boot: w.boot.clone(),
        metrics: w.metrics.output(name),
        formats,
        voice,
        answers: w.answers.clone(),
    };
    let task = tokio::spawn(crate::publish::mqtt::run(
        task,
        events_rx,
        w.incoming.clone(),
        reloads_rx,
        w.shutdown.clone(),
    ));
    OutputTask {
        task,
        events,
        reloads,
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
            tracing::info!(%listen, "HTTP endpoint: the status page at http://{listen}/, /api/v1/status, /metrics, /healthz");
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
pub async fn run(config: Config, shutdown: CancellationToken) {
    let (_keep, reloads) = unbounded_channel();
    run_with_reloads(config, shutdown, reloads).await;
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
    let heart = health.heart(&format!("bus/{}", bus.name));
    let task = BusTask::new(bus.clone(), &config.gateway, out.clone(), cmd_rx, heart)
        .with_metrics(metrics.bus(&bus.name));
    Running {
        config: bus.clone(),
        task: crate::driver::spawn(task, bus, scan_rx, stop.clone()),
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

async fn apply(
    current: &mut Config,
    new: Config,
    running: &mut BTreeMap<String, Running>,
    health: &Health,
    metrics: &Metrics,
    out: &UnboundedSender<Output>,
    shutdown: &CancellationToken,
) {
    if new.mqtt != current.mqtt || new.gateway != current.gateway {
        tracing::warn!("changes to [gateway] or [mqtt] take effect at the next restart");
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
        health.forget(&format!("bus/{name}"));
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
