//! The MQTT shell (rumqttc; MQTT 5 or 3.1.1 through [`super::session`]).
//!
//! A shell around [`crate::outbox`]: every message goes through the outbox (spool plus send
//! window, no I/O) and leaves it only when the broker acknowledges it; this file moves events
//! into it (connected, sent, acked, lost) and hands rumqttc what it says to send. Events become
//! messages in the output stage ([`super::format`]) before they get here.
//!
//! Every input is bounded before it costs anything: the gateway announces a maximum packet size
//! to the broker (and gives rumqttc the same limit), and a message that can never be sent (a topic
//! with a wildcard, a packet larger than the broker takes) is dropped from the spool with an error
//! instead of blocking everything behind it. Any client failure (collision timeout, protocol
//! error, a packet too large, the session taken over) ends with a fresh client and connection:
//! nothing of rumqttc's state survives it. "Connected" means publishing: when messages in flight
//! get no acknowledgement for a while, the connection is counted down and rebuilt.
//!
//! One task owns the shell (outbox and client) and `select!`s over the bus output, the
//! connection's reports and its timers; the connection itself is polled by a task of its own
//! ([`super::poller`]) that only moves rumqttc's events over a bounded channel, so nothing is
//! shared and nothing is locked. The buses hand output over an unbounded channel: they never
//! wait on MQTT.

use std::path::PathBuf;
use std::pin::Pin;
use std::time::Duration;

use tokio::time::Instant;

use tokio::sync::mpsc::{Sender, UnboundedReceiver, UnboundedSender};
use tokio_util::sync::CancellationToken;

use super::batch::{Batch, Verdict};
use super::dialer::{Dialer, Said};
use super::format::{Control, Format, Stage};
use super::poller::{Polled, Poller, Routes};
use super::session::{Client, Event, EventLoop, Failure, Options};
use super::spool::Spool;
use crate::config::{Config, Mqtt};
use crate::dispatch::Incoming;
use crate::health::Heart;
use crate::outbox::{Message, Outbox, Step};
use crate::reading::{Checkpoint, Output};
use crate::topics::Topics;

pub use crate::outbox::unsendable;

pub use super::session::{INFLIGHT, MAX_PACKET, REQUESTS, WINDOW};

/// The outbox and the client it feeds, owned by the MQTT task.
struct Shell {
    outbox: Outbox<Spool>,
    client: Client,
    topics: Topics,
    /// The formats' own filters (Home Assistant's status, say), renewed at every connection.
    extra_filters: Vec<String>,
    /// The last pump stopped at a full window or queue, not at the end of the outbox: the
    /// next acknowledgement lets more out.
    backlog: bool,
}

impl Shell {
    fn new(spool: Spool, client: Client, topics: Topics) -> Shell {
        Shell {
            outbox: Outbox::new(spool, WINDOW, Instant::now()),
            client,
            topics,
            extra_filters: Vec::new(),
            backlog: false,
        }
    }

    /// Hands rumqttc what the outbox says, until it says wait or rumqttc's queue is full. Each
    /// stored message passes the formats' last look on its way ([`Stage::outgoing`]).
    fn pump(&mut self, stage: &mut Stage) {
        let now = Instant::now();
        self.backlog = false;
        if stage.held().is_some() {
            return;
        }
        while let Some(step) = self.outbox.next(now) {
            match step {
                Step::Send { entry: e, replay } => {
                    let corr = e.correlation.as_deref();
                    let payload = stage
                        .outgoing(&e.topic, &e.payload, replay)
                        .unwrap_or(e.payload);
                    if self
                        .client
                        .publish(e.topic, e.qos, e.retain, payload, corr)
                        .is_err()
                    {
                        self.outbox.refused(); // more when it sends
                        stage.unsent();
                        self.backlog = true;
                        break;
                    }
                }
                Step::Dropped { topic, why } => {
                    tracing::error!(%topic, "message dropped, it can never be sent: {why}");
                }
            }
        }
        self.backlog |= self.outbox.backlogged();
    }

    /// Into the outbox (and its spool) without handing anything to rumqttc yet. Storing
    /// never fails: a message the disk refuses waits in memory or is dropped and counted.
    fn queue(&mut self, message: Message) {
        let Ok(_) = self.outbox.enqueue(message);
    }

