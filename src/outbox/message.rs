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
    /// Of the moment only (bus health): dropped rather than kept while the broker is away.
    pub transient: bool,
    /// Owed (kept, in order) or chatter (made again, dropped first).
    pub class: Class,
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
            transient: false,
            class: Class::Owed,
        }
    }

    /// A chatter message: one the gateway can make again.
    pub fn chatter(topic: String, payload: impl Into<Bytes>, qos: u8, retain: bool) -> Message {
        Message {
            class: Class::Chatter,
            ..Message::new(topic, payload, qos, retain)
        }
    }
}
