//! The output stage: typed events from the buses and the command router in, MQTT messages out
//! (topic, payload bytes, QoS, retain, properties). A format is one implementation of
//! [`Format`]; today's JSON ([`super::json`]) is the first. Adding one: a new file with a type
//! that implements [`Format`], its name in [`NAMES`] and a line in [`build`] (the config key
//! `mqtt.format` picks it). Ready messages (Home Assistant discovery, which builds its own) pass
//! through every format unchanged. Pure.

use crate::config::Mqtt;
use crate::outbox::Message;
use crate::reading::Output;

/// Turns one event into the messages that publish it.
pub trait Format: Send + Sync {
    /// The messages for `event`; none when this format does not publish such an event.
    fn messages(&self, event: &Output) -> Vec<Message>;
}

/// The formats `mqtt.format` may name.
pub const NAMES: &[&str] = &["json"];

/// The format named by the config (checked against [`NAMES`] when the config is read).
pub fn build(config: &Mqtt) -> Box<dyn Format> {
    match config.format.as_str() {
        "json" => Box::new(super::json::Json::new(config)),
        other => unreachable_format(other, config),
    }
}

/// A name `check` let through that [`build`] does not know: JSON, logged (a programming error
/// between [`NAMES`] and [`build`], never a crash of the gateway).
fn unreachable_format(name: &str, config: &Mqtt) -> Box<dyn Format> {
    tracing::error!("output format {name:?} is not built in; publishing JSON");
    Box::new(super::json::Json::new(config))
}

/// The output stage: ready messages as they are, events through `format`. Subscriptions are
/// not messages (the MQTT task takes them).
pub fn render(format: &dyn Format, event: &Output) -> Vec<Message> {
    match event {
        Output::Message {
            topic,
            payload,
            retain,
        } => vec![Message::new(topic.clone(), payload.clone(), 1, *retain)],
        Output::Subscribe(_) => Vec::new(),
        other => format.messages(other),
    }
}

#[cfg(test)]
#[path = "format_tests.rs"]
mod tests;