    /// A publish outside the outbox (boot marker, what formats say at connect and at stop).
    /// Counted as direct only when rumqttc took it: a send event that never comes would be
    /// taken for the next stored message's, whose acknowledgement would then never count.
    fn publish_direct(&mut self, m: Message) {
        let topic: String = m.topic.chars().take(200).collect();
        match self
            .client
            .publish(m.topic, m.qos, m.retain, m.payload, None)
        {
            Ok(()) => self.outbox.direct(),
            Err(e) => tracing::error!(%topic, "not published, the client's queue is full: {e}"),
        }
    }

    fn subscribe(&self, filter: &str) {
        if let Err(e) = self.client.subscribe(filter.to_string()) {
            tracing::error!("cannot subscribe to {filter}: {e}");
        }
    }

    /// Connected: the formats say so before the backlog, subscriptions are restored (clean
    /// session); the caller sends the backlog.
    fn on_connack(&mut self, max_packet: Option<u32>, link: &Connection, stage: &mut Stage) {
        self.outbox.connected(max_packet, Instant::now());
        if link.voice {
            // The boot marker: subscribe first, so the retained one of another gateway arrives
            // before ours replaces it.
            let marker = self.topics.gateway_marker();
            self.subscribe(&marker);
            let boot = link.boot.marker(&link.client_id, &link.config_hash);
            self.publish_direct(Message::new(marker, boot, 1, true));
        }
        for m in stage.connected() {
            self.publish_direct(m);
        }
        if link.commands || link.remote {
            let mut filters: Vec<String> = Vec::new();
            if link.commands {
                filters.extend(self.topics.command_filters());
            }
            if link.remote {
                filters.push(self.topics.config_set());
            }
            if let Err(e) = self.client.subscribe_commands(&filters) {
                tracing::error!("cannot subscribe to command topics: {e}");
            }
        }
        for f in &self.extra_filters {
            self.subscribe(f);
        }
    }

    /// The connection failed: everything rumqttc held goes with it (the outbox sends it again,
    /// in order, on the fresh connection, which leaves the formats' current will).
    fn on_lost(&mut self, options: &Options, stage: &mut Stage) -> EventLoop {
        self.outbox.lost();
        stage.disconnected();
        let (client, fresh) = options.connect(stage.will().as_ref(), REQUESTS);
        self.client = client;
        fresh
    }
}

pub use super::session::client_options;

/// What one output's MQTT task is given, besides its channels.
pub struct Task {
    /// The output's name (`gateway` for the gateway's own connection): in logs, metrics, and
    /// on the commands that come in on this connection.
    pub name: String,
    /// This connection's settings (`[mqtt]` with the output's own keys over it).
    pub config: Mqtt,
    pub spool_dir: PathBuf,
    /// How often the spool is flushed (spilled to disk while the broker is away).
    pub flush_every: Duration,
    pub heart: Heart,
    pub boot: crate::boot::Boot,
    pub metrics: crate::metrics::OutputMetrics,
    /// The output stage's formats ([`super::formats::build`]).
    pub formats: Vec<Box<dyn Format>>,
    /// The connection carries the gateway's voice: its boot marker and, with
    /// `mqtt.commands`, its command topics.
    pub voice: bool,
    /// Answers this output gives itself (a command of its protocol refused before the router,
    /// or the router too busy to take it), handed back to the fan-out to be counted and said.
    pub answers: UnboundedSender<Output>,
    /// What its protocol asks of the gateway (a reboot).
    pub controls: UnboundedSender<Control>,
    /// The hash of the config in force (`Config::hash`), in the boot marker.
    pub config_hash: String,
    /// This connection takes pushed configs (the voice's home, with `[remote] config`).
    pub remote_config: bool,
}

