//! The MQTT shell (rumqttc; MQTT 5 or 3.1.1 through [`super::session`]).
//!
//! Every message goes through the [`Spool`] and leaves it only when the broker acknowledges it.
//! rumqttc forgets unacknowledged messages when it reconnects with a clean session, so it is
//! never trusted with more than a small window: after a connection error the gateway takes back
//! whatever rumqttc still held and sends it again, in order, once the broker is back.
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
//! deadlock rumqttc); the publisher turns bus output into spooled messages. The buses hand
//! output over an unbounded channel: they never wait on MQTT.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use rumqttc::{TlsConfiguration, Transport};
use tokio::sync::mpsc::{Sender, UnboundedReceiver};
use tokio_util::sync::CancellationToken;

use super::payload;
use super::session::{Client, Event, EventLoop, Failure, Options, Settings};
use super::spool::Spool;
use super::topics::Topics;
use crate::config::Mqtt;
use crate::dispatch::Incoming;
use crate::health::Heart;
use crate::reading::Output;

/// Messages handed to rumqttc before their acknowledgement.
const WINDOW: usize = 100;

/// The largest MQTT packet the gateway takes, announced to the broker in CONNECT (so it never
/// sends a larger one) and given to rumqttc as its incoming limit (its default, 10 KiB, would
/// disconnect at the first larger command). Commands are refused above 1 KiB anyway.
pub const MAX_PACKET: u32 = 64 * 1024;

/// Why a spooled message can never be sent, if it can't: it would block the spool forever.
pub fn unsendable(
    topic: &str,
    payload: usize,
    correlation: usize,
    broker_max: Option<u32>,
) -> Option<String> {
    if !rumqttc::valid_topic(topic) || topic.is_empty() || topic.len() > usize::from(u16::MAX) {
        return Some("not a topic one can publish to (empty, too long or a wildcard)".into());
    }
    // Fixed header (≤ 5), topic, packet id, properties (correlation data), payload.
    let size =
        5 + 2 + topic.len() + 2 + 5 + if correlation > 0 { 3 + correlation } else { 0 } + payload;
    match broker_max {
        Some(max) if size > max as usize => Some(format!(
            "{size} bytes, more than the broker's maximum packet size of {max}"
        )),
        _ => None,
    }
}

/// A message handed to rumqttc, waiting for its acknowledgement.
#[derive(Debug, Clone, Copy)]
struct InFlight {
    pkid: Option<u16>,
    acked: bool,
}

/// State shared by the publisher and the event loop.
struct Shared {
    spool: Spool,
    /// The spool's oldest messages that rumqttc has, in order.
    inflight: VecDeque<InFlight>,
    connected: bool,
    /// The broker's maximum packet size (CONNACK), if it announced one.
    broker_max: Option<u32>,
    /// The last time the broker acknowledged something, or the window was empty.
    progress: std::time::Instant,
    /// Publishes outside the spool (gateway status) whose send event is still to come.
    direct: usize,
    client: Client,
    topics: Topics,
    /// Filters asked for with [`Output::Subscribe`], renewed at every connection.
    extra_filters: Vec<String>,
}

impl Shared {
    /// Hands rumqttc the next spooled messages, up to the window. A message that can never be
    /// sent is dropped with an error (counted as acknowledged, so order and the window hold).
    fn pump(&mut self) {
        loop {
            let n = self.inflight.iter().take_while(|f| f.acked).count();
            if n > 0 {
                self.inflight.drain(..n);
                self.spool.ack_front(n);
            }
            if self.inflight.is_empty() {
                self.progress = std::time::Instant::now();
            }
            let mut skipped = false;
            while self.connected && self.inflight.len() < WINDOW {
                let i = self.inflight.len();
                let broker_max = self.broker_max;
                let Some(e) = self.spool.get(i) else { break };
                let corr = e.correlation.as_ref().map_or(0, Vec::len);
                if let Some(why) = unsendable(&e.topic, e.payload.len(), corr, broker_max) {
                    let topic: String = e.topic.chars().take(200).collect();
                    tracing::error!(%topic, "message dropped, it can never be sent: {why}");
                    self.inflight.push_back(InFlight {
                        pkid: Some(0),
                        acked: true,
                    });
                    skipped = true;
                    continue;
                }
                if !self.send(i) {
                    break; // rumqttc's queue is full: more when it sends
                }
                self.inflight.push_back(InFlight {
                    pkid: None,
                    acked: false,
                });
            }
            if !skipped {
                break;
            }
        }
    }

