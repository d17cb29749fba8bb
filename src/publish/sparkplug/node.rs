//! The edge node as a value: sessions, births and deaths, `seq`, aliases, what the host's
//! commands mean. Pure: events, connection changes and received bytes in, messages out; the
//! bdSeq of each session comes from outside ([`super::bdseq`]).
//!
//! `seq` is given when a message goes to the wire ([`Node::outgoing`]), not when it is made:
//! readings spooled while the broker was away go out after the next session's births, and the
//! host must see one unbroken run 0..255 from the NBIRTH on. The same step marks what was
//! stored before this session `is_historical` and turns DDATA names into the aliases this
//! session's DBIRTH declared.

use std::collections::{BTreeMap, HashSet};

use bytes::Bytes;

use super::command::{HostCommandError, Write};
use super::host::{HostWatch, Rebirths, State};
use super::metrics::{self, Aliases, ChannelShape};
use super::proto::{Metric, Payload, Value, datatype};
use super::topic::{Kind, Topics};
use crate::command::{CommandError, Reply, Via, Written};
use crate::outbox::{Content, Message};
use crate::outcome::{CommandOutcome, Outcome};
use crate::publish::lifecycle::{Control, Reaction};
use crate::reading::{Output, Reading};

/// The NBIRTH/NDEATH metric that pairs a death with its birth.
pub const BD_SEQ: &str = "bdSeq";

/// The NBIRTH metric that says which config the gateway runs (`Config::hash`).
pub const CONFIG_HASH: &str = "Properties/Config Hash";

/// The node metrics that answer a host's command (in the NBIRTH when the node takes commands;
/// an NDATA sets all four for each command answered): the device and metric it wrote, `ok`
/// or the refusal's code, and what a person reads.
pub const ANSWER: [&str; 4] = [
    "Command/Device",
    "Command/Metric",
    "Command/Result",
    "Command/Message",
];

/// What the node knows of a device's availability.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Status {
    /// Not heard of yet in this run: born with null values, so spooled data has a birth.
    Unknown,
    Online,
    Offline,
}

/// One device of the node.
#[derive(Debug)]
struct DeviceNode {
    shapes: Vec<ChannelShape>,
    status: Status,
    /// Its DBIRTH went out in this session; the metric names it declared.
    declared: Option<HashSet<String>>,
    /// The last reading of each channel, for the next birth.
    last: BTreeMap<String, Reading>,
}

/// How the node is set up (from `[sparkplug]`, `[mqtt]` and the devices).
#[derive(Debug, Clone)]
pub struct Setup {
    pub topics: Topics,
    /// Where DCMD writes go: the JSON command topics the command router takes.
    pub commands: crate::topics::Topics,
    /// The output the node publishes for: answers to its host's commands come back to it.
    pub output: std::sync::Arc<str>,
    /// The output takes commands (`commands` of its connection): the births declare the
    /// writable metrics and the answer metrics.
    pub takes_commands: bool,
    /// The hash of the config in force, a node property of the NBIRTH ([`CONFIG_HASH`]).
    pub config_hash: String,
    pub primary_host: Option<String>,
    /// QoS of births and data (the will is QoS 1).
    pub qos: u8,
    /// Devices in config order, with their channels.
    pub devices: Vec<(String, Vec<ChannelShape>)>,
}

/// The edge node.
#[derive(Debug)]
pub struct Node {
    setup: Setup,
    devices: BTreeMap<String, DeviceNode>,
    aliases: Aliases,
    connected: bool,
    /// The primary host said it is online (always, without a primary host).
    host_online: bool,
    /// The NBIRTH of this session went out.
    born: bool,
    /// The `seq` of the next numbered message.
    seq: u8,
    /// The session's bdSeq.
    bd_seq: u8,
    /// Refused commands logged per minute.
    log_budget: crate::log_budget::LogBudget,
    /// The primary host's STATE as last taken.
    host: HostWatch,
    /// The host's rebirth requests, coalesced.
    rebirths: Rebirths,
    /// The `seq` before the last message [`Node::outgoing`] numbered, until the next: the
    /// client may not take it ([`Node::unsent`]).
    rewind: Option<u8>,
}