/// Runs MQTT until the bus output closes (after `shutdown`), then spools what is left, publishes
/// the gateway offline and disconnects. Reloaded configs go to the formats.
pub async fn run(
    mut task: Task,
    mut output: UnboundedReceiver<Output>,
    incoming: Sender<Incoming>,
    reloads: UnboundedReceiver<Config>,
    shutdown: CancellationToken,
) {
    let topics = Topics::new(&task.config.topic_root);
    let Some((dialer, spool)) = start(&task).await else {
        // `check` and the start refuse such a config; a file changed since is fatal too.
        shutdown.cancel();
        task.heart.set_up(false);
        while output.recv().await.is_some() {}
        return;
    };
    let mut stage = Stage::new(std::mem::take(&mut task.formats));
    let (client, eventloop) = dialer.options().connect(stage.will().as_ref(), REQUESTS);
    let mut to_task = vec![topics.gateway_marker()];
    to_task.extend(stage.subscriptions());
    // Everything but the command topics is the task's: a connection without the voice
    // subscribes to no command topic, and what else arrives is its formats'.
    if !task.voice {
        to_task.push("#".into());
    }
    let routes = Routes {
        to_task,
        router: incoming,
        via: crate::command::Via {
            output: task.name.as_str().into(),
            wrote: None,
        },
    };
    let link = Connection {
        broker: dialer.broker(),
        dialer,
        client_id: task.config.client_id.clone(),
        commands: task.voice && task.config.commands,
        voice: task.voice,
        remote: task.remote_config,
        boot: task.boot.clone(),
        config_hash: task.config_hash.clone(),
    };
    let mut publisher = Publisher {
        stage,
        reloads,
        stall_after: task.config.keep_alive.max(Duration::from_secs(10)),
        task: &task,
        shell: Shell::new(spool, client, topics),
        link,
        watch: Watch::new(),
        poller: Poller::start(eventloop, Duration::ZERO, routes.clone()),
        routes,
        batch: Batch::new(task.config.batch),
        batch_due: None,
        checkpoints: Vec::new(),
        held_since: None,
        certificates_at: Instant::now(),
    };
    publisher.start();
    publisher.serve(&mut output).await;
    let _ = shutdown; // The buses end the loop by closing `output` once they have finished.
    publisher.finish().await;
}

/// The dialer (brokers, protocol, TLS) and the spool, or `None` (logged) when the gateway
/// cannot publish.
async fn start(task: &Task) -> Option<(Dialer, Spool)> {
    let options = match Dialer::new(&task.config) {
        Ok(o) => o,
        Err(e) => {
            tracing::error!("MQTT TLS cannot be set up: {e}; stopping (never plaintext)");
            return None;
        }
    };
    let spool = open_spool(
        task.spool_dir.clone(),
        task.config.spool_bytes,
        &task.metrics,
    )
    .await?;
    if !spool.is_empty() {
        tracing::info!(
            messages = spool.len(),
            "spooled messages from the last run will be sent first"
        );
    }
    Some((options, spool))
}

/// Opens the spool off the runtime thread (a large one left by the last run must not hold up
/// the buses); a fresh private directory when its own cannot be used (see `spool_place`).
async fn open_spool(
    dir: PathBuf,
    bytes: u64,
    metrics: &crate::metrics::OutputMetrics,
) -> Option<Spool> {
    let opened = tokio::task::spawn_blocking(move || super::spool_place::open(&dir, bytes)).await;
    match opened {
        Ok(Ok(o)) => {
            metrics.spool_fallback(o.fallback.is_some());
            Some(o.spool)
        }
        Ok(Err(e)) => {
            tracing::error!("{e}; no spool at all: stopping");
            None
        }
        Err(e) => {
            tracing::error!("spool open task failed: {e}; stopping");
            None
        }
    }
}

/// The MQTT task: the one owner of the shell. Bus output goes through the output stage into
/// the outbox; the connection's reports (connected, sent, acked, failed) move the outbox; a
/// health beat every second (the stall check, the formats' ticks, checkpoints the broker did
/// not settle), the spool flushed every `flush_every`.
struct Publisher<'t> {
    task: &'t Task,
    stage: Stage,
    reloads: UnboundedReceiver<Config>,
    shell: Shell,
    link: Connection,
    watch: Watch,
    /// The connection being polled; replaced (the old one dropped) after every failure.
    poller: Poller,
    routes: Routes,
    /// In-flight messages without an acknowledgement for this long: the connection is stalled.
    stall_after: Duration,
    /// Readings held to go with the next polls' (`mqtt.batch`), and the end of their window.
    batch: Batch,
    /// Dropped with the batch: a timer left in the runtime's wheel (even reset to later) would
    /// still wake the runtime at its old time, for nothing.
    batch_due: Option<Pin<Box<tokio::time::Sleep>>>,
    /// State saves waiting to hear that what came before them is durable.
    checkpoints: Vec<PendingCheckpoint>,
    /// Held (a format's hold) on this connection since then.
    held_since: Option<Instant>,
    /// When the certificates were last looked at.
    certificates_at: Instant,
}

