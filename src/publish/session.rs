//! The MQTT protocol seam: rumqttc's MQTT 5 and MQTT 3.1.1 clients behind one small interface,
//! so the spool, the send window and the reconnect logic in [`super::mqtt`] are written once.
//!
//! What 3.1.1 lacks, and what the gateway does instead:
//! - no response topic or correlation data: command results go to `<command topic>/result` only;
//! - no retain-handling option at subscribe: retained command messages are delivered, flagged
//!   retained, and the router ignores them on receipt (as on v5, where they are also not asked
//!   for);
//! - no maximum packet size in CONNACK: messages larger than [`V311_MAX_OUT`] are refused as
//!   unsendable (rumqttc's own outgoing limit), never retried forever;
//! - no maximum packet size in CONNECT either: the broker sends messages of any size, and the
//!   ones over [`MAX_PACKET`] are skipped by rumqttc as they stream in ([`Event::TooLarge`]);
//! - no "session taken over" reason: the broker just closes the connection.

use bytes::Bytes;
use rumqttc::v5;
use rumqttc::v5::mqttbytes::v5::{
    DisconnectReasonCode, Filter, PublishProperties, RetainForwardRule,
};
use rumqttc::{Outgoing, Transport};

use crate::config::{Mqtt, MqttProtocol};
use rumqttc::TlsConfiguration;

/// Messages handed to rumqttc before their acknowledgement.
pub const WINDOW: usize = 100;

/// rumqttc's own in-flight limit: the outbox's two windows (owed and chatter) plus room for the
/// messages that bypass them (boot marker, what formats say at connect), so rumqttc never has to
/// hold one back.
pub const INFLIGHT: u16 = (WINDOW + crate::outbox::CHATTER_WINDOW) as u16 + 64;

/// Requests rumqttc's queue takes: both windows, and what formats publish at once at a
/// connection (a Sparkplug node's DBIRTH of every device) on top. Allocated as it fills.
pub const REQUESTS: usize = INFLIGHT as usize + 4096;

/// The largest MQTT packet the gateway takes: a message of 256 KiB, and 4 KiB for its topic,
/// properties and header. Announced to an MQTT 5 broker in CONNECT (so it never sends a larger
/// one) and given to rumqttc as its incoming limit on both protocols. A pushed config of up to
/// 256 KiB arrives (its handler refuses what it finds too large, with an answer); commands are
/// refused above 1 KiB. A larger message (a 3.1.1 broker cannot be told) is skipped by rumqttc
/// as it streams in, acknowledged and reported as [`Event::TooLarge`]: it never costs the
/// connection (vendor/rumqttc/PULSEGATE-PATCH.md).
pub const MAX_PACKET: u32 = 256 * 1024 + 4 * 1024;

/// The largest packet sent to a 3.1.1 broker (it cannot tell us its own limit).
pub const V311_MAX_OUT: u32 = 256 * 1024;

/// Connection options for one protocol.
#[derive(Clone)]
#[allow(clippy::large_enum_variant)] // one per gateway: boxing would buy nothing
pub enum Options {
    V5(v5::MqttOptions),
    V311(rumqttc::MqttOptions),
}

/// What the gateway sets on either protocol.
pub struct Settings<'a> {
    pub protocol: MqttProtocol,
    pub client_id: &'a str,
    /// The broker's host, or its socket path with `Transport::Unix` (rumqttc takes the path
    /// as the broker address and ignores the port).
    pub host: &'a str,
    pub port: u16,
    pub keep_alive: std::time::Duration,
    /// The largest packet the gateway takes (announced to a v5 broker).
    pub max_incoming: u32,
    /// The most QoS 1 messages unacknowledged at once. rumqttc's v5 client otherwise takes the
    /// protocol's 65535 and builds its in-flight table at that size up front (~14 MB resident,
    /// half the gateway's memory at 1000 devices); the outbox never has more than its window out.
    pub inflight: u16,
    pub login: Option<(String, String)>,
    pub transport: Option<Transport>,
}

