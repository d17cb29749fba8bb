//! Sparkplug B (Eclipse Sparkplug 3.0): the gateway as an edge node, its modules as devices.
//! The format of an output of kind `sparkplug`, set up by `[sparkplug]`; docs/sparkplug.md
//! tells what a SCADA host sees.
//!
//! [`node`] is the state machine (births, deaths, `seq`, aliases, commands), [`metrics`] what a
//! channel publishes, [`proto`] the payload, [`topic`] the topic names, [`command`] what the
//! host sends, [`bdseq`] the birth/death number kept across restarts. This file only builds
//! the node from the config and puts it behind the output stage's [`Format`] (its encoder) and
//! [`Lifecycle`] (births at connect, the NDEATH as its will, its hold, commands).

pub mod bdseq;
pub mod command;
pub mod host;
pub mod metrics;
pub mod node;
pub mod proto;
pub mod topic;

use std::collections::BTreeSet;
use std::time::SystemTime;

use crate::config::{Config, OutputConfig};
use bytes::Bytes;

use crate::config::outputs::sparkplug::Sparkplug as Settings;
use crate::outbox::{Message, Will};
use crate::publish::format::Format;
use crate::publish::lifecycle::{Lifecycle, Reaction};
use crate::reading::{Output, unix_ms};
use metrics::ChannelShape;
use node::{Node, Setup};

/// The Sparkplug B format of a gateway.
#[derive(Debug)]
pub struct Sparkplug {
    node: Node,
    bd_seq: bdseq::BdSeq,
    /// `mqtt.commands`: DCMD is subscribed only when commands are taken at all.
    commands: bool,
    /// The devices and channels the births describe (a reload that changes them rebirths).
    devices: Vec<(String, Vec<ChannelShape>)>,
    /// The output it publishes for (its settings as started).
    output: OutputConfig,
}

impl Sparkplug {
    /// The edge node of `output` (its QoS, commands and name; the node's ids from
    /// `[sparkplug]`).
    pub fn new(config: &Config, output: &OutputConfig) -> Sparkplug {
        let setup = setup(config, output);
        Sparkplug {
            devices: setup.devices.clone(),
            node: Node::new(setup),
            bd_seq: bdseq::BdSeq::load(&config.gateway.state_dir, &output.name),
            commands: output.mqtt.commands,
            output: output.clone(),
        }
    }
}

fn now_ms() -> u64 {
    unix_ms(SystemTime::now())
}

/// The node's setup from a checked config. `check` refuses an output of kind `sparkplug`
/// without `[sparkplug]`; a config built another way gets the gateway id as group and node.
fn setup(config: &Config, output: &OutputConfig) -> Setup {
    let (group, node, host) = match config.outputs.settings::<Settings>() {
        Some(s) => (
            s.group_id.clone(),
            s.edge_node_id.clone(),
            s.primary_host.clone(),
        ),
        None => {
            tracing::error!("Sparkplug output without [sparkplug]: using the gateway id as group");
            (config.gateway.id.clone(), config.gateway.id.clone(), None)
        }
    };
    Setup {
        topics: topic::Topics::new(&group, &node),
        commands: crate::topics::Topics::new(&config.mqtt.topic_root),
        output: output.name.as_str().into(),
        takes_commands: output.mqtt.commands,
        config_hash: config.hash().to_string(),
        primary_host: host,
        qos: output.mqtt.qos,
        devices: shapes(config, output.mqtt.commands),
    }
}

/// Every enabled device with the channels its profile can have (one shape per name, in the
/// profile's order; a channel whose kind depends on the mode takes the first and is born again
/// when a reading says otherwise), less the disabled ones.
pub fn shapes(config: &Config, commands: bool) -> Vec<(String, Vec<ChannelShape>)> {
    let mut out = Vec::new();
    for (_, d) in config.enabled_devices() {
        let all = d.profile.all_channels();
        let mut seen = BTreeSet::new();
        let mut shapes = Vec::new();
        for c in &all {
            let settings = d.channels.get(&c.name);
            if settings.is_some_and(|s| !s.enabled) || !seen.insert(c.name.clone()) {
                continue;
            }
            let same = all.iter().filter(|o| o.name == c.name);
            let (freq, rpm) = same.fold((false, false), |(f, r), o| {
                (f || o.freq.is_some(), r || o.rpm.is_some())
            });
            let units = settings.map(|s| &s.units);
            shapes.push(ChannelShape {
                name: c.name.clone(),
                kind: c.kind,
                freq,
                rpm,
                value_unit: units.and_then(|u| u.scale.map(|_| u.unit.clone())),
                writable: commands && d.commands && d.writable_counts(),
                gauge: None,
                obis: units.and_then(|u| u.obis).map(|o| o.to_string()),
            });
        }
        out.push((d.name.clone(), shapes));
    }
    out
}

impl Format for Sparkplug {
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        self.node.event(event, now_ms())
    }

    /// Devices or channels changed: the node is born again with them (same session and bdSeq).
    fn reload(&mut self, config: &Config) -> Vec<Message> {
        let fresh = setup(config, &self.output);
        let hash_moved = self.node.set_config_hash(fresh.config_hash);
        if fresh.devices == self.devices {
            return if hash_moved {
                self.node.rebirth(now_ms())
            } else {
                Vec::new()
            };
        }
        self.devices = fresh.devices.clone();
        self.node.reshape(fresh.devices, now_ms())
    }
}

impl Lifecycle for Sparkplug {
    fn subscriptions(&self) -> Vec<String> {
        self.node.subscriptions(self.commands)
    }

    fn received(&mut self, topic: &str, payload: &[u8]) -> Reaction {
        self.node.received(topic, payload, now_ms())
    }

    /// A retained NCMD or DCMD is stale (the spec forbids retaining them): ignored. The
    /// primary host's retained STATE is what it is there for.
    fn received_retained(&mut self, topic: &str, payload: &[u8]) -> Reaction {
        if self.node.is_command(topic) {
            tracing::warn!(%topic, "retained Sparkplug command ignored");
            return Reaction::default();
        }
        self.received(topic, payload)
    }

    /// The births, straight to the wire before the backlog.
    fn connected(&mut self) -> Vec<Message> {
        self.node.connected(now_ms())
    }

    fn disconnected(&mut self) {
        self.node.disconnected();
    }

    /// The NDEATH of the next connection, with its own bdSeq (taken and saved now).
    fn will(&mut self) -> Option<Will> {
        let (topic, payload) = self.node.will(self.bd_seq.take(), now_ms());
        Some(Will {
            topic,
            payload,
            qos: 1,
            retain: false,
        })
    }

    /// A clean stop says what the will would have said.
    fn stopping(&mut self) -> Vec<Message> {
        vec![self.node.death(now_ms())]
    }

    fn held(&self) -> Option<String> {
        self.node.held()
    }

    fn outgoing(&mut self, topic: &str, payload: &Bytes, replay: bool) -> Option<Bytes> {
        self.node.outgoing(topic, payload, replay)
    }

    fn unsent(&mut self) {
        self.node.unsent();
    }

    /// A rebirth the host's requests left owed.
    fn tick(&mut self, _now: tokio::time::Instant) -> Vec<Message> {
        self.node.tick(now_ms())
    }

    fn tallies(&self) -> Vec<(&'static str, u64)> {
        self.node.tallies()
    }
}

#[cfg(test)]
mod tests;