    /// Hands the spool's `i`-th message to rumqttc; `false` when its queue is full.
    fn send(&mut self, i: usize) -> bool {
        let Some(e) = self.spool.get(i) else {
            return true;
        };
        self.client
            .publish(
                e.topic.clone(),
                e.qos,
                e.retain,
                e.payload.clone(),
                e.correlation.as_deref(),
            )
            .is_ok()
    }

    /// Messages are in flight and the broker has acknowledged nothing for `limit`: the
    /// connection is not publishing, whatever the socket says.
    fn stalled(&self, limit: Duration) -> bool {
        self.connected && self.inflight.iter().any(|f| !f.acked) && self.progress.elapsed() > limit
    }

    /// rumqttc sent a publish with `pkid` (0 for QoS 0).
    fn sent(&mut self, pkid: u16) {
        if self.direct > 0 {
            self.direct -= 1;
            return;
        }
        if let Some(f) = self.inflight.iter_mut().find(|f| f.pkid.is_none()) {
            f.pkid = Some(pkid);
            f.acked = pkid == 0;
        }
        self.release();
    }

    /// The broker acknowledged `pkid`.
    fn acked(&mut self, pkid: u16) {
        self.progress = std::time::Instant::now();
        if let Some(f) = self
            .inflight
            .iter_mut()
            .find(|f| f.pkid == Some(pkid) && !f.acked)
        {
            f.acked = true;
        }
        self.release();
    }

    fn release(&mut self) {
        self.pump();
    }

    fn push(
        &mut self,
        topic: String,
        body: String,
        qos: u8,
        retain: bool,
        correlation: Option<Vec<u8>>,
    ) {
        if let Err(e) = self.spool.push(topic, body, qos, retain, correlation) {
            tracing::error!("{e}");
        }
        self.pump();
    }
}

fn lock(shared: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(|e| e.into_inner())
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
        will: (topics.gateway_status(), "offline"),
        login,
        transport,
    }))
}

