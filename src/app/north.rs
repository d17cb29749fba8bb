//! The northbound of a running gateway: one task per output (and the gateway's own connection
//! when no output carries its voice), the fan-out that feeds them, and their rebuild when a new
//! config changes what they are (their spools carry what they hold over to the new ones).

use std::sync::Arc;

use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use crate::config::Config;
use crate::health::{Health, Loop};
use crate::metrics::Metrics;
use crate::publish::lifecycle::{Control, MqttFormat};
use crate::reading::Output;

/// What every output task is wired to.
#[derive(Clone)]
pub(super) struct Wiring {
    pub health: Arc<Health>,
    pub metrics: Metrics,
    pub boot: crate::boot::Boot,
    /// The fan-out's input, for the answers an output gives itself.
    pub answers: UnboundedSender<Output>,
    /// The command router's bounded queue.
    pub incoming: tokio::sync::mpsc::Sender<crate::dispatch::Incoming>,
    /// What the outputs' protocols ask of the gateway.
    pub controls: UnboundedSender<Control>,
    pub shutdown: CancellationToken,
}

/// The outputs and the fan-out that feeds them.
pub(super) struct Northbound {
    fanout: JoinHandle<()>,
    /// New outputs' channels for the fan-out (a rebuild).
    swaps: UnboundedSender<Vec<UnboundedSender<Output>>>,
    tasks: Vec<JoinHandle<()>>,
    reloads: Vec<UnboundedSender<Config>>,
    wiring: Wiring,
}

/// What an output runs: an MQTT connection with its formats, or a server of its own.
enum Job {
    Mqtt(Box<crate::publish::mqtt::Task>),
    Server(Box<dyn crate::publish::Server>),
}

/// An output ready to run: its task's settings and channels.
struct Prepared {
    task: Job,
    events: UnboundedSender<Output>,
    events_rx: UnboundedReceiver<Output>,
    reloads: UnboundedSender<Config>,
    reloads_rx: UnboundedReceiver<Config>,
}

impl Prepared {
    fn spawn(self, w: &Wiring) -> (JoinHandle<()>, UnboundedSender<Config>) {
        let task = match self.task {
            Job::Mqtt(task) => tokio::spawn(crate::publish::mqtt::run(
                *task,
                self.events_rx,
                w.incoming.clone(),
                self.reloads_rx,
                w.shutdown.clone(),
            )),
            Job::Server(server) => {
                server.start(self.events_rx, w.incoming.clone(), self.reloads_rx)
            }
        };
        (task, self.reloads)
    }
}

impl Northbound {
    /// One task per output and the fan-out from `events` (the buses' and the router's output).
    pub async fn start(
        config: &Config,
        (health, metrics, status): (Arc<Health>, Metrics, Option<Arc<crate::status::Live>>),
        (incoming, controls): (
            tokio::sync::mpsc::Sender<crate::dispatch::Incoming>,
            UnboundedSender<Control>,
        ),
        events: UnboundedReceiver<Output>,
        shutdown: &CancellationToken,
    ) -> Northbound {
        let boot_dir = config.gateway.state_dir.clone();
        let mut boot = tokio::task::spawn_blocking(move || crate::boot::Boot::start(&boot_dir))
            .await
            .unwrap_or_default();
        let billing = config.gateway.billing.as_deref();
        boot.signing_key = billing
            .and_then(|b| b.signer.as_deref())
            .map(|k| k.public_base64());
        let (answers, answers_rx) = unbounded_channel();
        let (swaps, swaps_rx) = unbounded_channel();
        let wiring = Wiring {
            health: health.clone(),
            metrics: metrics.clone(),
            boot,
            answers,
            incoming,
            controls,
            shutdown: shutdown.clone(),
        };
        adopt_legacy_spool(config);
        let prepared = prepare(config, &wiring);
        let fanout = crate::publish::fanout::Fanout {
            outputs: prepared.iter().map(|p| p.events.clone()).collect(),
            health,
            metrics,
            status,
        };
        let (tasks, reloads) = prepared.into_iter().map(|p| p.spawn(&wiring)).unzip();
        Northbound {
            fanout: tokio::spawn(fanout.run(events, answers_rx, swaps_rx)),
            swaps,
            tasks,
            reloads,
            wiring,
        }
    }

