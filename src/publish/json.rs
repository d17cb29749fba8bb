//! The JSON format: one message per reading (or per device poll), retained status words, bus
//! health, command results, and the gateway's own status (`online` at every connection, its
//! will `offline`). Payload shapes are in [`super::payload`]; topics in [`super::topics`].
//! Readings and statuses are owed; bus health and results are chatter (made again).

use super::format::Format;
use super::payload;
use super::topics::Topics;
use crate::config::Mqtt;
use crate::outbox::{Message, Will};
use crate::reading::Output;

/// Today's payloads.
#[derive(Debug, Clone)]
pub struct Json {
    topics: Topics,
    /// `mqtt.retain`, for readings.
    retain: bool,
    /// `mqtt.qos`, for readings.
    qos: u8,
}

impl Json {
    pub fn new(config: &Mqtt) -> Json {
        Json {
            topics: Topics::new(&config.topic_root),
            retain: config.retain,
            qos: config.qos,
        }
    }
}

impl Format for Json {
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        let t = &self.topics;
        match event {
            Output::Reading(r) => {
                let topic = t.reading(&r.device, &r.channel);
                vec![Message::new(
                    topic,
                    payload::reading(r),
                    self.qos,
                    self.retain,
                )]
            }
            Output::DeviceReadings { device, readings } => {
                let body = payload::device(readings);
                vec![Message::new(t.device(device), body, self.qos, self.retain)]
            }
            Output::DeviceStatus { device, online } => {
                let word = if *online { "online" } else { "offline" };
                vec![Message::new(t.device_status(device), word, 1, true)]
            }
            Output::DeviceProblem { device, status } => {
                vec![Message::new(t.device_status(device), *status, 1, true)]
            }
            Output::BusStats { bus, stats } => {
                // Health is of the moment: not worth keeping while the broker is away.
                let body = serde_json::to_string(&**stats).unwrap_or_default();
                let mut m = Message::chatter(t.bus_stats(bus), body, 0, false);
                m.transient = true;
                vec![m]
            }
            Output::CommandResult {
                topics,
                correlation,
                outcome,
            } => {
                let body = bytes::Bytes::from(outcome.to_json().to_string());
                let mut out = Vec::with_capacity(topics.len());
                for (i, topic) in topics.iter().enumerate() {
                    let mut m = Message::chatter(topic.clone(), body.clone(), 1, false);
                    // The MQTT v5 response topic (after the result topic) gets the request's
                    // correlation data back.
                    if i > 0 {
                        m.properties.correlation = correlation.clone();
                    }
                    out.push(m);
                }
                out
            }
            Output::Checkpoint(_) => Vec::new(),
        }
    }

    /// The gateway's status, retained: `online` at every connection.
    fn connected(&mut self) -> Vec<Message> {
        vec![Message::new(
            self.topics.gateway_status(),
            "online",
            1,
            true,
        )]
    }

    /// `offline` when the connection dies without a word.
    fn will(&mut self) -> Option<Will> {
        Some(Will {
            topic: self.topics.gateway_status(),
            payload: bytes::Bytes::from_static(b"offline"),
            qos: 1,
            retain: true,
        })
    }

    /// `offline` as the gateway stops.
    fn stopping(&mut self) -> Vec<Message> {
        vec![Message::new(
            self.topics.gateway_status(),
            "offline",
            1,
            true,
        )]
    }
}
