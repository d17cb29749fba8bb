//! The MQTT shell (rumqttc, MQTT v5).
//!
//! Every message goes through the [`Spool`] and leaves it only when the broker acknowledges it.
//! rumqttc forgets unacknowledged messages when it reconnects with a clean session, so it is
//! never trusted with more than a small window: after a connection error the gateway takes back
//! whatever rumqttc still held and sends it again, in order, once the broker is back.
//!
//! Two tasks: the event loop only drives the connection (it never awaits a publish: that can
//! deadlock rumqttc); the publisher turns bus output into spooled messages. The buses hand
//! output over an unbounded channel: they never wait on MQTT.

use std::collections::VecDeque;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::{Filter, LastWill, Packet, PublishProperties, RetainForwardRule};
use rumqttc::v5::{AsyncClient, Event, EventLoop, MqttOptions, Request};
use rumqttc::{TlsConfiguration, Transport};
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};
use tokio_util::sync::CancellationToken;

use super::payload;
use super::spool::Spool;
use super::topics::Topics;
use crate::config::{Mqtt, Tls};
use crate::dispatch::Incoming;
use crate::health::Heart;
use crate::reading::Output;

/// Messages handed to rumqttc before their acknowledgement.
const WINDOW: usize = 100;

fn qos(level: u8) -> QoS {
    match level {
        0 => QoS::AtMostOnce,
        2 => QoS::ExactlyOnce,
        _ => QoS::AtLeastOnce,
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
    /// Publishes outside the spool (gateway status) whose send event is still to come.
    direct: usize,
    client: AsyncClient,
    topics: Topics,
}

impl Shared {
    /// Hands rumqttc the next spooled messages, up to the window.
    fn pump(&mut self) {
        while self.connected && self.inflight.len() < WINDOW {
            let i = self.inflight.len();
            let Some(e) = self.spool.get(i) else { break };
            let sent = match &e.correlation {
                Some(c) => {
                    let props = PublishProperties {
                        correlation_data: Some(c.clone().into()),
                        ..Default::default()
                    };
                    self.client.try_publish_with_properties(
                        e.topic.clone(),
                        qos(e.qos),
                        e.retain,
                        e.payload.clone(),
                        props,
                    )
                }
                None => self.client.try_publish(
                    e.topic.clone(),
                    qos(e.qos),
                    e.retain,
                    e.payload.clone(),
                ),
            };
            if sent.is_err() {
                break;
            }
            self.inflight.push_back(InFlight {
                pkid: None,
                acked: false,
            });
        }
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
        let n = self.inflight.iter().take_while(|f| f.acked).count();
        if n > 0 {
            self.inflight.drain(..n);
            self.spool.ack_front(n);
        }
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

/// Runs MQTT until the bus output closes (after `shutdown`), then spools what is left, publishes
/// the gateway offline and disconnects.
/// TLS to the broker with rustls: the broker's certificate must chain to `ca_file`; a client
/// certificate is presented when configured.
fn tls_transport(tls: &Tls) -> Result<Transport, String> {
    // One process-wide crypto provider (ring: pure Rust and C, no system library needed).
    let _ = rustls::crypto::ring::default_provider().install_default();
    let read = |p: &Path| std::fs::read(p).map_err(|e| format!("cannot read {}: {e}", p.display()));
    let ca = read(&tls.ca_file)?;
    let client_auth = match (&tls.cert_file, &tls.key_file) {
        (Some(c), Some(k)) => Some((read(c)?, read(k)?)),
        _ => None,
    };
    Ok(Transport::tls_with_config(TlsConfiguration::Simple {
        ca,
        alpn: None,
        client_auth,
    }))
}

#[allow(clippy::too_many_arguments)] // the task's whole world, wired once by the app
pub async fn run(
    config: Mqtt,
    spool_dir: &Path,
    flush_every: Duration,
    mut output: UnboundedReceiver<Output>,
    incoming: UnboundedSender<Incoming>,
    heart: Heart,
    health: std::sync::Arc<crate::health::Health>,
    shutdown: CancellationToken,
) {
    let topics = Topics::new(&config.topic_root);
    let mut options = MqttOptions::new(config.client_id.clone(), config.host.clone(), config.port);
    options.set_keep_alive(config.keep_alive);
    options.set_last_will(LastWill::new(
        topics.gateway_status(),
        "offline",
        QoS::AtLeastOnce,
        true,
        None,
    ));
    if let Some(user) = &config.username {
        let password = config
            .password
            .as_ref()
            .map(|p| p.0.clone())
            .unwrap_or_default();
        options.set_credentials(user.clone(), password);
    }
    if let Some(tls) = &config.tls {
        match tls_transport(tls) {
            Ok(t) => {
                options.set_transport(t);
            }
            Err(e) => tracing::error!("MQTT TLS: {e}; the connection will fail until it is fixed"),
        }
    }
    let (client, eventloop) = AsyncClient::new(options, WINDOW + 64);
    let spool = match Spool::open(spool_dir, config.spool_bytes) {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("{e}; spooling in a temporary directory instead");
            let dir = std::env::temp_dir().join(format!("pulsegate-spool-{}", std::process::id()));
            Spool::open(&dir, config.spool_bytes).expect("temporary spool")
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
        direct: 0,
        client: client.clone(),
        topics: topics.clone(),
    }));
    let loop_stop = CancellationToken::new();
    let broker = format!("{}:{}", config.host, config.port);
    let events = tokio::spawn(drive(
        eventloop,
        shared.clone(),
        incoming,
        loop_stop.clone(),
        broker,
    ));

    let reading_qos = config.qos;
    let mut flush = tokio::time::interval(flush_every);
    let mut beat = tokio::time::interval(Duration::from_secs(1));
    loop {
        heart.beat();
        let out = tokio::select! {
            out = output.recv() => out,
            _ = beat.tick() => {
                heart.set_up(lock(&shared).connected);
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
    {
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
            let _ =
                s.client
                    .try_publish(s.topics.gateway_status(), QoS::AtLeastOnce, true, "offline");
            let _ = s.client.try_disconnect();
        }
    }
    if tokio::time::timeout(Duration::from_secs(1), events)
        .await
        .is_err()
    {
        loop_stop.cancel();
    }
}

fn command_filter(topics: &Topics, tail: &str) -> Filter {
    let mut f = Filter::new(format!("{}/{tail}", topics.root()), QoS::AtLeastOnce);
    f.retain_forward_rule = RetainForwardRule::Never;
    f
}

/// Drives the connection; logs once per state change; reconnects after a pause. Forwards
/// command messages without waiting.
async fn drive(
    mut eventloop: EventLoop,
    shared: Arc<Mutex<Shared>>,
    incoming: UnboundedSender<Incoming>,
    stop: CancellationToken,
    broker: String,
) {
    let mut up = None;
    loop {
        let event = tokio::select! {
            e = eventloop.poll() => e,
            () = stop.cancelled() => return,
        };
        match event {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                if up != Some(true) {
                    tracing::info!(%broker, "connected to MQTT broker");
                }
                up = Some(true);
                let mut s = lock(&shared);
                s.connected = true;
                s.spool.set_spilling(false);
                // Say we are here before the backlog; restore subscriptions (clean session).
                s.direct += 1;
                let _ = s.client.try_publish(
                    s.topics.gateway_status(),
                    QoS::AtLeastOnce,
                    true,
                    "online",
                );
                let filters = [
                    command_filter(&s.topics, "+/+/cmd"),
                    command_filter(&s.topics, "+/cmd"),
                ];
                if let Err(e) = s.client.try_subscribe_many(filters) {
                    tracing::error!("cannot subscribe to command topics: {e}");
                }
                s.pump();
            }
            Ok(Event::Outgoing(rumqttc::Outgoing::Publish(pkid))) => lock(&shared).sent(pkid),
            Ok(Event::Incoming(Packet::PubAck(ack))) => lock(&shared).acked(ack.pkid),
            Ok(Event::Incoming(Packet::PubComp(comp))) => lock(&shared).acked(comp.pkid),
            Ok(Event::Incoming(Packet::Publish(p))) => {
                let props = p.properties.unwrap_or_default();
                let _ = incoming.send(Incoming {
                    topic: String::from_utf8_lossy(&p.topic).into_owned(),
                    payload: p.payload,
                    retain: p.retain,
                    response_topic: props.response_topic,
                    correlation: props.correlation_data,
                });
            }
            Ok(Event::Outgoing(rumqttc::Outgoing::Disconnect)) => return,
            Ok(_) => {}
            Err(rumqttc::v5::ConnectionError::RequestsDone) => return,
            Err(e) => {
                if up != Some(false) {
                    tracing::warn!(%broker, "MQTT broker unreachable: {e}; retrying, readings are spooled");
                }
                up = Some(false);
                {
                    let mut s = lock(&shared);
                    s.connected = false;
                    s.spool.set_spilling(true);
                    // Take back everything rumqttc holds: with a clean session it would drop it
                    // at reconnect anyway. The spool sends it again, in order.
                    eventloop.clean();
                    eventloop
                        .pending
                        .retain(|r| !matches!(r, Request::Publish(_) | Request::PubAck(_)));
                    s.inflight.clear();
                    s.direct = 0;
                }
                tokio::select! {
                    () = tokio::time::sleep(Duration::from_secs(1)) => {}
                    () = stop.cancelled() => return,
                }
            }
        }
    }
}