impl Publisher<'_> {
    /// The formats' subscriptions (renewed at every connection) and what they publish first.
    fn start(&mut self) {
        self.check_certificates();
        self.shell.extra_filters = self.stage.subscriptions();
        for m in self.stage.start() {
            self.shell.queue(m);
        }
        self.pump();
    }

    /// Until the bus output closes.
    async fn serve(&mut self, output: &mut UnboundedReceiver<Output>) {
        let mut flush = tokio::time::interval(self.task.flush_every);
        let mut beat = tokio::time::interval(Duration::from_secs(1));
        loop {
            self.task.heart.beat();
            tokio::select! {
                out = output.recv() => match out {
                    Some(out) => self.handle(out),
                    None => return,
                },
                Some(polled) = self.poller.events.recv() => self.polled(polled),
                () = due(&mut self.batch_due), if self.batch_due.is_some() => self.pump(),
                Some(config) = self.reloads.recv() => {
                    for m in self.stage.reload(&config) {
                        self.shell.queue(m);
                    }
                    self.pump();
                    // SIGHUP reads the TLS files again too (the next connection uses them).
                    self.refresh_tls();
                    self.new_config_hash(config.hash().to_string());
                }
                _ = beat.tick() => self.beat(Instant::now()),
                _ = flush.tick() => self.flush(),
            }
        }
    }

    /// One event from the buses or the router: its side effects on health and metrics, then
    /// its messages into the outbox, to rumqttc at once or, readings, with their batch.
    fn handle(&mut self, out: Output) {
        if let Output::Checkpoint(c) = &out {
            return self.checkpoint(c.clone());
        }
        for m in self.stage.render(&out) {
            self.shell.queue(m);
        }
        if !matches!(out, Output::DeviceReadings { .. }) {
            self.pump(); // never held, and takes held readings along
            return;
        }
        match self.batch.reading(Instant::now()) {
            Verdict::Send => self.pump(),
            Verdict::HoldUntil(t) => {
                self.batch_due = Some(Box::pin(tokio::time::sleep_until(t)));
            }
            Verdict::Hold => {}
        }
    }

    /// A state save asks whether everything before it is durable: held readings go to the
    /// broker now; the answer comes when the broker has acknowledged them, or (broker away or
    /// slow) once they are fsynced in the spool.
    fn checkpoint(&mut self, checkpoint: Checkpoint) {
        self.pump();
        let upto = self.shell.outbox.next_seq().saturating_sub(1);
        self.checkpoints.push(PendingCheckpoint {
            checkpoint,
            upto,
            since: Instant::now(),
        });
        self.settle(Instant::now());
    }

    /// Answers the checkpoints the broker has settled by acknowledging; those it left too long
    /// (or every one, while it is away) are made durable on disk.
    fn settle(&mut self, now: Instant) {
        if self.checkpoints.is_empty() {
            return;
        }
        let oldest = self.shell.outbox.oldest_unacked();
        let up = self.shell.outbox.is_connected();
        let (done, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.checkpoints)
            .into_iter()
            .partition(|p| oldest.is_none_or(|o| o > p.upto));
        for p in done {
            p.checkpoint.answer(true);
        }
        let (to_disk, waiting): (Vec<_>, Vec<_>) = waiting
            .into_iter()
            .partition(|p| !up || now.saturating_duration_since(p.since) >= CHECKPOINT_WAIT);
        self.checkpoints = waiting;
        if !to_disk.is_empty() {
            self.sync_to_disk(to_disk);
        }
    }

    /// Spills what only memory holds and answers `checkpoints` once the disk has it: `false`
    /// when something could not be written or synced (the save then waits for the broker).
    fn sync_to_disk(&mut self, checkpoints: Vec<PendingCheckpoint>) {
        let durable = self.shell.outbox.store_mut().durable();
        tokio::task::spawn_blocking(move || {
            let durable = durable.wait(Duration::from_secs(5));
            for p in checkpoints {
                p.checkpoint.answer(durable);
            }
        });
    }

    /// The connection took or acknowledged a message: more may go out, but held readings wait
    /// for their batch unless the outbox has a backlog that only the window kept back.
    fn acknowledged(&mut self) {
        if !self.batch.holding() || self.shell.backlog {
            self.pump();
        }
        self.settle(Instant::now());
    }

    /// Hands rumqttc what the outbox lets out, held readings included: the batch is over, and
    /// so is its timer (a fired one left in place would be ready at every turn of the loop).
    fn pump(&mut self) {
        self.shell.pump(&mut self.stage);
        self.batch.sent();
        self.batch_due = None;
    }

    /// What the connection reported.
    fn polled(&mut self, polled: Polled) {
        let s = &mut self.shell;
        match polled {
            Ok(Event::ConnAck { max_packet }) => {
                if self.watch.up != Some(true) {
                    tracing::info!(broker = %self.link.broker, "connected to MQTT broker");
                }
                self.watch.up = Some(true);
                self.task.heart.set_problem(None);
                if let Some(said) = self.link.dialer.connected() {
                    self.say(&said);
                }
                let s = &mut self.shell;
                s.on_connack(max_packet, &self.link, &mut self.stage);
                self.pump();
                // Health (the systemd status, the ready line) says so now, not at the next beat.
                self.task.heart.set_up(self.shell.outbox.is_connected());
            }
            Ok(Event::Sent(pkid)) => {
                s.outbox.sent(pkid);
                self.acknowledged();
            }
            Ok(Event::Acked(pkid)) => {
                self.watch.pause = Duration::from_secs(1);
                s.outbox.acked(pkid, Instant::now());
                self.acknowledged();
            }
            Ok(Event::Received(p)) => self.received(&p.topic, &p.payload, p.retain),
            // Our DISCONNECT went out, or the client was dropped: the gateway is stopping.
            Ok(Event::Disconnected | Event::Other) | Err(Failure::RequestsDone) => {}
            Err(e) => self.reconnect(&e),
        }
    }

    /// A message on the boot marker or a format's subscription (the poller sends the rest to
    /// the router); commands a format makes of it go to the router too, never waiting on it.
    fn received(&mut self, topic: &[u8], payload: &[u8], retained: bool) {
        let topic = String::from_utf8_lossy(topic);
        if topic == self.shell.topics.gateway_marker() {
            self.watch.marker(payload, &self.link);
            return;
        }
        let reaction = if retained {
            self.stage.received_retained(&topic, payload)
        } else {
            self.stage.received(&topic, payload)
        };
        for m in reaction.at_once {
            self.shell.publish_direct(m);
        }
        for m in reaction.messages {
            self.shell.queue(m);
        }
        for c in reaction.commands {
            self.admit(c);
        }
        for a in reaction.answers {
            let _ = self.task.answers.send(a);
        }
        for c in reaction.control {
            self.control(c);
        }
        self.pump();
    }

    /// What a format's protocol asked: the next broker now, or a reboot of the gateway.
    fn control(&mut self, c: Control) {
        match c {
            Control::NextServer => self.move_on("its protocol asked for the next server"),
            Control::Reboot => {
                let _ = self.task.controls.send(Control::Reboot);
            }
        }
    }

    /// Moves to the next broker at once (with one broker: stays), the connection rebuilt.
    fn move_on(&mut self, why: &str) {
        let Some(said) = self.link.dialer.next_server(Instant::now(), why) else {
            tracing::warn!(output = %self.task.name, "{why}, but this output has one broker (mqtt.hosts)");
            return;
        };
        self.say(&said);
        self.link.broker = self.link.dialer.broker();
        self.task.heart.set_up(false);
        let eventloop = self
            .shell
            .on_lost(self.link.dialer.options(), &mut self.stage);
        self.poller = Poller::start(eventloop, Duration::ZERO, self.routes.clone());
        self.settle(Instant::now());
    }

    /// A command of a format's own protocol into the router's bounded queue; when the queue is
    /// full it is refused (answered `busy`, counted), never dropped.
    fn admit(&mut self, c: Incoming) {
        let Err(e) = self.routes.router.try_send(c) else {
            return;
        };
        let c = e.into_inner();
        let busy = crate::command::CommandError::Busy {
            device: c
                .via
                .as_ref()
                .and_then(|v| v.wrote.as_ref())
                .map_or_else(String::new, |w| w.device.clone()),
            why: "the gateway's command queue is full",
        };
        let outcome = crate::outcome::Outcome::Command(crate::outcome::CommandOutcome {
            id: None,
            op: None,
            result: Err(busy),
        });
        let reply = crate::command::Reply {
            topics: Vec::new(),
            correlation: None,
            via: c.via,
        };
        let _ = self
            .task
            .answers
            .send(Output::CommandResult { reply, outcome });
    }

    /// The connection failed or stalled: everything rumqttc held goes with it, a fresh client
    /// connects after the back-off (the outbox sends again, in order, what was not acked).
    fn reconnect(&mut self, why: &Failure) {
        self.watch.failed(why, &self.link);
        self.task.heart.set_up(false);
        self.task.heart.set_error(why.to_string());
        let pinned = self.task.config.protocol != crate::config::MqttProtocol::Auto;
        if pinned && matches!(why, Failure::ProtocolRefused) {
            self.task.heart.set_problem(Some(why.to_string()));
        }
        for said in self.link.dialer.failed(why, Instant::now()) {
            self.say(&said);
        }
        self.link.broker = self.link.dialer.broker();
        let eventloop = self
            .shell
            .on_lost(self.link.dialer.options(), &mut self.stage);
        self.poller = Poller::start(eventloop, self.watch.pause, self.routes.clone());
        self.settle(Instant::now());
    }

    /// Held on this broker (a Sparkplug primary host offline) for `failover_after`: the next
    /// broker, as Sparkplug 3.0 has a node do (its host may be on another server).
    fn held_on_this_broker(&mut self, held: bool, now: Instant) {
        if !held || !self.shell.outbox.is_connected() {
            self.held_since = None;
            return;
        }
        let since = *self.held_since.get_or_insert(now);
        let servers = self.task.config.servers().len();
        if servers > 1 && now.saturating_duration_since(since) >= self.task.config.failover_after {
            self.held_since = None;
            self.move_on(
                "held on this broker for mqtt.failover_after (its primary host is offline here)",
            );
        }
    }

    /// A config with another hash is in force: the boot marker says so at once.
    fn new_config_hash(&mut self, hash: String) {
        if hash == self.link.config_hash {
            return;
        }
        self.link.config_hash = hash;
        if self.link.voice && self.shell.outbox.is_connected() {
            let marker = self.shell.topics.gateway_marker();
            let boot = self
                .link
                .boot
                .marker(&self.link.client_id, &self.link.config_hash);
            self.shell
                .publish_direct(Message::new(marker, boot, 1, true));
        }
    }

    /// The TLS files read again when they changed (logged; a set that does not load keeps the
    /// one in use).
    fn refresh_tls(&mut self) {
        if let Some(said) = self.link.dialer.rebuild() {
            self.say(&said);
        }
    }

    /// The expiry of this connection's certificates, as metrics; a warning in the log and the
    /// status within [`EXPIRY_WARNING`] of it (or after it).
    fn check_certificates(&self) {
        let now = crate::reading::unix_ms(std::time::SystemTime::now()) as i64 / 1000;
        let mut soon = Vec::new();
        for file in self.link.dialer.tls_files() {
            let shown = file.display().to_string();
            match crate::config::tls::expiry(&file) {
                Ok(at) => {
                    self.task.metrics.tls_expiry(&shown, at);
                    let days = (at - now) / 86_400;
                    if at - now < EXPIRY_WARNING.as_secs() as i64 {
                        soon.push(format!("TLS certificate {shown} expires in {days} days"));
                    }
                }
                Err(e) => {
                    tracing::warn!(output = %self.task.name, "cannot read the expiry of {shown}: {e}")
                }
            }
        }
        for s in &soon {
            tracing::warn!(output = %self.task.name, "{s}: renew it (the gateway reads new files at its next connection)");
        }
        self.task
            .heart
            .set_note((!soon.is_empty()).then(|| soon.join(", ")));
    }

    /// Logs what the dialer decided.
    fn say(&self, said: &Said) {
        let output = &self.task.name;
        match said {
            Said::Fallback { broker, to } => {
                tracing::warn!(%output, %broker, "the broker did not answer this protocol's CONNECT (refused, closed or silent): trying {to} next (mqtt.protocol = \"auto\")")
            }
            Said::Speaks { broker, protocol } => {
                tracing::info!(%output, %broker, "the broker speaks {protocol}: connected with it (mqtt.protocol = \"auto\")")
            }
            Said::MovedOn { from, to, why } => {
                tracing::warn!(%output, "moving from broker {from} to {to}: {why}; what is spooled goes there, in order")
            }
            Said::TlsReloaded => {
                tracing::info!(%output, "TLS files changed: the next connection uses them");
                self.check_certificates();
            }
            Said::TlsRefused(e) => {
                tracing::error!(%output, "the changed TLS files do not load ({e}): the previous ones stay in use")
            }
        }
    }

    /// Every second: a connection that takes messages but acknowledges none is rebuilt (what
    /// rumqttc does after a packet-id collision); the formats' put-off work; checkpoints the
    /// broker left waiting; health and metrics.
    fn beat(&mut self, now: Instant) {
        if now.saturating_duration_since(self.certificates_at) >= CERTIFICATE_CHECK {
            self.certificates_at = now;
            self.refresh_tls();
            self.check_certificates();
        }
        let outbox = &self.shell.outbox;
        if outbox.stalled(now, self.stall_after) {
            tracing::warn!(
                in_flight = outbox.in_flight(),
                "MQTT broker acknowledged nothing for {}s: reconnecting with a fresh client",
                self.stall_after.as_secs()
            );
            self.reconnect(&Failure::Other(
                "no acknowledgement: connection stalled".into(),
            ));
        }
        let ticked = self.stage.tick(now);
        if !ticked.is_empty() {
            for m in ticked {
                self.shell.queue(m);
            }
            self.pump();
        }
        self.settle(now);
        let up = self.shell.outbox.is_connected();
        self.task.heart.set_up(up);
        let held = self.stage.held();
        self.task.heart.set_held(held.clone());
        self.held_on_this_broker(held.is_some(), now);
        let outbox = &self.shell.outbox;
        let spool = outbox.store();
        let chatter = outbox.chatter();
        self.task.heart.set_spool(spool.len(), spool.total_bytes());
        self.task.metrics.sample(&crate::metrics::OutputSample {
            connected: up,
            held: held.is_some(),
            spool_messages: spool.len(),
            spool_bytes: spool.total_bytes(),
            spool_dropped: spool.dropped,
            spool_written: spool.written,
            spool_write_failures: spool.write_failures(),
            spool_unreadable_lines: spool.unreadable_lines(),
            chatter_waiting: chatter.len(),
            chatter_dropped: chatter.dropped,
        });
        self.task.metrics.tallies(&self.stage.tallies());
        self.watch.chatter_dropped(chatter.dropped, now);
    }

    /// While the broker is away, memory is written out so a crash loses little; what could
    /// not be written before is tried again (the spool counts and logs its failures).
    fn flush(&mut self) {
        let up = self.shell.outbox.is_connected();
        let spool = self.shell.outbox.store_mut();
        if up { spool.flush() } else { spool.spill() }
    }

    /// Gives the broker a moment to take what is in flight, keeps the rest for next time,
    /// lets the formats say goodbye, lets the connection write that and our DISCONNECT, and
    /// waits (off the runtime thread) for the spool's last writes. The summary counts what is
    /// really on disk, and says what could not be written.
    async fn finish(&mut self) {
        self.pump();
        let deadline = tokio::time::Instant::now() + Duration::from_millis(1500);
        while self.shell.outbox.is_connected() && !self.shell.outbox.store().is_empty() {
            tokio::select! {
                Some(polled) = self.poller.events.recv() => self.polled(polled),
                () = tokio::time::sleep_until(deadline) => break,
            }
        }
        let s = &mut self.shell;
        let durable = s.outbox.store_mut().durable();
        if s.outbox.is_connected() {
            for m in self.stage.stopping() {
                s.publish_direct(m);
            }
            let _ = s.client.disconnect();
        }
        let waiting = std::mem::take(&mut self.checkpoints);
        // The spool's last writes reach the disk before the process ends.
        let synced = tokio::task::spawn_blocking(move || {
            let durable = durable.wait(Duration::from_secs(3));
            for p in waiting {
                p.checkpoint.answer(durable);
            }
        });
        let _ = tokio::join!(self.poller.finish(Duration::from_secs(1)), synced);
        let spool = self.shell.outbox.store_mut();
        spool.settle();
        kept_summary(spool);
    }
}

