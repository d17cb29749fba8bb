//! The JSON format: one message per reading (or per device poll), retained status words, bus
//! health, command results, and the gateway's own status (`online` at every connection, its
//! will `offline`). Payload shapes are in [`super::payload`]; topics in [`crate::topics`].
//! Readings and statuses are owed; bus health and results are chatter (made again).

use super::format::Format;
use super::payload;
use crate::topics::Topics;
use std::collections::HashSet;

use crate::config::Config;
use crate::config::policy::PayloadMode;
use crate::outbox::{Message, Will};
use crate::reading::{Output, Reading};

/// Today's payloads.
#[derive(Debug, Clone)]
pub struct Json {
    topics: Topics,
    /// `mqtt.retain`, for readings.
    retain: bool,
    /// `mqtt.qos`, for readings.
    qos: u8,
    /// The devices whose polls go as one message (`payload = "device"`, theirs or inherited).
    per_device: HashSet<String>,
}

impl Json {
    /// The JSON format of `config` (the payload shape of each device from its own config).
    pub fn new(config: &Config) -> Json {
        let mqtt = &config.mqtt;
        Json {
            topics: Topics::new(&mqtt.topic_root),
            retain: mqtt.retain,
            qos: mqtt.qos,
            per_device: per_device(config),
        }
    }

    /// One message per reading.
    fn readings<'r>(&self, readings: impl IntoIterator<Item = &'r Reading>) -> Vec<Message> {
        readings
            .into_iter()
            .map(|r| {
                let topic = self.topics.reading(&r.device, &r.channel);
                Message::new(topic, payload::reading(r), self.qos, self.retain)
            })
            .collect()
    }
}

fn per_device(config: &Config) -> HashSet<String> {
    config
        .devices()
        .filter(|(_, d)| d.payload.unwrap_or(config.gateway.payload) == PayloadMode::Device)
        .map(|(_, d)| d.name.clone())
        .collect()
}

impl Format for Json {
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        let t = &self.topics;
        match event {
            Output::Reading(r) => self.readings([r]),
            Output::DeviceReadings { device, readings } if self.per_device.contains(&**device) => {
                let body = payload::device(readings);
                vec![Message::new(t.device(device), body, self.qos, self.retain)]
            }
            Output::DeviceReadings { readings, .. } => self.readings(readings),
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
            Output::Interval(i) => {
                let topic = t.interval(&i.device, &i.channel, &i.period);
                vec![Message::new(
                    topic,
                    payload::interval(i),
                    self.qos,
                    self.retain,
                )]
            }
            Output::ScanProgress { topic, progress } => {
                let body = serde_json::to_string(&**progress).unwrap_or_default();
                // Made again by the next scan: chatter, never spooled.
                vec![Message::chatter(topic.clone(), body, 1, false)]
            }
            Output::Checkpoint(_) => Vec::new(),
        }
    }

    /// A device's payload shape may change with the config.
    fn reload(&mut self, config: &Config) -> Vec<Message> {
        self.per_device = per_device(config);
        Vec::new()
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