/// Runs MQTT until the bus output closes (after `shutdown`), then spools what is left, publishes
/// the gateway offline and disconnects.
#[allow(clippy::too_many_arguments)] // the task's whole world, wired once by the app
pub async fn run(
    config: Mqtt,
    spool_dir: &Path,
    flush_every: Duration,
    mut output: UnboundedReceiver<Output>,
    incoming: Sender<Incoming>,
    heart: Heart,
    health: std::sync::Arc<crate::health::Health>,
    boot: crate::boot::Boot,
    metrics: crate::metrics::Metrics,
    shutdown: CancellationToken,
) {
    let topics = Topics::new(&config.topic_root);
    let options = match client_options(&config, &topics) {
        Ok(o) => o,
        Err(e) => {
            // `check` and the start refuse such a config; a file changed since is fatal too.
            tracing::error!("MQTT TLS cannot be set up: {e}; stopping (never plaintext)");
            shutdown.cancel();
            heart.set_up(false);
            while output.recv().await.is_some() {}
            return;
        }
    };
    let (client, eventloop) = options.connect(WINDOW + 64);
    // Reading a large spool left by the last run must not hold up the buses.
    let (dir, bytes) = (spool_dir.to_path_buf(), config.spool_bytes);
    let opened = tokio::task::spawn_blocking(move || match Spool::open(&dir, bytes) {
        Ok(s) => Ok(s),
        Err(e) => {
            tracing::error!("{e}; spooling in a temporary directory instead");
            let dir = std::env::temp_dir().join(format!("pulsegate-spool-{}", std::process::id()));
            Spool::open(&dir, bytes)
        }
    })
    .await;
    let spool = match opened {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => {
            tracing::error!("{e}; no spool at all: stopping");
            shutdown.cancel();
            while output.recv().await.is_some() {}
            return;
        }
        Err(e) => {
            tracing::error!("spool open task failed: {e}; stopping");
            shutdown.cancel();
            while output.recv().await.is_some() {}
            return;
        }
    };
    if !spool.is_empty() {
        tracing::info!(
            messages = spool.len(),
            "spooled messages from the last run will be sent first"
        );
    }
    let shared = Arc::new(Mutex::new(Shared {
        spool,
        inflight: VecDeque::new(),
        connected: false,
        broker_max: None,
        progress: std::time::Instant::now(),
        direct: 0,
        client,
        topics: topics.clone(),
        extra_filters: Vec::new(),
    }));
    let loop_stop = CancellationToken::new();
    let rebuild = Arc::new(tokio::sync::Notify::new());
    let link = Connection {
        options,
        broker: format!("{}:{}", config.host, config.port),
        client_id: config.client_id.clone(),
        commands: config.commands,
        boot,
    };
    let events = tokio::spawn(drive(
        eventloop,
        link,
        shared.clone(),
        incoming,
        loop_stop.clone(),
        rebuild.clone(),
    ));

    let reading_qos = config.qos;
    let stall_after = config.keep_alive.max(Duration::from_secs(10));
    let mut flush = tokio::time::interval(flush_every);
    let mut beat = tokio::time::interval(Duration::from_secs(1));
    loop {
        heart.beat();
        let out = tokio::select! {
            out = output.recv() => out,
            _ = beat.tick() => {
                let mut s = lock(&shared);
                if s.stalled(stall_after) {
                    tracing::warn!(in_flight = s.inflight.len(), "MQTT broker acknowledged nothing for {}s: reconnecting with a fresh client", stall_after.as_secs());
                    s.connected = false;
                    rebuild.notify_one();
                }
                heart.set_up(s.connected);
                metrics.mqtt(s.connected, s.spool.len(), s.spool.total_bytes(), s.spool.dropped);
                continue;
            }
            _ = flush.tick() => {
                let mut s = lock(&shared);
                // While the broker is away, memory is written out so a crash loses little.
                let result = if s.connected { s.spool.flush() } else { s.spool.spill() };
                if let Err(e) = result {
                    tracing::error!("{e}");
                }
                continue;
            }
        };
        let Some(out) = out else { break };
        let (topic, retain, qos, body, correlation) = match out {
            Output::Reading(r) => (
                topics.reading(&r.device, &r.channel),
                config.retain,
                reading_qos,
                payload::reading(&r),
                None,
            ),
            Output::DeviceReadings { device, readings } => (
                topics.device(&device),
                config.retain,
                reading_qos,
                payload::device(&readings),
                None,
            ),
            Output::Message {
                topic,
                payload,
                retain,
            } => (topic, retain, 1, payload, None),
            Output::Subscribe(filter) => {
                let mut s = lock(&shared);
                if s.connected
                    && let Err(e) = s.client.subscribe(filter.clone())
                {
                    tracing::error!("cannot subscribe to {filter}: {e}");
                }
                s.extra_filters.push(filter);
                continue;
            }
            Output::DeviceStatus { device, online } => {
                health.device(&device, online);
                (
                    topics.device_status(&device),
                    true,
                    1,
                    if online { "online" } else { "offline" }.to_string(),
                    None,
                )
            }
            Output::DeviceProblem { device, status } => {
                health.device(&device, false);
                (
                    topics.device_status(&device),
                    true,
                    1,
                    status.to_string(),
                    None,
                )
            }
            Output::BusStats { bus, stats } => {
                if !lock(&shared).connected {
                    continue; // Health is of the moment: not worth spooling.
                }
                (topics.bus_stats(&bus), false, 0, stats.to_string(), None)
            }
            Output::CommandResult {
                topics: to,
                correlation,
                payload,
            } => {
                metrics.command_result(&payload);
                let mut s = lock(&shared);
                for (i, t) in to.into_iter().enumerate() {
                    // The MQTT v5 response topic (after the result topic) gets the request's
                    // correlation data back.
                    let c = if i > 0 {
                        correlation.as_ref().map(|c| c.to_vec())
                    } else {
                        None
                    };
                    s.push(t, payload.to_string(), 1, false, c);
                }
                continue;
            }
        };
        lock(&shared).push(topic, body, qos, retain, correlation);
    }
    let _ = shutdown; // The buses end the loop by closing `output` once they have finished.

    // Give the broker a moment to take what is in flight, then keep the rest for next time.
    let deadline = tokio::time::Instant::now() + Duration::from_millis(1500);
    while tokio::time::Instant::now() < deadline {
        let drained = {
            let s = lock(&shared);
            !s.connected || s.spool.is_empty()
        };
        if drained {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let synced = {
        let mut s = lock(&shared);
        if let Err(e) = s.spool.spill() {
            tracing::error!("{e}");
        }
        if !s.spool.is_empty() {
            tracing::info!(
                messages = s.spool.len(),
                "unsent messages kept for the next start"
            );
        }
        if s.connected {
            s.direct += 1;
            let status = s.topics.gateway_status();
            let _ = s.client.publish(status, 1, true, "offline".into(), None);
            let _ = s.client.disconnect();
        }
        s.spool.barrier()
    };
    // The spool's last writes reach the disk before the process ends.
    let _ = tokio::task::spawn_blocking(move || synced.recv_timeout(Duration::from_secs(3))).await;
    if tokio::time::timeout(Duration::from_secs(1), events)
        .await
        .is_err()
    {
        loop_stop.cancel();
    }
}

fn command_filter(topics: &Topics, tail: &str) -> String {
    format!("{}/{tail}", topics.root())
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

/// Drives the connection; logs once per state change; after any failure builds a fresh client
/// (rumqttc keeps collision state and queued requests across its own reconnects). Forwards
/// command messages, waiting when the router is behind (TCP then pushes back on the sender).
async fn drive(
    mut eventloop: EventLoop,
    link: Connection,
    shared: Arc<Mutex<Shared>>,
    incoming: Sender<Incoming>,
    stop: CancellationToken,
    rebuild: Arc<tokio::sync::Notify>,
) {
    let mut up = None;
    let mut takeovers: u64 = 0;
    let mut takeover_log = crate::admission::LogBudget::new(1);
    let mut pause = Duration::from_secs(1);
    loop {
        let event = tokio::select! {
            e = eventloop.poll() => e,
            () = rebuild.notified() => Err(Failure::Other("no acknowledgement: connection stalled".into())),
            () = stop.cancelled() => return,
        };
        match event {
            Ok(Event::ConnAck { max_packet }) => {
                if up != Some(true) {
                    tracing::info!(broker = %link.broker, "connected to MQTT broker");
                }
                up = Some(true);
                let mut s = lock(&shared);
                s.connected = true;
                s.broker_max = max_packet;
                s.progress = std::time::Instant::now();
                s.spool.set_spilling(false);
                // Say we are here before the backlog; restore subscriptions (clean session).
                // The boot marker: subscribe first, so the retained one of another gateway
                // arrives before ours replaces it.
                let marker = s.topics.gateway_marker();
                if let Err(e) = s.client.subscribe(marker.clone()) {
                    tracing::error!("cannot subscribe to {marker}: {e}");
                }
                s.direct += 2;
                let boot = link.boot.marker(&link.client_id);
                let _ = s.client.publish(marker, 1, true, boot.into(), None);
                let status = s.topics.gateway_status();
                let _ = s.client.publish(status, 1, true, "online".into(), None);
                if link.commands {
                    let filters = [
                        command_filter(&s.topics, "+/+/cmd"),
                        command_filter(&s.topics, "+/cmd"),
                        command_filter(&s.topics, "bus/+/scan"),
                    ];
                    if let Err(e) = s.client.subscribe_commands(&filters) {
                        tracing::error!("cannot subscribe to command topics: {e}");
                    }
                }
                for f in s.extra_filters.clone() {
                    if let Err(e) = s.client.subscribe(f.clone()) {
                        tracing::error!("cannot subscribe to {f}: {e}");
                    }
                }
                s.pump();
            }
            Ok(Event::Sent(pkid)) => lock(&shared).sent(pkid),
            Ok(Event::Acked(pkid)) => {
                pause = Duration::from_secs(1);
                lock(&shared).acked(pkid)
            }
            Ok(Event::Received(p))
                if *p.topic == *lock(&shared).topics.gateway_marker().as_bytes() =>
            {
                if let Some(other) = link.boot.foreign(&p.payload) {
                    let (log, _) = takeover_log.allow(std::time::Instant::now());
                    if log {
                        tracing::error!(other = %other, "another gateway publishes under this topic root (its boot marker is not ours): two gateways share gateway.id or mqtt.topic_root, so both receive each other's commands and, with one client id, take each other's MQTT session; give each gateway its own id");
                    }
                }
            }
            Ok(Event::Received(p)) => {
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
            Ok(Event::Disconnected) => return,
            Ok(Event::Other) => {}
            Err(Failure::RequestsDone) => return,
            Err(e) => {
                if matches!(e, Failure::TakenOver) {
                    takeovers += 1;
                    let (log, _) = takeover_log.allow(std::time::Instant::now());
                    if log {
                        tracing::error!(client_id = %link.client_id, takeovers, "the broker dropped this connection because another client connected with the same client id: is a second gateway using mqtt.client_id {:?}? Both would receive each other's commands", link.client_id);
                    }
                    // Do not fight over the id every second.
                    pause = (pause * 2).clamp(Duration::from_secs(5), Duration::from_secs(60));
                } else if up != Some(false) {
                    tracing::warn!(broker = %link.broker, "MQTT broker unreachable: {e}; reconnecting with a fresh client, readings are spooled");
                }
                up = Some(false);
                {
                    let mut s = lock(&shared);
                    s.connected = false;
                    s.spool.set_spilling(true);
                    // Everything rumqttc held is dropped with it; the spool sends it again, in
                    // order, on the fresh connection.
                    s.inflight.clear();
                    s.direct = 0;
                    let (client, fresh) = link.options.connect(WINDOW + 64);
                    s.client = client;
                    eventloop = fresh;
                }
                tokio::select! {
                    () = tokio::time::sleep(pause) => {}
                    () = stop.cancelled() => return,
                }
            }
        }
    }
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

    /// Shared state with a client whose requests go nowhere (its event loop is returned to keep
    /// the queue open, never polled).
    fn shared(name: &str) -> (Shared, EventLoop) {
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
            will: ("pg/t/status".into(), "offline"),
            login: None,
            transport: None,
        })
        .connect(10);
        let shared = Shared {
            spool: Spool::open(&dir, 1 << 20).unwrap(),
            inflight: VecDeque::new(),
            connected: true,
            broker_max: None,
            progress: std::time::Instant::now(),
            direct: 0,
            client,
            topics: Topics::new("pg/t"),
            extra_filters: Vec::new(),
        };
        (shared, eventloop)
    }

    /// What rumqttc does after a packet-id collision: the publish was taken but nothing is
    /// acknowledged any more, while pings go on. The gateway counts that as not publishing.
    #[test]
    fn messages_in_flight_without_an_acknowledgement_for_too_long_are_a_stalled_connection() {
        let (mut s, _requests) = shared("stall");
        s.push("pg/t/d/enc0".into(), "{}".into(), 1, false, None);
        assert_eq!(s.inflight.len(), 1);
        let limit = Duration::from_secs(10);
        assert!(!s.stalled(limit));
        s.progress -= Duration::from_secs(11);
        assert!(s.stalled(limit), "nothing acknowledged for 11 s");
        s.sent(1);
        s.acked(1);
        assert!(s.inflight.is_empty());
        assert!(!s.stalled(limit), "acknowledged: publishing");
    }

    #[test]
    fn an_unsendable_message_is_dropped_and_the_next_one_sent() {
        let (mut s, _requests) = shared("unsendable");
        s.push("evil/#".into(), "{}".into(), 1, false, None);
        s.push("pg/t/ok".into(), "{}".into(), 1, false, None);
        assert_eq!(s.spool.len(), 1, "the wildcard one is gone");
        assert_eq!(s.inflight.len(), 1);
        assert_eq!(s.spool.get(0).unwrap().topic, "pg/t/ok");
    }

    #[test]
    fn a_message_larger_than_the_broker_takes_can_never_be_sent() {
        assert!(unsendable("t", 2000, 0, Some(1024)).is_some());
        assert!(unsendable("t", 200, 900, Some(1024)).is_some());
        assert!(unsendable("t", 200, 0, Some(1024)).is_none());
    }
}
