//! Home Assistant discovery, the format of an output of kind `homeassistant` (beside the JSON
//! format, on the same connection): a state machine
//! of what the gateway has announced, what the broker holds, and what to publish when readings,
//! Home Assistant or a reload say so. Pure: events in, retained config messages out. It runs in
//! the output stage before the payload format, so an entity is announced before its first
//! reading; it subscribes to Home Assistant's status and this gateway's configs on the broker.
//!
//! Configs are chatter (the gateway can make them again): they never push a reading out of the
//! outbox. Home Assistant's `online` announces every config again, but a flood of them (a
//! flapping Home Assistant, a misbehaving client) costs at most one announcement every
//! [`REANNOUNCE_GAP`]: an `online` within it leaves one announcement pending for the next tick.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::time::Duration;

use tokio::time::Instant;

pub mod account_entities;
pub mod entities;
pub mod entity;
pub mod meter_entities;

use super::format::Format;
use super::lifecycle::{Lifecycle, Reaction};
use crate::config::{Config, OutputConfig};
use crate::outbox::{Content, Message};
use crate::profile::ChannelKind;
use crate::reading::{Output, Reading};
use entities::{
    Shape, channel_entities, channel_spec, device_entities, gateway_entities, module_topics,
    possible_topics,
};
use entity::{Entity, Module, Site};

/// A retained config message (an empty payload removes the entity).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Announce {
    pub topic: String,
    pub payload: String,
}

impl Announce {
    /// Retained, at least once; chatter (made again at will).
    fn message(self) -> Message {
        Message::new(self.topic, self.payload, 1, true).carrying(Content::Config)
    }
}

/// The least time between two announcements of every config for Home Assistant's `online`.
pub const REANNOUNCE_GAP: Duration = Duration::from_secs(5);

fn messages(list: impl IntoIterator<Item = Announce>) -> Vec<Message> {
    list.into_iter().map(Announce::message).collect()
}

/// A channel by its place on the wire and what it counts: bus, the device's place (`u3`,
/// `a5`, `id12345678`), channel name, kind.
type ChannelKey = (String, String, String, ChannelKind);

/// What discovery knows.
pub struct Discovery {
    site: Site,
    config: Config,
    /// Config topics we published and their payloads (republished when HA comes back).
    announced: BTreeMap<String, String>,
    /// Config topics of this gateway seen retained on the broker.
    on_broker: BTreeSet<String>,
    /// Channels that have published readings, and what their entities are made of: their
    /// entities are announced.
    learned: HashMap<ChannelKey, Shape>,
    /// Topics this config may have; anything else of ours on the broker is stale.
    possible: BTreeSet<String>,
    /// Modules that completed a poll: their channels in the current work mode are all learned.
    settled: BTreeSet<(String, String)>,
    /// Topics of settled modules' channels they do not have (another work mode): stale.
    unwanted: BTreeSet<String>,
    /// When every config was last announced for Home Assistant's `online`.
    reannounced: Option<Instant>,
    /// An `online` came within [`REANNOUNCE_GAP`] of the last announcement: one is owed.
    reannounce_pending: bool,
}

impl Discovery {
    /// Discovery for `output`, whose topic root the entities read their states from.
    pub fn new(config: &Config, output: &OutputConfig) -> Discovery {
        let mut config = config.clone();
        config.mqtt = output.mqtt.clone();
        let site = Site::of(&config);
        Discovery {
            possible: possible_topics(&site, &config),
            site,
            config,
            announced: BTreeMap::new(),
            on_broker: BTreeSet::new(),
            learned: HashMap::new(),
            settled: BTreeSet::new(),
            unwanted: BTreeSet::new(),
            reannounced: None,
            reannounce_pending: false,
        }
    }

    fn announce(&mut self, entities: Vec<Entity>) -> Vec<Announce> {
        let mut out = Vec::new();
        for e in entities {
            let topic = e.topic(&self.site);
            let payload = e.config.to_string();
            if self.announced.get(&topic) != Some(&payload) {
                self.announced.insert(topic.clone(), payload.clone());
                out.push(Announce { topic, payload });
            }
        }
        out
    }