/// What the stop leaves for the next start: only what is on disk is said to be kept.
fn kept_summary(spool: &Spool) {
    let kept = spool.on_disk();
    let lost = spool.len() - kept;
    if kept > 0 {
        tracing::info!(messages = kept, "unsent messages kept for the next start");
    }
    if lost > 0 {
        tracing::error!(
            messages = lost,
            spool = %spool.dir().display(),
            "unsent messages could not be written to the spool (see the spool errors above): lost with this stop; the readings after them carry the totals, so counts stay exact, but these messages are not sent"
        );
    }
}

/// How long before a certificate expires the log and the status warn of it.
const EXPIRY_WARNING: Duration = Duration::from_secs(30 * 86_400);

/// How often certificates are looked at again (their files, and the time left).
const CERTIFICATE_CHECK: Duration = Duration::from_secs(3600);

/// How long a checkpoint waits for the broker's acknowledgements before what they cover is
/// fsynced in the spool instead (checked at the beat, so up to a second more).
const CHECKPOINT_WAIT: Duration = Duration::from_millis(500);

/// A state save waiting for the owed messages up to `upto` to be durable.
struct PendingCheckpoint {
    checkpoint: Checkpoint,
    upto: u64,
    since: Instant,
}

/// The end of the batch's window (never, without one).
async fn due(timer: &mut Option<Pin<Box<tokio::time::Sleep>>>) {
    match timer {
        Some(t) => t.await,
        None => std::future::pending().await,
    }
}