impl Options {
    pub fn new(s: Settings<'_>) -> Options {
        match s.protocol {
            MqttProtocol::V5 | MqttProtocol::Auto => {
                let mut o = v5::MqttOptions::new(s.client_id, s.host, s.port);
                o.set_keep_alive(s.keep_alive);
                o.set_max_packet_size(Some(s.max_incoming));
                o.set_outgoing_inflight_upper_limit(s.inflight);
                if let Some((u, p)) = s.login {
                    o.set_credentials(u, p);
                }
                if let Some(t) = s.transport {
                    o.set_transport(t);
                }
                Options::V5(o)
            }
            MqttProtocol::V311 => {
                let mut o = rumqttc::MqttOptions::new(s.client_id, s.host, s.port);
                o.set_keep_alive(s.keep_alive);
                o.set_max_packet_size(s.max_incoming as usize, V311_MAX_OUT as usize);
                o.set_inflight(s.inflight);
                if let Some((u, p)) = s.login {
                    o.set_credentials(u, p);
                }
                if let Some(t) = s.transport {
                    o.set_transport(t);
                }
                Options::V311(o)
            }
        }
    }

    /// The same options with `will` as the last will: a format's will may change from one
    /// connection to the next (Sparkplug's NDEATH carries the connection's bdSeq).
    fn with_will(&self, will: Option<&crate::outbox::Will>) -> Options {
        let mut o = self.clone();
        match (&mut o, will) {
            (Options::V5(o), Some(w)) => {
                o.set_last_will(v5::mqttbytes::v5::LastWill::new(
                    w.topic.clone(),
                    w.payload.clone(),
                    v5_qos(w.qos),
                    w.retain,
                    None,
                ));
            }
            (Options::V311(o), Some(w)) => {
                o.set_last_will(rumqttc::LastWill::new(
                    w.topic.clone(),
                    w.payload.clone(),
                    v311_qos(w.qos),
                    w.retain,
                ));
            }
            (_, None) => {}
        }
        o
    }

    /// A fresh client and its event loop (nothing of an earlier one carries over), leaving
    /// `will` with the broker.
    pub fn connect(&self, will: Option<&crate::outbox::Will>, cap: usize) -> (Client, EventLoop) {
        match self.with_will(will) {
            Options::V5(o) => {
                let (c, e) = v5::AsyncClient::new(o, cap);
                (Client::V5(c), EventLoop::V5(e))
            }
            Options::V311(o) => {
                let (c, e) = rumqttc::AsyncClient::new(o, cap);
                (Client::V311(c), EventLoop::V311(e))
            }
        }
    }
}

/// The request side: never waits (rumqttc's queue full is an error the caller retries later).
#[derive(Clone)]
pub enum Client {
    V5(v5::AsyncClient),
    V311(rumqttc::AsyncClient),
}

/// rumqttc's request queue is full (or the event loop is gone).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct RequestError(String);

fn v5_qos(level: u8) -> v5::mqttbytes::QoS {
    match level {
        0 => v5::mqttbytes::QoS::AtMostOnce,
        2 => v5::mqttbytes::QoS::ExactlyOnce,
        _ => v5::mqttbytes::QoS::AtLeastOnce,
    }
}

fn v311_qos(level: u8) -> rumqttc::QoS {
    match level {
        0 => rumqttc::QoS::AtMostOnce,
        2 => rumqttc::QoS::ExactlyOnce,
        _ => rumqttc::QoS::AtLeastOnce,
    }
}

fn req<E: std::fmt::Display>(r: Result<(), E>) -> Result<(), RequestError> {
    r.map_err(|e| RequestError(e.to_string()))
}

impl Client {
    /// Publishes; `correlation` goes out as v5 correlation data and is dropped on 3.1.1.
    pub fn publish(
        &self,
        topic: String,
        qos: u8,
        retain: bool,
        payload: Bytes,
        correlation: Option<&[u8]>,
    ) -> Result<(), RequestError> {
        match self {
            Client::V5(c) => match correlation {
                Some(data) => {
                    let props = PublishProperties {
                        correlation_data: Some(Bytes::copy_from_slice(data)),
                        ..Default::default()
                    };
                    req(c.try_publish_with_properties(topic, v5_qos(qos), retain, payload, props))
                }
                None => req(c.try_publish(topic, v5_qos(qos), retain, payload)),
            },
            Client::V311(c) => req(c.try_publish(topic, v311_qos(qos), retain, payload.to_vec())),
        }
    }