    /// At start: the gateway device and each module's device-wide entities.
    pub fn start(&mut self) -> Vec<Announce> {
        let mut entities = gateway_entities(&self.site);
        for (bus, device) in self.config.enabled_devices() {
            let m = Module {
                bus: &bus.name,
                device,
            };
            entities.extend(device_entities(&self.site, m));
        }
        self.announce(entities)
    }

    /// A reading went by: the first of a channel announces its entities.
    pub fn reading(&mut self, r: &Reading) -> Vec<Announce> {
        let Some((bus, device)) = self
            .config
            .enabled_devices()
            .find(|(_, d)| *d.name == *r.device)
        else {
            return Vec::new();
        };
        let key = (
            bus.name.clone(),
            device.place_tag(),
            r.channel.to_string(),
            r.kind,
        );
        let m = Module {
            bus: &bus.name,
            device,
        };
        // A channel its device declares (an M-Bus record) is what its reading shows; it is
        // announced again when that changes.
        let declared = device.channels_from_device().then(|| Shape::of_reading(r));
        if let Some(known) = self.learned.get(&key)
            && declared.as_ref().is_none_or(|d| d == known)
        {
            // A channel read again: the module's first poll is complete.
            return self.settle(key.0, key.1);
        }
        let Some(spec) = declared.or_else(|| channel_spec(m, &r.channel, r.kind)) else {
            return Vec::new();
        };
        let entities = channel_entities(&self.site, m, &spec);
        let settled = self.settled.contains(&(key.0.clone(), key.1.clone()));
        self.learned.insert(key, spec);
        if settled {
            // The work mode changed under a settled module: its new channels are wanted now.
            self.refresh_unwanted();
        }
        self.announce(entities)
    }

    /// The module at `bus`/`place` completed a poll: configs of channels it does not have in
    /// its current work mode are cleared.
    fn settle(&mut self, bus: String, place: String) -> Vec<Announce> {
        if !self.settled.insert((bus, place)) {
            return Vec::new();
        }
        self.refresh_unwanted();
        self.clear_where(|d, t| d.unwanted.contains(t))
    }

    /// Recomputes the topics settled modules do not have.
    fn refresh_unwanted(&mut self) {
        let mut unwanted = BTreeSet::new();
        for (bus, device) in self.config.enabled_devices() {
            if !self
                .settled
                .contains(&(bus.name.clone(), device.place_tag()))
            {
                continue;
            }
            let m = Module {
                bus: &bus.name,
                device,
            };
            let mut topics = module_topics(&self.site, m);
            for e in device_entities(&self.site, m) {
                topics.remove(&e.topic(&self.site));
            }
            let place = device.place_tag();
            let learned = self
                .learned
                .iter()
                .filter(|((b, p, ..), _)| *b == bus.name && *p == place);
            for (_, spec) in learned {
                for e in channel_entities(&self.site, m, spec) {
                    topics.remove(&e.topic(&self.site));
                }
            }
            unwanted.extend(topics);
        }
        self.unwanted = unwanted;
    }

    /// Clears every announced or retained config for which `stale` holds.
    fn clear_where(&mut self, stale: impl Fn(&Discovery, &str) -> bool) -> Vec<Announce> {
        let topics: BTreeSet<String> = self
            .announced
            .keys()
            .chain(&self.on_broker)
            .filter(|t| stale(self, t))
            .cloned()
            .collect();
        topics.iter().map(|t| self.clear(t)).collect()
    }

    /// Home Assistant announced itself: every config again, at once or (within
    /// [`REANNOUNCE_GAP`] of the last time) at a later [`Discovery::due`].
    pub fn ha_status(&mut self, payload: &[u8], now: Instant) -> Vec<Announce> {
        if payload != b"online" {
            return Vec::new();
        }
        self.reannounce_pending = true;
        self.due(now)
    }

    /// A pending announcement whose time has come.
    pub fn due(&mut self, now: Instant) -> Vec<Announce> {
        let recent = self
            .reannounced
            .is_some_and(|t| now.saturating_duration_since(t) < REANNOUNCE_GAP);
        if !self.reannounce_pending || recent {
            return Vec::new();
        }
        self.reannounce_pending = false;
        self.reannounced = Some(now);
        self.everything()
    }

    /// Every config announced so far.
    pub fn everything(&self) -> Vec<Announce> {
        self.announced
            .iter()
            .map(|(topic, payload)| Announce {
                topic: topic.clone(),
                payload: payload.clone(),
            })
            .collect()
    }

