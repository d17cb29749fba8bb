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
//! Two tasks: the event loop only drives the connection (it never awaits a publish: that can
//! deadlock rumqttc); the publisher turns bus output into messages for the outbox. The buses hand
//! output over an unbounded channel: they never wait on MQTT.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use rumqttc::{TlsConfiguration, Transport};
use tokio::sync::mpsc::{Sender, UnboundedReceiver};
use tokio_util::sync::CancellationToken;

use super::format::{Format, render};
use super::session::{Client, Event, EventLoop, Failure, Options, Received, Settings};
use super::spool::Spool;
use super::topics::Topics;
use crate::config::Mqtt;
use crate::dispatch::Incoming;
use crate::health::Heart;
use crate::outbox::{Message, Outbox, Step};
use crate::reading::Output;

pub use crate::outbox::unsendable;

/// Messages handed to rumqttc before their acknowledgement.
const WINDOW: usize = 100;

/// rumqttc's own in-flight limit: the outbox's window plus room for the messages that bypass it
/// (command results, subscriptions), so rumqttc never has to hold one back.
const INFLIGHT: u16 = WINDOW as u16 + 64;

/// The largest MQTT packet the gateway takes, announced to the broker in CONNECT (so it never
/// sends a larger one) and given to rumqttc as its incoming limit (its default, 10 KiB, would
/// disconnect at the first larger command). Commands are refused above 1 KiB anyway.
pub const MAX_PACKET: u32 = 64 * 1024;

/// The outbox and the client it feeds, shared by the publisher and the event loop.
struct Shell {
    outbox: Outbox<Spool>,
    client: Client,
    topics: Topics,
    /// Filters asked for with [`Output::Subscribe`], renewed at every connection.
    extra_filters: Vec<String>,
}

impl Shell {
    fn new(spool: Spool, client: Client, topics: Topics) -> Shell {
        Shell {
            outbox: Outbox::new(spool, WINDOW, Instant::now()),
            client,
            topics,
            extra_filters: Vec::new(),
        }
    }

    /// Hands rumqttc what the outbox says, until it says wait or rumqttc's queue is full.
    fn pump(&mut self) {
        let now = Instant::now();
        while let Some(step) = self.outbox.next(now) {
            match step {
                Step::Send(e) => {
                    let corr = e.correlation.as_deref();
                    if self
                        .client
                        .publish(e.topic, e.qos, e.retain, e.payload, corr)
                        .is_err()
                    {
                        self.outbox.refused(); // more when it sends
                        break;
                    }
                }
                Step::Dropped { topic, why } => {
                    tracing::error!(%topic, "message dropped, it can never be sent: {why}");
                }
            }
        }
    }

    fn enqueue(&mut self, message: Message) {
        if let Err(e) = self.outbox.enqueue(message) {
            tracing::error!("{e}");
        }
        self.pump();
    }

    /// A publish outside the outbox (boot marker, gateway status).
    fn publish_direct(&mut self, topic: String, payload: &'static str) {
        self.outbox.direct();
        let _ = self.client.publish(topic, 1, true, payload.into(), None);
    }

    fn subscribe(&self, filter: &str) {
        if let Err(e) = self.client.subscribe(filter.to_string()) {
            tracing::error!("cannot subscribe to {filter}: {e}");
        }
    }

    /// Connected: say so before the backlog, restore subscriptions (clean session), send.
    fn on_connack(&mut self, max_packet: Option<u32>, link: &Connection) {
        self.outbox.connected(max_packet, Instant::now());
        // The boot marker: subscribe first, so the retained one of another gateway arrives
        // before ours replaces it.
        let marker = self.topics.gateway_marker();
        self.subscribe(&marker);
        let boot = link.boot.marker(&link.client_id);
        self.outbox.direct();
        let _ = self.client.publish(marker, 1, true, boot.into(), None);
        self.publish_direct(self.topics.gateway_status(), "online");
        if link.commands {
            let filters = self.topics.command_filters();
            if let Err(e) = self.client.subscribe_commands(&filters) {
                tracing::error!("cannot subscribe to command topics: {e}");
            }
        }
        for f in &self.extra_filters {
            self.subscribe(f);
        }
        self.pump();
    }