    pub fn subscribe(&self, filter: String) -> Result<(), RequestError> {
        match self {
            Client::V5(c) => req(c.try_subscribe(filter, v5_qos(1))),
            Client::V311(c) => req(c.try_subscribe(filter, v311_qos(1))),
        }
    }

    /// Subscribes to command topics: on v5 without the retained messages (retain handling 2);
    /// 3.1.1 cannot say so, and the router drops what arrives flagged retained.
    ///
    /// With MQTT 5, no retained message is sent at subscribe, and each filter says whether a
    /// message that arrives live keeps the retain flag it was published with (Retain As
    /// Published: a pushed config published retained is then told apart and refused). MQTT
    /// 3.1.1 has neither: retained messages arrive at subscribe, flagged, and live ones never are.
    pub fn subscribe_commands(&self, filters: &[(String, bool)]) -> Result<(), RequestError> {
        match self {
            Client::V5(c) => req(
                c.try_subscribe_many(filters.iter().map(|(f, as_published)| {
                    let mut f = Filter::new(f.clone(), v5_qos(1));
                    f.retain_forward_rule = RetainForwardRule::Never;
                    f.preserve_retain = *as_published;
                    f
                })),
            ),
            Client::V311(c) => req(c.try_subscribe_many(
                filters
                    .iter()
                    .map(|(f, _)| rumqttc::SubscribeFilter::new(f.clone(), v311_qos(1))),
            )),
        }
    }

    pub fn disconnect(&self) -> Result<(), RequestError> {
        match self {
            Client::V5(c) => req(c.try_disconnect()),
            Client::V311(c) => req(c.try_disconnect()),
        }
    }
}

/// A message that arrived (commands, the boot marker).
#[derive(Debug, Clone)]
pub struct Received {
    pub topic: Bytes,
    pub payload: Bytes,
    pub retain: bool,
    /// v5 only.
    pub response_topic: Option<String>,
    pub correlation: Option<Bytes>,
}

/// What the event loop reports, the same for both protocols.
#[derive(Debug)]
pub enum Event {
    /// Connected; the broker's maximum packet size where it says (v5), our own limit on 3.1.1.
    ConnAck {
        max_packet: Option<u32>,
    },
    /// rumqttc sent a publish with this packet id (0 for QoS 0).
    Sent(u16),
    /// The broker acknowledged this packet id (PUBACK, or PUBCOMP for QoS 2).
    Acked(u16),
    Received(Received),
    /// A message larger than [`MAX_PACKET`] arrived and was dropped unread (and acknowledged):
    /// its topic, and its size on the wire in bytes.
    TooLarge {
        topic: String,
        size: usize,
    },
    /// Our DISCONNECT went out.
    Disconnected,
    Other,
}

/// Why the connection failed.
#[derive(Debug)]
pub enum Failure {
    /// The client was dropped: nothing more will come.
    RequestsDone,
    /// Another client connected with our client id (v5 says so; 3.1.1 just closes).
    TakenOver,
    /// The broker refused the protocol version we asked for (an MQTT 3.1.1 broker asked for
    /// v5, in the v5 form, reason 0x84, or the 3.1.1 form, return code 1).
    ProtocolRefused,
    Other(String),
}

/// What the log and the systemd status say when the broker refuses MQTT 5.
pub const PROTOCOL_REFUSED: &str = "the broker refuses MQTT 5 (CONNACK: unacceptable protocol version): it speaks MQTT 3.1.1 only; set mqtt.protocol = \"3.1.1\" in the config";

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::RequestsDone => f.write_str("client closed"),
            Failure::TakenOver => f.write_str("session taken over by another client"),
            Failure::ProtocolRefused => f.write_str(PROTOCOL_REFUSED),
            Failure::Other(m) => f.write_str(m),
        }
    }
}