    /// A reloaded config to every output's stage (Home Assistant discovery describes it).
    pub fn reload(&self, config: &Config) {
        for r in &self.reloads {
            let _ = r.send(config.clone());
        }
    }

    /// The outputs of `config` in place of the running ones: the fan-out feeds the new ones
    /// from now on (they keep what comes until they run), the old ones finish (what they hold
    /// goes to their spools, their `offline` and deaths are said), then the new ones start on
    /// the same spools.
    pub async fn rebuild(&mut self, config: &Config) {
        let prepared = prepare(config, &self.wiring);
        let _ = self
            .swaps
            .send(prepared.iter().map(|p| p.events.clone()).collect());
        for t in self.tasks.drain(..) {
            if let Err(e) = t.await {
                tracing::error!("MQTT output task failed: {e}");
            }
        }
        let (tasks, reloads) = prepared.into_iter().map(|p| p.spawn(&self.wiring)).unzip();
        (self.tasks, self.reloads) = (tasks, reloads);
        tracing::info!("outputs rebuilt for the new config");
    }

    /// Waits for the fan-out (it ends when the buses and the router are gone) and then for the
    /// outputs, which end when it closes their channels.
    pub async fn finish(self) {
        let _ = self.fanout.await;
        for t in self.tasks {
            if let Err(e) = t.await {
                tracing::error!("MQTT output task failed: {e}");
            }
        }
    }
}

/// One output per `[outputs]` entry, and the gateway's own connection when no output carries
/// its voice on the `[mqtt]` broker (`config::outputs::VoiceHome`).
fn prepare(config: &Config, w: &Wiring) -> Vec<Prepared> {
    use crate::config::outputs::{VOICE_NAME, VoiceHome};
    let home = match config.outputs.voice {
        VoiceHome::Output(i) => config.outputs.list[i].name.as_str(),
        VoiceHome::Own => VOICE_NAME,
    };
    let mut out = Vec::new();
    for o in &config.outputs.list {
        let formats = crate::publish::formats::build(config, o);
        let voice = o.kind.carries_gateway_topics();
        out.push(prepare_one(
            config,
            (&o.name, &o.mqtt),
            formats,
            voice,
            home,
            w,
        ));
    }
    let parts = |name: &str| {
        let heart = w.health.heart(Loop::Output(name.to_string()));
        (heart, w.metrics.output(name))
    };
    for server in crate::protocols::servers(config, parts) {
        out.push(prepare_server(server));
    }
    if config.outputs.voice == VoiceHome::Own {
        let voice = crate::publish::voice::Voice::new(&config.mqtt.topic_root, VOICE_NAME);
        let formats: Vec<Box<dyn MqttFormat>> = vec![Box::new(voice)];
        let own = (VOICE_NAME, &config.mqtt);
        out.push(prepare_one(config, own, formats, true, home, w));
    }
    out
}

fn prepare_one(
    config: &Config,
    (name, mqtt): (&str, &crate::config::Mqtt),
    formats: Vec<Box<dyn MqttFormat>>,
    voice: bool,
    home: &str,
    w: &Wiring,
) -> Prepared {
    let (events, events_rx) = unbounded_channel();
    let (reloads, reloads_rx) = unbounded_channel();
    let task = crate::publish::mqtt::Task {
        name: name.to_string(),
        config: mqtt.clone(),
        spool_dir: crate::publish::spool_place::output_dir(&config.gateway.state_dir, name),
        flush_every: config.gateway.state_flush,
        heart: w.health.heart(Loop::Output(name.to_string())),
        boot: w.boot.clone(),
        metrics: w.metrics.output(name),
        formats,
        voice,
        answers: w.answers.clone(),
        controls: w.controls.clone(),
        config_hash: config.hash().to_string(),
        remote_config: config.remote.config && name == home,
    };
    Prepared {
        task: Job::Mqtt(Box::new(task)),
        events,
        events_rx,
        reloads,
        reloads_rx,
    }
}

/// A serving output: its channels.
fn prepare_server(server: Box<dyn crate::publish::Server>) -> Prepared {
    let (events, events_rx) = unbounded_channel();
    let (reloads, reloads_rx) = unbounded_channel();
    Prepared {
        task: Job::Server(server),
        events,
        events_rx,
        reloads,
        reloads_rx,
    }
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
