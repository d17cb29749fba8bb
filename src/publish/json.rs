//! The JSON format: one message per reading (or per device poll), interval records, retained
//! device status words and bus health, under the output's topic root. Payload shapes are in
//! [`super::payload`]; topics in [`crate::topics`]. The gateway's own status and results are
//! its voice's ([`super::voice`]), not this format's.

use super::account::Ledger;
use super::format::Format;
use super::payload;
use super::signed::Signer;
use crate::topics::Topics;
use std::collections::HashSet;

use crate::config::policy::PayloadMode;
use crate::config::{Config, OutputConfig};
use crate::outbox::{Content, Message};
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
    /// Signs interval and billing records (`[billing] signing_key`), the key read at start;
    /// numbers the tariff registers.
    ledger: Ledger,
}

impl Json {
    /// The JSON format of `output` (the payload shape of each device from its own config).
    pub fn new(config: &Config, output: &OutputConfig) -> Json {
        let mqtt = &output.mqtt;
        Json {
            topics: Topics::new(&mqtt.topic_root),
            retain: mqtt.retain,
            qos: mqtt.qos,
            per_device: per_device(config),
            ledger: Ledger {
                calendar: config.gateway.tariffs.clone(),
                signer: Signer::of(config),
            },
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
                let m = Message::new(t.bus_stats(bus), body, 0, false);
                vec![m.carrying(Content::Health)]
            }
            Output::Interval(i) => {
                let topic = t.interval(&i.device, &i.channel, &i.period);
                let mut body = payload::interval(i);
                if let Some(s) = &self.ledger.signer {
                    body = s.interval(i, body);
                }
                let record = Message::new(topic, body, self.qos, self.retain);
                let mut out = vec![record];
                out.extend(super::account::messages(t, i, self.qos, &self.ledger));
                out
            }
            _ => Vec::new(),
        }
    }

    /// A device's payload shape may change with the config.
    fn reload(&mut self, config: &Config) -> Vec<Message> {
        self.per_device = per_device(config);
        self.ledger.calendar = config.gateway.tariffs.clone();
        Vec::new()
    }
}