/// The connection side, polled by one task.
#[allow(clippy::large_enum_variant)] // one per gateway: boxing would buy nothing
pub enum EventLoop {
    V5(v5::EventLoop),
    V311(rumqttc::EventLoop),
}

impl EventLoop {
    pub async fn poll(&mut self) -> Result<Event, Failure> {
        match self {
            EventLoop::V5(e) => e.poll().await.map(v5_event).map_err(v5_failure),
            EventLoop::V311(e) => e.poll().await.map(v311_event).map_err(v311_failure),
        }
    }
}

fn outgoing(o: Outgoing) -> Event {
    match o {
        Outgoing::Publish(pkid) => Event::Sent(pkid),
        Outgoing::Disconnect => Event::Disconnected,
        _ => Event::Other,
    }
}

fn v5_event(e: v5::Event) -> Event {
    use v5::mqttbytes::v5::Packet;
    match e {
        v5::Event::Outgoing(o) => outgoing(o),
        v5::Event::Incoming(Packet::ConnAck(ack)) => Event::ConnAck {
            max_packet: ack.properties.and_then(|p| p.max_packet_size),
        },
        v5::Event::Incoming(Packet::PubAck(a)) => Event::Acked(a.pkid),
        v5::Event::Incoming(Packet::PubComp(c)) => Event::Acked(c.pkid),
        v5::Event::Incoming(Packet::Publish(p)) => {
            let props = p.properties.unwrap_or_default();
            Event::Received(Received {
                topic: p.topic,
                payload: p.payload,
                retain: p.retain,
                response_topic: props.response_topic,
                correlation: props.correlation_data,
            })
        }
        v5::Event::Incoming(_) => Event::Other,
        v5::Event::Dropped(o) => too_large(o),
    }
}

fn v311_event(e: rumqttc::Event) -> Event {
    use rumqttc::Packet;
    match e {
        rumqttc::Event::Outgoing(o) => outgoing(o),
        rumqttc::Event::Incoming(Packet::ConnAck(_)) => Event::ConnAck {
            max_packet: Some(V311_MAX_OUT),
        },
        rumqttc::Event::Incoming(Packet::PubAck(a)) => Event::Acked(a.pkid),
        rumqttc::Event::Incoming(Packet::PubComp(c)) => Event::Acked(c.pkid),
        rumqttc::Event::Incoming(Packet::Publish(p)) => Event::Received(Received {
            topic: Bytes::from(p.topic),
            payload: p.payload,
            retain: p.retain,
            response_topic: None,
            correlation: None,
        }),
        rumqttc::Event::Incoming(_) => Event::Other,
        rumqttc::Event::Dropped(o) => too_large(o),
    }
}

fn too_large(o: rumqttc::Oversized) -> Event {
    Event::TooLarge {
        topic: o.topic,
        size: o.size,
    }
}

fn v5_failure(e: v5::ConnectionError) -> Failure {
    match e {
        v5::ConnectionError::RequestsDone => Failure::RequestsDone,
        v5::ConnectionError::MqttState(v5::StateError::ServerDisconnect {
            reason_code: DisconnectReasonCode::SessionTakenOver,
            ..
        }) => Failure::TakenOver,
        v5::ConnectionError::ConnectionRefused(
            v5::mqttbytes::v5::ConnectReturnCode::UnsupportedProtocolVersion
            | v5::mqttbytes::v5::ConnectReturnCode::RefusedProtocolVersion,
        ) => Failure::ProtocolRefused,
        other => Failure::Other(other.to_string()),
    }
}

fn v311_failure(e: rumqttc::ConnectionError) -> Failure {
    match e {
        rumqttc::ConnectionError::RequestsDone => Failure::RequestsDone,
        other => Failure::Other(other.to_string()),
    }
}

/// The client options of this gateway: a fresh client is built from them after every failure
/// (with the formats' will of the moment). TLS that cannot be set up is an error: the gateway
/// never falls back to plaintext.
pub fn client_options(config: &Mqtt) -> Result<Options, crate::config::tls::TlsError> {
    client_options_as(config, &config.client_id)
}

