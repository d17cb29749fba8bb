//! The encoder of an output: typed events from the buses and the command router in, messages
//! out (topic, payload bytes, QoS, retain, properties, and what they carry). A format is one
//! implementation of [`Format`]; an output's kind chooses which run (the registry,
//! [`super::formats`]). Pure, and no notion of the transport: what a format does on an MQTT
//! connection (its subscriptions, what it says at connect and leaves as its will, its hold) is
//! the [`super::lifecycle::Lifecycle`] of the formats that need one.
//!
//! Adding one: a new file (or folder) with a type that implements [`Format`], its kind's part of
//! the config in `config/outputs/` and one line in the registry ([`super::formats`]). A format
//! is an encoder: it says what each message carries ([`Content`]) and has no say over its
//! delivery (owed or chatter, decided in [`super::delivery`]).

use crate::config::Config;
#[cfg(doc)]
use crate::outbox::Content;
use crate::outbox::Message;
use crate::reading::Output;

/// Turns events into the messages that publish them. `&mut self`: a format may remember what it
/// published (discovery announces each entity once; Sparkplug B numbers its messages).
pub trait Format: Send + Sync {
    /// The messages for `event`; none when this format does not publish such an event.
    fn messages(&mut self, event: &Output) -> Vec<Message>;

    /// The gateway's config was reloaded (SIGHUP).
    fn reload(&mut self, _config: &Config) -> Vec<Message> {
        Vec::new()
    }
}

#[cfg(test)]
#[path = "format_tests.rs"]
mod tests;