/// What a fresh client is built from, and what it announces.
struct Connection {
    /// Which broker, protocol and TLS files the next connection uses.
    dialer: Dialer,
    /// The broker of the current (or next) connection, as logs name it.
    broker: String,
    client_id: String,
    /// Subscribe to command topics (the voice's, with `mqtt.commands`).
    commands: bool,
    /// Carries the gateway's voice: publishes and watches the boot marker.
    voice: bool,
    /// Takes pushed configs (`<root>/config/set`, `[remote] config = true`).
    remote: bool,
    /// This run's boot id, published retained on `<root>/gateway`.
    boot: crate::boot::Boot,
    /// The hash of the config in force, in that marker.
    config_hash: String,
}

/// Logs of the connection: once per state change, takeovers at most once a minute.
struct Watch {
    up: Option<bool>,
    /// Chatter dropped when last logged, and the budget of those lines.
    chatter_dropped: u64,
    chatter_log: crate::log_budget::LogBudget,
    takeovers: u64,
    takeover_log: crate::log_budget::LogBudget,
    /// Wait before the next attempt after a failure.
    pause: Duration,
    /// The broker's refusal of MQTT 5 was logged (once a run: it will not change by itself).
    protocol_named: bool,
    /// This machine's previous run was recognised by its marker (said once).
    earlier_run_named: bool,
}

