//! The output stage: typed events from the buses and the command router in, MQTT messages out
//! (topic, payload bytes, QoS, retain, properties). A format is one implementation of
//! [`Format`]; the config chooses which run ([`chosen`]), in one [`Stage`] owned by the MQTT
//! task. Pure.
//!
//! Adding one: a new file with a type that implements [`Format`], plus its config key. A payload
//! format (today's JSON, [`super::json`], is the first) is named by `mqtt.format`: its name goes
//! in [`NAMES`] and a line in [`build`]. A format that runs beside it (Home Assistant discovery,
//! [`super::discovery`], under `[homeassistant] discovery`) is a line in [`chosen`].
//!
//! Most formats only turn events into messages. One that also listens (discovery: Home
//! Assistant's birth message, the configs the broker holds) names its subscriptions, and what
//! arrives on them comes back to it; one that describes the config hears about reloads.

use crate::config::{Config, Mqtt};
use crate::outbox::Message;
use crate::reading::Output;

/// Turns events into the messages that publish them. `&mut self`: a format may remember what it
/// published (discovery announces each entity once; Sparkplug B numbers its messages).
pub trait Format: Send + Sync {
    /// The messages for `event`; none when this format does not publish such an event.
    fn messages(&mut self, event: &Output) -> Vec<Message>;

    /// Topic filters this format reads, subscribed at every connection.
    fn subscriptions(&self) -> Vec<String> {
        Vec::new()
    }

    /// What it publishes at start, before any event.
    fn start(&mut self) -> Vec<Message> {
        Vec::new()
    }

    /// A message arrived on one of the formats' subscriptions (any format's: take only yours).
    fn received(&mut self, _topic: &str, _payload: &[u8]) -> Vec<Message> {
        Vec::new()
    }

    /// The gateway's config was reloaded (SIGHUP).
    fn reload(&mut self, _config: &Config) -> Vec<Message> {
        Vec::new()
    }
}

/// The formats `mqtt.format` may name.
pub const NAMES: &[&str] = &["json", "sparkplug"];

/// The payload format `name` (checked against [`NAMES`] when the config is read).
pub fn build(config: &Config, name: &str) -> Box<dyn Format> {
    match name {
        "json" => Box::new(super::json::Json::new(&config.mqtt)),
        "sparkplug" => Box::new(super::sparkplug::Sparkplug::new(config)),
        other => unreachable_format(other, &config.mqtt),
    }
}

/// A name `check` let through that [`build`] does not know: JSON, logged (a programming error
/// between [`NAMES`] and [`build`], never a crash of the gateway).
fn unreachable_format(name: &str, config: &Mqtt) -> Box<dyn Format> {
    tracing::error!("output format {name:?} is not built in; publishing JSON");
    Box::new(super::json::Json::new(config))
}

/// Every format the config chooses, in the order their messages go out: discovery first, so an
/// entity is announced before its first reading.
pub fn chosen(config: &Config) -> Vec<Box<dyn Format>> {
    let mut formats: Vec<Box<dyn Format>> = Vec::new();
    if config.homeassistant.discovery {
        formats.push(Box::new(super::discovery::Discovery::new(config)));
    }
    for name in &config.mqtt.format {
        formats.push(build(config, name));
    }
    formats
}

/// One format's messages for one event.
pub fn render(format: &mut dyn Format, event: &Output) -> Vec<Message> {
    format.messages(event)
}

/// The formats in use, run one after the other on every event.
pub struct Stage {
    formats: Vec<Box<dyn Format>>,
}

impl Stage {
    pub fn new(formats: Vec<Box<dyn Format>>) -> Stage {
        Stage { formats }
    }

    /// Every format's messages for `event`, in the formats' order.
    pub fn render(&mut self, event: &Output) -> Vec<Message> {
        self.each(|f| f.messages(event))
    }

    /// Every format's subscriptions.
    pub fn subscriptions(&self) -> Vec<String> {
        self.formats
            .iter()
            .flat_map(|f| f.subscriptions())
            .collect()
    }

    pub fn start(&mut self) -> Vec<Message> {
        self.each(|f| f.start())
    }

    /// A message on one of the subscriptions, offered to every format.
    pub fn received(&mut self, topic: &str, payload: &[u8]) -> Vec<Message> {
        self.each(|f| f.received(topic, payload))
    }

    pub fn reload(&mut self, config: &Config) -> Vec<Message> {
        self.each(|f| f.reload(config))
    }

    fn each(&mut self, mut f: impl FnMut(&mut dyn Format) -> Vec<Message>) -> Vec<Message> {
        let mut out = Vec::new();
        for format in &mut self.formats {
            out.extend(f(&mut **format));
        }
        out
    }
}

#[cfg(test)]
#[path = "format_tests.rs"]
mod tests;
