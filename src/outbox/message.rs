//! What formats hand the outbox: a message with its topic, bytes, QoS, retain, properties and
//! class, and the will a format leaves with the broker.

use bytes::Bytes;

/// A message to publish: what an output format produces (see [`crate::publish::format`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    pub topic: String,
    /// Any bytes: JSON text today, binary formats tomorrow.
    pub payload: Bytes,
    pub qos: u8,
    pub retain: bool,
    /// MQTT v5 publish properties.
    pub properties: Properties,
    /// What it carries, as the format that made it says (its delivery follows from it).
    pub content: Content,
    /// Of the moment only (bus health): dropped rather than kept while the broker is away.
    pub transient: bool,
    /// Owed (kept, in order) or chatter (made again, dropped first).
    pub class: Class,
}

/// What a message carries. A format says it; how the message is delivered (owed or chatter,
/// kept while the broker is away or not) is decided from it in one place,
/// `publish::delivery`, never by the format.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Content {
    /// Readings, availability, interval records: what a consumer counts on.
    #[default]
    Data,
    /// A description the gateway can make again (a Home Assistant discovery config).
    Config,
    /// The answer to a command or scan, or a scan's progress.
    Answer,
    /// Of the moment only (bus health).
    Health,
}

/// What losing a message costs, and so how it is kept.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Class {
    /// Readings, statuses, interval records: spooled (to disk while the broker is away),
    /// delivered in order, never evicted by anything else.
    #[default]
    Owed,
    /// What the gateway can make again (discovery configs, command and scan results, bus
    /// stats): a bounded queue in memory, dropped first, never written to disk.
    Chatter,
}

/// A message the broker publishes for the gateway when its connection dies (the MQTT will).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Will {
    pub topic: String,
    pub payload: Bytes,
    pub qos: u8,
    pub retain: bool,
}

/// The MQTT v5 publish properties the gateway sets (dropped on MQTT 3.1.1).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Properties {
    /// Correlation data of the request a command result answers.
    pub correlation: Option<Bytes>,
}

impl Message {
    /// An owed QoS `qos` message without properties.
    pub fn new(topic: String, payload: impl Into<Bytes>, qos: u8, retain: bool) -> Message {
        Message {
            topic,
            payload: payload.into(),
            qos,
            retain,
            properties: Properties::default(),
            content: Content::Data,
            transient: false,
            class: Class::Owed,
        }
    }

    /// The same message, saying it carries `content`.
    pub fn carrying(self, content: Content) -> Message {
        Message { content, ..self }
    }

    /// A chatter message: one the gateway can make again (for the outbox's own tests; formats
    /// say what they carry instead).
    pub fn chatter(topic: String, payload: impl Into<Bytes>, qos: u8, retain: bool) -> Message {
        Message {
            class: Class::Chatter,
            ..Message::new(topic, payload, qos, retain)
        }
    }
}