impl Node {
    pub fn new(setup: Setup) -> Node {
        let devices = setup
            .devices
            .iter()
            .map(|(name, shapes)| {
                let d = DeviceNode {
                    shapes: shapes.clone(),
                    status: Status::Unknown,
                    declared: None,
                    last: BTreeMap::new(),
                };
                (name.clone(), d)
            })
            .collect();
        Node {
            host_online: setup.primary_host.is_none(),
            setup,
            devices,
            aliases: Aliases::default(),
            connected: false,
            born: false,
            seq: 0,
            bd_seq: 0,
            log_budget: crate::log_budget::LogBudget::new(20),
            host: HostWatch::default(),
            rebirths: Rebirths::default(),
            rewind: None,
        }
    }

    /// Another config is in force (the next NBIRTH says so); whether it changed.
    pub fn set_config_hash(&mut self, hash: String) -> bool {
        hash != std::mem::replace(&mut self.setup.config_hash, hash.clone())
    }

    /// Every birth again now, when the node is born (its description changed).
    pub fn rebirth(&mut self, now_ms: u64) -> Vec<Message> {
        if self.connected && self.born {
            self.births_queued(now_ms)
        } else {
            Vec::new()
        }
    }

    /// The devices or their channels changed (a reload): the node describes the new ones, with
    /// a rebirth when it is born.
    pub fn reshape(
        &mut self,
        devices: Vec<(String, Vec<ChannelShape>)>,
        now_ms: u64,
    ) -> Vec<Message> {
        let mut old = std::mem::take(&mut self.devices);
        for (name, shapes) in &devices {
            let kept = old.remove(name);
            let d = DeviceNode {
                shapes: shapes.clone(),
                status: kept.as_ref().map_or(Status::Unknown, |d| d.status),
                declared: None,
                last: kept.map(|d| d.last).unwrap_or_default(),
            };
            self.devices.insert(name.clone(), d);
        }
        self.setup.devices = devices;
        if self.connected && self.born {
            self.births_queued(now_ms)
        } else {
            Vec::new()
        }
    }

    /// The filters the node reads: its NCMD and DCMDs, and its primary host's state.
    pub fn subscriptions(&self, commands: bool) -> Vec<String> {
        let t = &self.setup.topics;
        let mut out = vec![t.node(Kind::NCmd)];
        if commands {
            out.push(t.device(Kind::DCmd, "+"));
        }
        if let Some(host) = &self.setup.primary_host {
            out.push(Topics::state(host));
        }
        out
    }