impl Watch {
    fn new() -> Watch {
        Watch {
            up: None,
            chatter_dropped: 0,
            chatter_log: crate::log_budget::LogBudget::new(1),
            takeovers: 0,
            takeover_log: crate::log_budget::LogBudget::new(1),
            pause: Duration::from_secs(1),
            protocol_named: false,
            earlier_run_named: false,
        }
    }

    /// Chatter was dropped since the last look: said at most once a minute, with the count.
    fn chatter_dropped(&mut self, dropped: u64, now: Instant) {
        if dropped > self.chatter_dropped && self.chatter_log.allow(now).0 {
            let n = dropped - self.chatter_dropped;
            tracing::warn!(
                dropped = n,
                "{n} command results, discovery configs or bus stats dropped: they came faster than the broker took them (readings are never dropped for them)"
            );
            self.chatter_dropped = dropped;
        }
    }

    /// A boot marker arrived: another gateway's is logged (within budget); this machine's
    /// previous run, which `boot.json` did not record, is said once as what it is.
    fn marker(&mut self, payload: &[u8], link: &Connection) {
        match link.boot.judge(payload) {
            crate::boot::Marker::Ours => {}
            crate::boot::Marker::EarlierRun(earlier) => {
                if !std::mem::replace(&mut self.earlier_run_named, true) {
                    tracing::info!(earlier = %earlier, "the boot marker on the topic root is this machine's previous run (same host, its process is gone), which boot.json did not record: not another gateway");
                }
            }
            crate::boot::Marker::Foreign(other) => {
                let (log, _) = self.takeover_log.allow(Instant::now());
                if log {
                    tracing::error!(other = %other, "another gateway publishes under this topic root (its boot marker is not ours): two gateways share gateway.id or mqtt.topic_root, so both receive each other's commands and, with one client id, take each other's MQTT session; give each gateway its own id");
                }
            }
        }
    }

    /// A connection failure: logged once per state change (takeovers each time, within
    /// budget); a takeover backs off so two gateways do not fight over the id every second.
    fn failed(&mut self, e: &Failure, link: &Connection) {
        if matches!(e, Failure::TakenOver) {
            self.takeovers += 1;
            let (log, _) = self.takeover_log.allow(Instant::now());
            if log {
                tracing::error!(client_id = %link.client_id, takeovers = self.takeovers, "the broker dropped this connection because another client connected with the same client id: is a second gateway using mqtt.client_id {:?}? Both would receive each other's commands", link.client_id);
            }
            self.pause = (self.pause * 2).clamp(Duration::from_secs(5), Duration::from_secs(60));
        } else if matches!(e, Failure::ProtocolRefused) {
            if !std::mem::replace(&mut self.protocol_named, true) {
                tracing::error!(broker = %link.broker, "MQTT broker refused the connection: {e}");
            }
        } else if self.up != Some(false) {
            tracing::warn!(broker = %link.broker, "MQTT broker unreachable: {e}; reconnecting with a fresh client, readings are spooled");
        }
        self.up = Some(false);
    }
}

#[cfg(test)]
#[path = "mqtt_tests.rs"]
mod tests;
