//! The output registry: every output kind the gateway has, one line each. An entry is the kind's
//! part of the config ([`Kind`]: its name, its own table and the file that reads it, the topic
//! prefixes it reserves, whether it carries the gateway's topics; in its file under
//! `config/outputs/`) and its builder (the formats an output of that kind runs). The config is
//! checked against this list ([`Registry::kinds`]), so a kind left out of it can neither be
//! parsed nor built, and the error that lists the kinds lists these. The one place that knows
//! every format (the trait they implement is in [`super::format`], their MQTT parts in
//! [`super::lifecycle`]).

use super::lifecycle::{MqttFormat, plain};
use super::voice::Voice;
use crate::config::outputs::{Kind, homeassistant, json, sparkplug};
use crate::config::{Config, Kinds, OutputConfig};

/// The formats an output of a kind runs, in the order their messages go out.
pub type Build = fn(&Config, &OutputConfig) -> Vec<Box<dyn MqttFormat>>;

/// One output kind: its part of the config and its builder.
#[derive(Clone, Copy)]
pub struct Entry {
    pub kind: &'static Kind,
    pub build: Build,
}

/// The gateway's output kinds, in the order the config's error message lists them. Home
/// Assistant's discovery goes before the JSON readings (an entity is announced before its first
/// reading).
pub static STANDARD: &[Entry] = &[
    Entry {
        kind: &json::KIND,
        build: |c, o| vec![plain(super::json::Json::new(c, o))],
    },
    Entry {
        kind: &sparkplug::KIND,
        build: |c, o| vec![Box::new(super::sparkplug::Sparkplug::new(c, o))],
    },
    Entry {
        kind: &homeassistant::KIND,
        build: |c, o| {
            let discovery = super::homeassistant::Discovery::new(c, o);
            vec![Box::new(discovery), plain(super::json::Json::new(c, o))]
        },
    },
];

/// A list of output kinds: the gateway's ([`Registry::standard`]), or more (a test's own).
#[derive(Clone)]
pub struct Registry(Vec<Entry>);

impl Registry {
    /// The gateway's output kinds.
    pub fn standard() -> Registry {
        Registry(STANDARD.to_vec())
    }

    /// These kinds and `entry`, whose name none of them has.
    pub fn with(mut self, entry: Entry) -> Registry {
        let name = entry.kind.name;
        assert!(
            self.0.iter().all(|e| e.kind.name != name),
            "two output kinds named {name:?}"
        );
        self.0.push(entry);
        self
    }

    /// What the config checks `kind` against.
    pub fn kinds(&self) -> Kinds {
        Kinds(self.0.iter().map(|e| e.kind).collect())
    }

    /// The formats of `output`, in the order their messages go out, and the gateway's voice
    /// first on every connection that carries its JSON topics (its will is theirs).
    pub fn build(&self, config: &Config, output: &OutputConfig) -> Vec<Box<dyn MqttFormat>> {
        let mut formats: Vec<Box<dyn MqttFormat>> = Vec::new();
        if output.kind.carries_gateway_topics() {
            formats.push(Box::new(Voice::new(&output.mqtt.topic_root, &output.name)));
        }
        match self.0.iter().find(|e| output.kind.is(e.kind)) {
            Some(entry) => formats.extend((entry.build)(config, output)),
            None => tracing::error!(
                output = %output.name,
                kind = %output.kind,
                "an output of a kind the registry does not build: it publishes nothing"
            ),
        }
        formats
    }
}

/// The formats of `output` by the gateway's registry.
pub fn build(config: &Config, output: &OutputConfig) -> Vec<Box<dyn MqttFormat>> {
    Registry::standard().build(config, output)
}