/// The same options under another client id (`pulsegate set-reading`'s own client): the one
/// place the connection settings become rumqttc's options.
pub fn client_options_as(
    config: &Mqtt,
    client_id: &str,
) -> Result<Options, crate::config::tls::TlsError> {
    let login = config.username.as_ref().map(|user| {
        let password = config.password.as_ref().map(|p| p.0.clone());
        (user.clone(), password.unwrap_or_default())
    });
    let (host, transport) = broker_transport(config)?;
    Ok(Options::new(Settings {
        protocol: config.protocol,
        client_id,
        host: &host,
        port: config.port,
        keep_alive: config.keep_alive,
        max_incoming: MAX_PACKET,
        inflight: INFLIGHT,
        login,
        transport,
    }))
}

/// Where and how to connect: a local socket (its path is rumqttc's broker address, the port
/// is ignored), TLS, or plain TCP. A socket with TLS is refused rather than connected without
/// TLS: `check` refuses that config, and a config built another way must fail closed too.
pub(crate) fn broker_transport(
    config: &Mqtt,
) -> Result<(String, Option<Transport>), crate::config::tls::TlsError> {
    match (&config.socket, &config.tls) {
        (Some(path), Some(_)) => Err(crate::config::tls::TlsError::OverSocket {
            socket: path.display().to_string(),
        }),
        (Some(path), None) => Ok((path.to_string_lossy().into_owned(), Some(Transport::Unix))),
        (None, Some(tls)) => Ok((
            config.host.clone(),
            Some(Transport::tls_with_config(TlsConfiguration::Rustls(
                crate::config::tls::client_config(tls)?,
            ))),
        )),
        (None, None) => Ok((config.host.clone(), None)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_of_mqtt_5_in_either_form_is_named_as_such() {
        use v5::mqttbytes::v5::{ConnectReturnCode, Packet};
        // A 3.1.1 broker's CONNACK (no properties), return code 1, read by the v5 client.
        let mut bytes = bytes::BytesMut::from(&[0x20u8, 0x02, 0x00, 0x01][..]);
        let Ok(Packet::ConnAck(ack)) = Packet::read(&mut bytes, None) else {
            panic!("a 3.1.1 CONNACK is read, not awaited");
        };
        assert_eq!(ack.code, ConnectReturnCode::RefusedProtocolVersion);
        for code in [
            ConnectReturnCode::RefusedProtocolVersion,
            ConnectReturnCode::UnsupportedProtocolVersion,
        ] {
            let failure = v5_failure(v5::ConnectionError::ConnectionRefused(code));
            assert!(matches!(failure, Failure::ProtocolRefused));
            assert!(failure.to_string().contains("mqtt.protocol = \"3.1.1\""));
        }
        assert!(matches!(
            v5_failure(v5::ConnectionError::ConnectionRefused(
                ConnectReturnCode::NotAuthorized
            )),
            Failure::Other(_)
        ));
    }

    fn settings(protocol: MqttProtocol) -> Settings<'static> {
        Settings {
            protocol,
            client_id: "t",
            host: "127.0.0.1",
            port: 1,
            keep_alive: std::time::Duration::from_secs(30),
            max_incoming: 65536,
            inflight: 164,
            login: None,
            transport: None,
        }
    }

    /// Without the limit rumqttc's v5 client sizes its in-flight table for 65535 messages.
    #[test]
    fn rumqttc_is_told_how_many_messages_may_be_in_flight() {
        match Options::new(settings(MqttProtocol::V5)) {
            Options::V5(o) => assert_eq!(o.get_outgoing_inflight_upper_limit(), Some(164)),
            Options::V311(_) => panic!("asked for v5"),
        }
        match Options::new(settings(MqttProtocol::V311)) {
            Options::V311(o) => assert_eq!(o.inflight(), 164),
            Options::V5(_) => panic!("asked for 3.1.1"),
        }
    }
}
