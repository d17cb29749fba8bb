//! The MQTT shell (rumqttc; MQTT 5 or 3.1.1 through [`super::session`]).
//!
//! A shell around [`crate::outbox`]: every message goes through the outbox (spool plus send
//! window, no I/O) and leaves it only when the broker acknowledges it; this file moves events
//! into it (connected, sent, acked, lost) and hands rumqttc what it says to send. Events become
//! messages in the output stage ([`super::format`]) before they get here.
//!
//! Every input is bounded before it costs anything: the gateway announces a maximum packet size
//! to the broker (and gives rumqttc the same limit); a larger message (a 3.1.1 broker cannot be
//! told) is skipped by rumqttc, counted and logged within budget, and the connection stays up.
//! A message that can never be sent (a topic with a wildcard, a packet larger than the broker
//! takes) is dropped from the spool with an error instead of blocking everything behind it. Any
//! client failure (collision timeout, protocol error, a packet too large to send, the session
//! taken over) ends with a fresh client and connection:
//! nothing of rumqttc's state survives it. "Connected" means publishing: when messages in flight
//! get no acknowledgement for a while, the connection is counted down and rebuilt.
//!
//! One task owns the shell (outbox and client) and `select!`s over the bus output, the
//! connection's reports and its timers; the connection itself is polled by a task of its own
//! ([`super::poller`]) that only moves rumqttc's events over a bounded channel, so nothing is
//! shared and nothing is locked. The buses hand output over an unbounded channel: they never
//! wait on MQTT.

mod broker;
mod checkpoints;
mod commands;
mod link;
mod shell;

use link::{Connection, Watch};
use shell::Shell;

use std::path::PathBuf;
use std::pin::Pin;
use std::time::Duration;

use tokio::time::Instant;

use tokio::sync::mpsc::{Sender, UnboundedReceiver, UnboundedSender};
use tokio_util::sync::CancellationToken;

use super::batch::{Batch, Verdict};
use super::dialer::Dialer;
use super::lifecycle::{Control, MqttFormat, Stage};
use super::poller::{Polled, Poller, Routes};
use super::session::{Event, Failure};
use super::spool::Spool;
use crate::config::{Config, Mqtt};
use crate::dispatch::Incoming;
use crate::health::Heart;

use crate::reading::{Checkpoint, Output};
use crate::topics::Topics;

pub use crate::outbox::unsendable;

pub use super::session::{INFLIGHT, MAX_PACKET, REQUESTS, WINDOW};

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
    pub formats: Vec<Box<dyn MqttFormat>>,
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
            Ok(Event::TooLarge { topic, size }) => {
                self.task.metrics.message_dropped("too_large");
                let now = Instant::now();
                self.watch.too_large(&topic, size, &self.link, now);
            }
            // Our DISCONNECT went out, or the client was dropped: the gateway is stopping.
            Ok(Event::Disconnected | Event::Other) | Err(Failure::RequestsDone) => {}
            Err(e) => self.reconnect(&e),
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

#[cfg(test)]
mod tests;
