//! The JSON format: one message per reading (or per device poll), retained status words, bus
//! health, command results. Payload shapes are in [`super::payload`]; topics in [`super::topics`].

use super::format::Format;
use super::payload;
use super::topics::Topics;
use crate::config::Mqtt;
use crate::outbox::Message;
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
                // Health is of the moment: not worth spooling.
                let body = serde_json::to_string(&**stats).unwrap_or_default();
                let mut m = Message::new(t.bus_stats(bus), body, 0, false);
                m.transient = true;
                vec![m]
            }
            Output::CommandResult {
                topics,
                correlation,
                payload,
            } => {
                let body = bytes::Bytes::from(payload.to_string());
                let mut out = Vec::with_capacity(topics.len());
                for (i, topic) in topics.iter().enumerate() {
                    let mut m = Message::new(topic.clone(), body.clone(), 1, false);
                    // The MQTT v5 response topic (after the result topic) gets the request's
                    // correlation data back.
                    if i > 0 {
                        m.properties.correlation = correlation.clone();
                    }
                    out.push(m);
                }
                out
            }
            Output::ScanProgress { topic, progress } => {
                let body = serde_json::to_string(&**progress).unwrap_or_default();
                vec![Message::new(topic.clone(), body, 1, false)]
            }
            Output::Checkpoint => Vec::new(),
        }
    }
}