    /// A new session starts with `bd_seq`; its will is the NDEATH carrying it.
    pub fn will(&mut self, bd_seq: u8, now_ms: u64) -> (String, Bytes) {
        self.bd_seq = bd_seq;
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics: vec![Metric::new(
                BD_SEQ,
                None,
                datatype::INT64,
                Some(Value::Long(bd_seq.into())),
            )],
            ..Payload::default()
        };
        (
            self.setup.topics.node(Kind::NDeath),
            payload.encode().into(),
        )
    }

    /// The NDEATH of this session, for a clean stop (the broker sends the will otherwise).
    pub fn death(&mut self, now_ms: u64) -> Message {
        let (topic, payload) = self.will(self.bd_seq, now_ms);
        self.born = false;
        Message::new(topic, payload, 1, false)
    }

    /// A command topic of this node (NCMD, DCMD).
    pub fn is_command(&self, topic: &str) -> bool {
        matches!(
            self.setup.topics.parse(topic),
            Some((Kind::NCmd | Kind::DCmd, _))
        )
    }

    /// Connected: the births, unless the primary host is not online yet.
    pub fn connected(&mut self, now_ms: u64) -> Vec<Message> {
        self.connected = true;
        if self.host_online {
            self.births(now_ms)
        } else {
            Vec::new()
        }
    }

    /// The session is over: everything is born again in the next one.
    pub fn disconnected(&mut self) {
        self.connected = false;
        self.born = false;
        self.rewind = None;
        for d in self.devices.values_mut() {
            d.declared = None;
        }
    }

    /// NBIRTH and the DBIRTH of every device not known to be offline, numbered from 0: births
    /// that go straight to the wire (at a connection, the primary host back), ahead of what the
    /// outbox holds.
    pub fn births(&mut self, now_ms: u64) -> Vec<Message> {
        self.birth_set(now_ms, true)
    }

    /// The same births for the outbox, behind what it holds: numbered when they leave
    /// ([`Node::outgoing`]), not now (messages made before them are still to be numbered: a
    /// number taken now would be on the wire after theirs).
    fn births_queued(&mut self, now_ms: u64) -> Vec<Message> {
        self.birth_set(now_ms, false)
    }

    fn birth_set(&mut self, now_ms: u64, numbered: bool) -> Vec<Message> {
        self.born = true;
        self.rewind = None;
        let mut metrics = vec![Metric::new(
            BD_SEQ,
            None,
            datatype::INT64,
            Some(Value::Long(self.bd_seq.into())),
        )];
        for control in super::command::NODE_CONTROLS {
            let off = Some(Value::Boolean(false));
            metrics.push(Metric::new(control, None, datatype::BOOLEAN, off));
        }
        let hash = Some(Value::String(self.setup.config_hash.clone()));
        metrics.push(Metric::new(CONFIG_HASH, None, datatype::STRING, hash));
        if self.setup.takes_commands {
            for name in ANSWER {
                let empty = Some(Value::String(String::new()));
                metrics.push(Metric::new(name, None, datatype::STRING, empty));
            }
        }
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics,
            seq: numbered.then(|| self.number(Kind::NBirth)),
            ..Payload::default()
        };
        let mut out = vec![self.message(self.setup.topics.node(Kind::NBirth), &payload)];
        let names: Vec<String> = self.devices.keys().cloned().collect();
        for name in names {
            if self.devices[&name].status != Status::Offline {
                let mut m = self.device_birth(&name, now_ms, numbered);
                out.append(&mut m);
            }
        }
        out
    }

    /// The DBIRTH of `device`: numbered now when it goes straight to the wire with the
    /// NBIRTH, else when it leaves the outbox.
    fn device_birth(&mut self, device: &str, now_ms: u64, numbered: bool) -> Vec<Message> {
        let Some(d) = self.devices.get_mut(device) else {
            return Vec::new();
        };
        let metrics = metrics::birth(device, &d.shapes, &d.last, &mut self.aliases);
        d.declared = Some(metrics.iter().filter_map(|m| m.name.clone()).collect());
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics,
            seq: numbered.then(|| self.number(Kind::DBirth)),
            ..Payload::default()
        };
        let topic = self.setup.topics.device(Kind::DBirth, device);
        vec![self.message(topic, &payload)]
    }

    /// The messages of one event of the buses.
    pub fn event(&mut self, event: &Output, now_ms: u64) -> Vec<Message> {
        match event {
            Output::DeviceReadings { device, readings } => self.readings(device, readings, now_ms),
            Output::DeviceStatus { device, online } => {
                if *online {
                    self.online(device, now_ms)
                } else {
                    self.offline(device)
                }
            }
            Output::DeviceProblem { device, status } if *status == "wrong_model" => {
                self.offline(device)
            }
            Output::CommandResult { reply, outcome } => self.answer(reply, outcome, now_ms),
            _ => Vec::new(),
        }
    }

    /// The answer to a command the host wrote to this node: an NDATA setting the answer
    /// metrics ([`ANSWER`]). Answers to anyone else's commands are not the node's.
    fn answer(&mut self, reply: &Reply, outcome: &Outcome, now_ms: u64) -> Vec<Message> {
        let Some(Via {
            output,
            wrote: Some(wrote),
        }) = &reply.via
        else {
            return Vec::new();
        };
        if **output != *self.setup.output {
            return Vec::new();
        }
        let (result, message) = match outcome.refusal() {
            None => ("ok".to_string(), String::new()),
            Some(code) => (
                code.to_string(),
                outcome.to_json()["message"]
                    .as_str()
                    .unwrap_or_default()
                    .to_string(),
            ),
        };
        let values = [wrote.device.clone(), wrote.metric.clone(), result, message];
        let metrics = ANSWER
            .iter()
            .zip(values)
            .map(|(name, v)| Metric::new(name, None, datatype::STRING, Some(Value::String(v))))
            .collect();
        let payload = Payload {
            timestamp: Some(now_ms),
            metrics,
            ..Payload::default()
        };
        let topic = self.setup.topics.node(Kind::NData);
        vec![self.message(topic, &payload).carrying(Content::Answer)]
    }

    /// A device answers: its DBIRTH when the session has none for it.
    fn online(&mut self, device: &str, now_ms: u64) -> Vec<Message> {
        let Some(d) = self.devices.get_mut(device) else {
            return Vec::new();
        };
        d.status = Status::Online;
        if self.connected && self.born && d.declared.is_none() {
            self.device_birth(device, now_ms, false)
        } else {
            Vec::new()
        }
    }

    /// A device is lost (offline, or the wrong model): its DDEATH when it was born.
    fn offline(&mut self, device: &str) -> Vec<Message> {
        let Some(d) = self.devices.get_mut(device) else {
            return Vec::new();
        };
        d.status = Status::Offline;
        if d.declared.take().is_none() || !self.connected {
            return Vec::new();
        }
        let payload = Payload {
            timestamp: Some(crate::reading::unix_ms(std::time::SystemTime::now())),
            ..Payload::default()
        };
        let topic = self.setup.topics.device(Kind::DDeath, device);
        vec![self.message(topic, &payload)]
    }

    /// One DDATA with the readings of one poll (after a DBIRTH when the device needs one:
    /// first reading of the session, or a channel that changed its kind).
    fn readings(&mut self, device: &str, readings: &[Reading], now_ms: u64) -> Vec<Message> {
        let Some(d) = self.devices.get_mut(device) else {
            return Vec::new();
        };
        let mut metrics = Vec::new();
        for r in readings {
            if !d.shapes.iter().any(|s| *s.name == *r.channel) {
                // A channel its device declared (an M-Bus record): born with its first reading.
                d.shapes.push(ChannelShape::of_reading(r));
                d.declared = None;
            }
            let Some(shape) = d.shapes.iter_mut().find(|s| *s.name == *r.channel) else {
                continue;
            };
            if shape.kind != r.kind {
                shape.kind = r.kind; // a mode change: its total changes type
                d.declared = None;
            }
            metrics.extend(metrics::data(r, shape, &mut self.aliases));
            d.last.insert(r.channel.to_string(), r.clone());
        }
        if metrics.is_empty() {
            return Vec::new();
        }
        // Made while the host cannot see it (away, or held for the primary host): history.
        if !(self.connected && self.born) {
            for m in &mut metrics {
                m.is_historical = Some(true);
            }
        }
        let mut out = self.online(device, now_ms);
        let payload = Payload {
            timestamp: readings.iter().map(|r| crate::reading::unix_ms(r.ts)).max(),
            metrics,
            ..Payload::default()
        };
        let topic = self.setup.topics.device(Kind::DData, device);
        out.push(self.message(topic, &payload));
        out
    }

    fn message(&self, topic: String, payload: &Payload) -> Message {
        Message::new(topic, payload.encode(), self.setup.qos, false)
    }

    /// The `seq` of the next message of `kind`: an NBIRTH starts again at 0.
    fn number(&mut self, kind: Kind) -> u64 {
        if kind == Kind::NBirth {
            self.seq = 0;
        }
        let n = self.seq;
        self.seq = n.wrapping_add(1);
        n.into()
    }

    /// A message of the outbox goes to the wire: the node's own are numbered, DDATA gets the
    /// aliases this session declared, and what was stored before this session (`replay`) is
    /// marked historical. `None` for what is not the node's (or cannot be read: sent as is).
    pub fn outgoing(&mut self, topic: &str, payload: &[u8], replay: bool) -> Option<Bytes> {
        let (kind, device) = self.setup.topics.parse(topic)?;
        if !kind.numbered() {
            return None;
        }
        self.rewind = Some(self.seq);
        self.number_on_the_wire(kind, device, payload, replay)
    }

    /// The client did not take the message [`Node::outgoing`] last numbered (its queue was
    /// full): it is offered again later and takes the same number, or the host would see a gap.
    /// Told, never guessed from the bytes: two answers may be byte for byte the same.
    pub fn unsent(&mut self) {
        if let Some(seq) = self.rewind.take() {
            self.seq = seq;
        }
    }

    fn number_on_the_wire(
        &mut self,
        kind: Kind,
        device: Option<&str>,
        payload: &[u8],
        replay: bool,
    ) -> Option<Bytes> {
        let mut p = Payload::decode(payload).ok()?;
        p.seq = Some(self.number(kind));
        match kind {
            Kind::NBirth => {
                for m in p
                    .metrics
                    .iter_mut()
                    .filter(|m| m.name.as_deref() == Some(BD_SEQ))
                {
                    m.value = Some(Value::Long(self.bd_seq.into()));
                }
            }
            Kind::DData | Kind::NData => {
                let declared = device
                    .and_then(|d| self.devices.get(d))
                    .and_then(|d| d.declared.as_ref());
                for m in &mut p.metrics {
                    alias_only(m, declared);
                    if replay {
                        m.is_historical = Some(true);
                    }
                }
            }
            _ => {}
        }
        Some(p.encode().into())
    }

    /// A message on one of the node's subscriptions: births for a rebirth request or the
    /// primary host coming online, commands for DCMD writes. Anything else is not the node's.
    pub fn received(&mut self, topic: &str, payload: &[u8], now_ms: u64) -> Reaction {
        if let Some(host) = &self.setup.primary_host
            && topic == Topics::state(host)
        {
            return self.host_state(payload, now_ms);
        }
        match self.setup.topics.parse(topic) {
            Some((Kind::NCmd, None)) => self.node_command(payload, now_ms),
            Some((Kind::DCmd, Some(device))) => self.device_command(device, payload),
            _ => Reaction::default(),
        }
    }

    /// Connected and waiting for the primary host: the MQTT task keeps the outbox (what it
    /// holds goes out after the births, flagged historical).
    pub fn holding(&self) -> bool {
        self.connected && !self.born
    }

    /// A rebirth the host asked for within the gap, now that it is over.
    pub fn tick(&mut self, now_ms: u64) -> Vec<Message> {
        if self.connected && self.born && self.rebirths.due(now_ms) {
            tracing::info!(
                requests = self.rebirths.requested,
                "Sparkplug rebirth for the host's requests of the last seconds"
            );
            return self.births_queued(now_ms);
        }
        Vec::new()
    }

    /// What the node counted of its host: STATE messages ignored, rebirths asked and done.
    pub fn tallies(&self) -> Vec<(&'static str, u64)> {
        vec![
            ("host_state_ignored", self.host.ignored),
            ("rebirth_requested", self.rebirths.requested),
            ("rebirth", self.rebirths.done),
        ]
    }

    /// Why it holds, while it does.
    pub fn held(&self) -> Option<String> {
        let host = self.setup.primary_host.as_deref().unwrap_or_default();
        self.holding()
            .then(|| format!("Sparkplug primary host {host:?} is offline"))
    }

    /// `spBv1.0/STATE/<host>`: online, the births at once (ahead of what was held for them);
    /// offline, an NDEATH and quiet until the host is back (the spec's node disconnects; this
    /// one keeps its connection for the other formats and holds its output).
    fn host_state(&mut self, payload: &[u8], now_ms: u64) -> Reaction {
        let online = match self.host.state(payload) {
            State::Accepted { online } => online,
            State::Stale { timestamp, last } => {
                let why = format!(
                    "its timestamp {timestamp} is older than the last one taken ({last}): ignored"
                );
                self.refused("primary host STATE", &why);
                return Reaction::default();
            }
            State::Malformed(why) => {
                self.refused("primary host STATE", &format!("{why}: ignored"));
                return Reaction::default();
            }
        };
        let was = self.host_online;
        self.host_online = online;
        let mut at_once = Vec::new();
        if online && !was && self.connected && !self.born {
            tracing::info!("Sparkplug primary host online: publishing births");
            at_once = self.births(now_ms);
        }
        if !online && was {
            tracing::warn!("Sparkplug primary host offline: output held until it is back");
            if self.connected && self.born {
                at_once.push(self.death(now_ms));
            }
            self.born = false;
            for d in self.devices.values_mut() {
                d.declared = None;
            }
        }
        Reaction {
            at_once,
            ..Reaction::default()
        }
    }

    /// NCMD: `Node Control/Rebirth` = true is answered with every birth again, at most once
    /// every few seconds (a burst of requests is one rebirth now and one at the end of the gap);
    /// `Reboot` and `Next Server` are the output's and the gateway's to carry out.
    fn node_command(&mut self, payload: &[u8], now_ms: u64) -> Reaction {
        let asked = match super::command::node(payload) {
            Ok(asked) => asked,
            Err(e) => {
                self.refused("NCMD", &e.to_string());
                return Reaction::default();
            }
        };
        let mut r = Reaction::default();
        if asked.reboot {
            tracing::warn!("Sparkplug host asked the node to reboot");
            r.control.push(Control::Reboot);
        }
        if asked.next_server {
            tracing::info!("Sparkplug host asked the node to move to its next server");
            r.control.push(Control::NextServer);
        }
        if asked.rebirth && self.connected && self.host_online && self.rebirths.request(now_ms) {
            tracing::info!("Sparkplug host asked for a rebirth");
            r.messages = self.births_queued(now_ms);
        }
        r
    }

    /// DCMD: writes to `<c>/Clear` and `<c>/Preset` of a writable channel, as commands for the
    /// command router; a DCMD the node cannot take is refused whole and answered.
    fn device_command(&mut self, device: &str, payload: &[u8]) -> Reaction {
        match self.writes(device, payload) {
            Ok(writes) => Reaction {
                commands: writes
                    .into_iter()
                    .map(|w| w.incoming(&self.setup.commands, device, &self.setup.output))
                    .collect(),
                ..Reaction::default()
            },
            Err(e) => {
                self.refused("DCMD", &format!("{device}: {e}"));
                Reaction {
                    answers: vec![self.refusal(device, &e)],
                    ..Reaction::default()
                }
            }
        }
    }

    /// The writes of a DCMD to `device`, each to a writable channel of it.
    fn writes(&self, device: &str, payload: &[u8]) -> Result<Vec<Write>, HostCommandError> {
        let d = self
            .devices
            .get(device)
            .ok_or_else(|| HostCommandError::UnknownDevice(device.to_string()))?;
        let names = |alias: u64| {
            d.declared
                .iter()
                .flatten()
                .find(|n| self.aliases.get(device, n) == Some(alias))
                .cloned()
        };
        let writes = super::command::device(payload, names)?;
        for w in &writes {
            let (Write::Clear { channel } | Write::Preset { channel, .. }) = w;
            if !d.shapes.iter().any(|s| s.name == *channel && s.writable) {
                return Err(HostCommandError::NotWritable(w.metric()));
            }
        }
        Ok(writes)
    }

    /// The answer to a DCMD refused before it became a command.
    fn refusal(&self, device: &str, e: &HostCommandError) -> Output {
        let metric = match e {
            HostCommandError::NotWritable(m) => m.clone(),
            HostCommandError::BadValue { metric, .. } => metric.clone(),
            _ => String::new(),
        };
        let via = Via {
            output: self.setup.output.clone(),
            wrote: Some(Written {
                device: device.to_string(),
                metric,
            }),
        };
        let result = Err(CommandError::Protocol {
            code: e.code(),
            message: e.to_string(),
        });
        Output::CommandResult {
            reply: Reply {
                topics: Vec::new(),
                correlation: None,
                via: Some(via),
            },
            outcome: Outcome::Command(CommandOutcome {
                id: None,
                op: None,
                result,
            }),
        }
    }

    /// Logs a refused command or state, within the budget (a flood of bad commands is counted, not
    /// logged line by line).
    fn refused(&mut self, what: &str, why: &str) {
        let (log, suppressed) = self.log_budget.allow(tokio::time::Instant::now());
        if let Some(n) = suppressed {
            tracing::warn!(
                suppressed = n,
                "Sparkplug commands refused in the last minute, not logged one by one"
            );
        }
        if log {
            tracing::warn!("Sparkplug {what} refused: {why}");
        }
    }
}

/// A DDATA metric as it goes out: its alias alone when this session's DBIRTH declared its name,
/// else its name alone (a host reads either; an alias the host never saw would be an error).
fn alias_only(m: &mut Metric, declared: Option<&HashSet<String>>) {
    let known = match (&m.name, declared) {
        (Some(name), Some(set)) => set.contains(name),
        _ => false,
    };
    if known && m.alias.is_some() {
        m.name = None;
        m.datatype = None;
    } else if m.name.is_some() {
        m.alias = None;
    }
}

#[cfg(test)]
#[path = "node_tests.rs"]
mod tests;