    /// The connection failed: everything rumqttc held goes with it (the outbox sends it again,
    /// in order, on the fresh connection).
    fn on_lost(&mut self, options: &Options) -> EventLoop {
        self.outbox.lost();
        let (client, fresh) = options.connect(WINDOW + 64);
        self.client = client;
        fresh
    }
}

fn lock(shell: &Mutex<Shell>) -> MutexGuard<'_, Shell> {
    shell.lock().unwrap_or_else(|e| e.into_inner())
}

/// The client options of this gateway: a fresh client is built from them after every failure.
/// TLS that cannot be set up is an error: the gateway never falls back to plaintext.
pub fn client_options(config: &Mqtt, topics: &Topics) -> Result<Options, super::tls::TlsError> {
    let login = config.username.as_ref().map(|user| {
        let password = config.password.as_ref().map(|p| p.0.clone());
        (user.clone(), password.unwrap_or_default())
    });
    let transport = match &config.tls {
        Some(tls) => Some(Transport::tls_with_config(TlsConfiguration::Rustls(
            super::tls::client_config(tls)?,
        ))),
        None => None,
    };
    Ok(Options::new(Settings {
        protocol: config.protocol,
        client_id: &config.client_id,
        host: &config.host,
        port: config.port,
        keep_alive: config.keep_alive,
        max_incoming: MAX_PACKET,
        inflight: INFLIGHT,
        will: (topics.gateway_status(), "offline"),
        login,
        transport,
    }))
}

/// What the MQTT task is given, besides its channels.
pub struct Task {
    pub config: Mqtt,
    pub spool_dir: PathBuf,
    /// How often the spool is flushed (spilled to disk while the broker is away).
    pub flush_every: Duration,
    pub heart: Heart,
    pub health: Arc<crate::health::Health>,
    pub boot: crate::boot::Boot,
    pub metrics: crate::metrics::Metrics,
}

/// Runs MQTT until the bus output closes (after `shutdown`), then spools what is left, publishes
/// the gateway offline and disconnects.
pub async fn run(
    task: Task,
    mut output: UnboundedReceiver<Output>,
    incoming: Sender<Incoming>,
    shutdown: CancellationToken,
) {
    let topics = Topics::new(&task.config.topic_root);
    let Some((options, spool)) = start(&task, &topics).await else {
        // `check` and the start refuse such a config; a file changed since is fatal too.
        shutdown.cancel();
        task.heart.set_up(false);
        while output.recv().await.is_some() {}
        return;
    };
    let (client, eventloop) = options.connect(WINDOW + 64);
    let shell = Arc::new(Mutex::new(Shell::new(spool, client, topics)));
    let loop_stop = CancellationToken::new();
    let rebuild = Arc::new(tokio::sync::Notify::new());
    let link = Connection {
        options,
        broker: format!("{}:{}", task.config.host, task.config.port),
        client_id: task.config.client_id.clone(),
        commands: task.config.commands,
        boot: task.boot.clone(),
    };
    let events = tokio::spawn(drive(
        eventloop,
        link,
        shell.clone(),
        incoming,
        loop_stop.clone(),
        rebuild.clone(),
    ));
    let format = super::format::build(&task.config);
    publish(&task, &*format, &shell, &rebuild, &mut output).await;
    let _ = shutdown; // The buses end the loop by closing `output` once they have finished.
    finish(&shell).await;
    if tokio::time::timeout(Duration::from_secs(1), events)
        .await
        .is_err()
    {
        loop_stop.cancel();
    }
}

/// The client options and the spool, or `None` (logged) when the gateway cannot publish.
async fn start(task: &Task, topics: &Topics) -> Option<(Options, Spool)> {
    let options = match client_options(&task.config, topics) {
        Ok(o) => o,
        Err(e) => {
            tracing::error!("MQTT TLS cannot be set up: {e}; stopping (never plaintext)");
            return None;
        }
    };
    let spool = open_spool(task.spool_dir.clone(), task.config.spool_bytes).await?;
    if !spool.is_empty() {
        tracing::info!(
            messages = spool.len(),
            "spooled messages from the last run will be sent first"
        );
    }
    Some((options, spool))
}