    /// A config of this gateway arrived from the broker (retained at subscription, or our own
    /// publish coming back): one that the config cannot have is cleared.
    pub fn config_seen(&mut self, topic: &str, payload: &[u8]) -> Option<Announce> {
        if payload.is_empty() {
            self.on_broker.remove(topic);
            return None;
        }
        self.on_broker.insert(topic.to_string());
        (!self.possible(topic) || self.unwanted.contains(topic)).then(|| self.clear(topic))
    }

    /// Whether the config may have `topic`: one of its modules' and channels' topics, or any
    /// topic of a module whose channels are what its device answers (an M-Bus meter's records
    /// are known only once it answers).
    fn possible(&self, topic: &str) -> bool {
        if self.possible.contains(topic) {
            return true;
        }
        let Some(object) = topic.split('/').nth(3) else {
            return false;
        };
        self.config
            .enabled_devices()
            .filter(|(_, d)| d.channels_from_device())
            .any(|(b, d)| {
                let m = Module {
                    bus: &b.name,
                    device: d,
                };
                object.starts_with(&format!("{}_", m.key()))
            })
    }

    fn clear(&mut self, topic: &str) -> Announce {
        self.announced.remove(topic);
        self.on_broker.remove(topic);
        Announce {
            topic: topic.to_string(),
            payload: String::new(),
        }
    }

    /// A reloaded config: configs of removed devices and channels are cleared, the rest
    /// announced again as the new config describes them (a renamed device keeps its entities).
    pub fn reload(&mut self, config: &Config) -> Vec<Announce> {
        // [gateway], the output's connection and the outputs stay as started (as for the buses).
        let mut config = config.clone();
        config.gateway = self.config.gateway.clone();
        config.mqtt = self.config.mqtt.clone();
        config.outputs = self.config.outputs.clone();
        self.config = config;
        self.possible = possible_topics(&self.site, &self.config);
        let mut out = self.clear_where(|d, t| !d.possible(t));
        out.extend(self.start());
        let learned = std::mem::take(&mut self.learned);
        for ((bus, place, channel, kind), shape) in learned {
            let config = self.config.clone();
            let Some((b, device)) = config
                .enabled_devices()
                .find(|(b, d)| b.name == bus && d.place_tag() == place)
            else {
                continue;
            };
            let m = Module {
                bus: &b.name,
                device,
            };
            let spec = match device.channels_from_device() {
                true => Some(shape),
                false => channel_spec(m, &channel, kind),
            };
            if let Some(spec) = spec {
                let entities = channel_entities(&self.site, m, &spec);
                self.learned.insert((bus, place, channel, kind), spec);
                out.extend(self.announce(entities));
            }
        }
        self.refresh_unwanted();
        out.extend(self.clear_where(|d, t| d.unwanted.contains(t)));
        out
    }
}

impl Format for Discovery {
    /// The first reading of each channel announces its entities (none for other events).
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        match event {
            Output::DeviceReadings { readings, .. } => {
                let mut out = Vec::new();
                for r in readings {
                    out.extend(messages(self.reading(r)));
                }
                out
            }
            _ => Vec::new(),
        }
    }

    fn reload(&mut self, config: &Config) -> Vec<Message> {
        messages(Discovery::reload(self, config))
    }
}

impl Lifecycle for Discovery {
    /// Home Assistant's status (it says `online` after it starts) and this gateway's configs.
    fn subscriptions(&self) -> Vec<String> {
        vec![self.site.ha_status(), self.site.config_filter()]
    }

    /// The gateway device and each module's device-wide entities.
    fn start(&mut self) -> Vec<Message> {
        messages(Discovery::start(self))
    }

    fn received(&mut self, topic: &str, payload: &[u8]) -> Reaction {
        let out = if topic == self.site.ha_status() {
            messages(self.ha_status(payload, Instant::now()))
        } else if topic.starts_with(&format!("{}/", self.site.prefix)) && topic.ends_with("/config")
        {
            messages(self.config_seen(topic, payload))
        } else {
            Vec::new()
        };
        out.into()
    }

    /// A re-announcement put off by a flood of `online`.
    fn tick(&mut self, now: Instant) -> Vec<Message> {
        messages(self.due(now))
    }
}

#[cfg(test)]
mod tests;