/// Opens the spool off the runtime thread (a large one left by the last run must not hold up
/// the buses); a temporary directory when its own cannot be used.
async fn open_spool(dir: PathBuf, bytes: u64) -> Option<Spool> {
    let opened = tokio::task::spawn_blocking(move || match Spool::open(&dir, bytes) {
        Ok(s) => Ok(s),
        Err(e) => {
            tracing::error!("{e}; spooling in a temporary directory instead");
            let dir = std::env::temp_dir().join(format!("pulsegate-spool-{}", std::process::id()));
            Spool::open(&dir, bytes)
        }
    })
    .await;
    match opened {
        Ok(Ok(s)) => Some(s),
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

/// The publisher: bus output through the output stage into the outbox, a health beat every
/// second, the spool flushed every `flush_every`; until the output closes.
async fn publish(
    task: &Task,
    format: &dyn Format,
    shell: &Mutex<Shell>,
    rebuild: &tokio::sync::Notify,
    output: &mut UnboundedReceiver<Output>,
) {
    let stall_after = task.config.keep_alive.max(Duration::from_secs(10));
    let mut flush = tokio::time::interval(task.flush_every);
    let mut beat = tokio::time::interval(Duration::from_secs(1));
    loop {
        task.heart.beat();
        tokio::select! {
            out = output.recv() => match out {
                Some(out) => handle(task, format, shell, out),
                None => return,
            },
            _ = beat.tick() => {
                let mut s = lock(shell);
                let now = Instant::now();
                if s.outbox.stalled(now, stall_after) {
                    tracing::warn!(in_flight = s.outbox.in_flight(), "MQTT broker acknowledged nothing for {}s: reconnecting with a fresh client", stall_after.as_secs());
                    s.outbox.lost();
                    rebuild.notify_one();
                }
                let up = s.outbox.is_connected();
                task.heart.set_up(up);
                let spool = s.outbox.store();
                task.metrics.mqtt(up, spool.len(), spool.total_bytes(), spool.dropped);
            }
            _ = flush.tick() => {
                let mut s = lock(shell);
                // While the broker is away, memory is written out so a crash loses little.
                let up = s.outbox.is_connected();
                let spool = s.outbox.store_mut();
                if let Err(e) = if up { spool.flush() } else { spool.spill() } {
                    tracing::error!("{e}");
                }
            }
        }
    }
}

/// One event from the buses or the router: its side effects on health and metrics, then its
/// messages into the outbox.
fn handle(task: &Task, format: &dyn Format, shell: &Mutex<Shell>, out: Output) {
    match &out {
        Output::Subscribe(filter) => {
            let mut s = lock(shell);
            if s.outbox.is_connected() {
                s.subscribe(filter);
            }
            s.extra_filters.push(filter.clone());
            return;
        }
        Output::DeviceStatus { device, online } => task.health.device(device, *online),
        Output::DeviceProblem { device, .. } => task.health.device(device, false),
        Output::CommandResult { payload, .. } => task.metrics.command_result(payload),
        _ => {}
    }
    let messages = render(format, &out);
    let mut s = lock(shell);
    for m in messages {
        s.enqueue(m);
    }
}

/// Gives the broker a moment to take what is in flight, keeps the rest for next time, publishes
/// the gateway offline and waits (off the runtime thread) for the spool's last writes.
async fn finish(shell: &Mutex<Shell>) {
    let deadline = tokio::time::Instant::now() + Duration::from_millis(1500);
    while tokio::time::Instant::now() < deadline {
        let drained = {
            let s = lock(shell);
            !s.outbox.is_connected() || s.outbox.store().is_empty()
        };
        if drained {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let synced = {
        let mut s = lock(shell);
        if let Err(e) = s.outbox.store_mut().spill() {
            tracing::error!("{e}");
        }
        if !s.outbox.store().is_empty() {
            let messages = s.outbox.store().len();
            tracing::info!(messages, "unsent messages kept for the next start");
        }
        if s.outbox.is_connected() {
            let status = s.topics.gateway_status();
            s.publish_direct(status, "offline");
            let _ = s.client.disconnect();
        }
        s.outbox.store().barrier()
    };
    // The spool's last writes reach the disk before the process ends.
    let _ = tokio::task::spawn_blocking(move || synced.recv_timeout(Duration::from_secs(3))).await;
}

/// What the event loop needs to build a fresh client.
struct Connection {
    options: Options,
    broker: String,
    client_id: String,
    /// Subscribe to command topics (`mqtt.commands`).
    commands: bool,
    /// This run's boot id, published retained on `<root>/gateway`.
    boot: crate::boot::Boot,
}

/// Logs of the connection: once per state change, takeovers at most once a minute.
struct Watch {
    up: Option<bool>,
    takeovers: u64,
    takeover_log: crate::admission::LogBudget,
    /// Wait before the next attempt after a failure.
    pause: Duration,
}

/// Drives the connection; logs once per state change; after any failure builds a fresh client
/// (rumqttc keeps collision state and queued requests across its own reconnects). Forwards
/// command messages, waiting when the router is behind (TCP then pushes back on the sender).
async fn drive(
    mut eventloop: EventLoop,
    link: Connection,
    shell: Arc<Mutex<Shell>>,
    incoming: Sender<Incoming>,
    stop: CancellationToken,
    rebuild: Arc<tokio::sync::Notify>,
) {
    let mut watch = Watch {
        up: None,
        takeovers: 0,
        takeover_log: crate::admission::LogBudget::new(1),
        pause: Duration::from_secs(1),
    };
    loop {
        let event = tokio::select! {
            e = eventloop.poll() => e,
            () = rebuild.notified() => Err(Failure::Other("no acknowledgement: connection stalled".into())),
            () = stop.cancelled() => return,
        };
        match event {
            Ok(Event::ConnAck { max_packet }) => {
                if watch.up != Some(true) {
                    tracing::info!(broker = %link.broker, "connected to MQTT broker");
                }
                watch.up = Some(true);
                lock(&shell).on_connack(max_packet, &link);
            }
            Ok(Event::Sent(pkid)) => {
                let mut s = lock(&shell);
                s.outbox.sent(pkid);
                s.pump();
            }
            Ok(Event::Acked(pkid)) => {
                watch.pause = Duration::from_secs(1);
                let mut s = lock(&shell);
                s.outbox.acked(pkid, Instant::now());
                s.pump();
            }
            Ok(Event::Received(p)) => received(p, &link, &shell, &incoming, &mut watch).await,
            Ok(Event::Disconnected) => return,
            Ok(Event::Other) => {}
            Err(Failure::RequestsDone) => return,
            Err(e) => {
                failed(&e, &link, &mut watch);
                eventloop = lock(&shell).on_lost(&link.options);
                tokio::select! {
                    () = tokio::time::sleep(watch.pause) => {}
                    () = stop.cancelled() => return,
                }
            }
        }
    }
}

/// A message that arrived: another gateway's boot marker is logged, the rest goes to the router.
async fn received(
    p: Received,
    link: &Connection,
    shell: &Mutex<Shell>,
    incoming: &Sender<Incoming>,
    watch: &mut Watch,
) {
    if *p.topic == *lock(shell).topics.gateway_marker().as_bytes() {
        if let Some(other) = link.boot.foreign(&p.payload) {
            let (log, _) = watch.takeover_log.allow(Instant::now());
            if log {
                tracing::error!(other = %other, "another gateway publishes under this topic root (its boot marker is not ours): two gateways share gateway.id or mqtt.topic_root, so both receive each other's commands and, with one client id, take each other's MQTT session; give each gateway its own id");
            }
        }
        return;
    }
    let msg = Incoming {
        topic: String::from_utf8_lossy(&p.topic).into_owned(),
        payload: p.payload,
        retain: p.retain,
        response_topic: p.response_topic,
        correlation: p.correlation,
    };
    if incoming.send(msg).await.is_err() {
        tracing::debug!("command router gone");
    }
}

/// A connection failure: logged once per state change (takeovers each time, within budget);
/// a takeover backs off so two gateways do not fight over the id every second.
fn failed(e: &Failure, link: &Connection, watch: &mut Watch) {
    if matches!(e, Failure::TakenOver) {
        watch.takeovers += 1;
        let (log, _) = watch.takeover_log.allow(Instant::now());
        if log {
            tracing::error!(client_id = %link.client_id, takeovers = watch.takeovers, "the broker dropped this connection because another client connected with the same client id: is a second gateway using mqtt.client_id {:?}? Both would receive each other's commands", link.client_id);
        }
        watch.pause = (watch.pause * 2).clamp(Duration::from_secs(5), Duration::from_secs(60));
    } else if watch.up != Some(false) {
        tracing::warn!(broker = %link.broker, "MQTT broker unreachable: {e}; reconnecting with a fresh client, readings are spooled");
    }
    watch.up = Some(false);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wildcard_topic_can_never_be_sent() {
        assert!(unsendable("evil/#", 10, 0, None).is_some());
        assert!(unsendable("a/+/b", 10, 0, None).is_some());
        assert!(unsendable("", 10, 0, None).is_some());
        assert!(unsendable("pulsegate/e1/press/enc0", 100, 0, None).is_none());
    }

    /// A connected shell with a client whose requests go nowhere (its event loop is returned to
    /// keep the queue open, never polled).
    fn shell(name: &str) -> (Shell, EventLoop) {
        let dir =
            std::env::temp_dir().join(format!("pulsegate-mqtt-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (client, eventloop) = Options::new(Settings {
            protocol: crate::config::MqttProtocol::V5,
            client_id: "t",
            host: "127.0.0.1",
            port: 1,
            keep_alive: Duration::from_secs(30),
            max_incoming: MAX_PACKET,
            inflight: INFLIGHT,
            will: ("pg/t/status".into(), "offline"),
            login: None,
            transport: None,
        })
        .connect(10);
        let mut shell = Shell::new(
            Spool::open(&dir, 1 << 20).unwrap(),
            client,
            Topics::new("pg/t"),
        );
        shell.outbox.connected(None, Instant::now());
        (shell, eventloop)
    }

    fn message(topic: &str) -> Message {
        Message::new(topic.into(), "{}", 1, false)
    }

    /// What rumqttc does after a packet-id collision: the publish was taken but nothing is
    /// acknowledged any more, while pings go on. The gateway counts that as not publishing.
    #[test]
    fn messages_in_flight_without_an_acknowledgement_for_too_long_are_a_stalled_connection() {
        let (mut s, _requests) = shell("stall");
        s.enqueue(message("pg/t/d/enc0"));
        assert_eq!(s.outbox.in_flight(), 1);
        let limit = Duration::from_secs(10);
        let now = Instant::now();
        assert!(!s.outbox.stalled(now, limit));
        let later = now + Duration::from_secs(11);
        assert!(
            s.outbox.stalled(later, limit),
            "nothing acknowledged for 11 s"
        );
        s.outbox.sent(1);
        s.outbox.acked(1, later);
        s.pump();
        assert_eq!(s.outbox.in_flight(), 0);
        assert!(!s.outbox.stalled(later, limit), "acknowledged: publishing");
    }

    #[test]
    fn an_unsendable_message_is_dropped_and_the_next_one_sent() {
        let (mut s, _requests) = shell("unsendable");
        s.enqueue(message("evil/#"));
        s.enqueue(message("pg/t/ok"));
        assert_eq!(s.outbox.store().len(), 1, "the wildcard one is gone");
        assert_eq!(s.outbox.in_flight(), 1);
        assert_eq!(s.outbox.store_mut().get(0).unwrap().topic, "pg/t/ok");
    }

    #[test]
    fn a_message_larger_than_the_broker_takes_can_never_be_sent() {
        assert!(unsendable("t", 2000, 0, Some(1024)).is_some());
        assert!(unsendable("t", 200, 900, Some(1024)).is_some());
        assert!(unsendable("t", 200, 0, Some(1024)).is_none());
    }
}
