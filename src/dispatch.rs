//! Routes command messages from MQTT to the bus of their device, after every check that needs no
//! module, and publishes each result. Retained command messages are ignored: a stale retained
//! clear must not fire at every start.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::Bytes;
use tokio::sync::mpsc::{Receiver, UnboundedSender};
use tokio::sync::oneshot;
use tokio::time::Instant;

use crate::admission::Admission;
use crate::bus::BusCommand;
use crate::command::{self, CommandError, Reply, Request};
use crate::config::Config;
use crate::dedupe::{Dedupe, Seen};
use crate::log_budget::LogBudget;
use crate::outcome::{CommandOutcome, Outcome, ScanOutcome};
use crate::reading::Output;
use crate::scan::{self, ScanRequest};
use crate::topics::ResponseRule;

fn targets_of(
    config: &Config,
    buses: &HashMap<String, UnboundedSender<BusCommand>>,
) -> HashMap<String, Target> {
    config
        .devices()
        .filter_map(|(bus, d)| {
            let target = Target {
                bus: buses.get(&bus.name)?.clone(),
                bus_name: bus.name.clone(),
                unit: d.unit,
                scanned: d.commands,
                commands: d.commands && d.enabled && bus.enabled,
                channels: d
                    .profile
                    .all_channels()
                    .into_iter()
                    .map(|c| c.name)
                    .collect(),
                channels_from_device: d.channels_from_device(),
            };
            Some((d.name.clone(), target))
        })
        .collect()
}

/// A message that arrived on a command topic (or a command of an output's own protocol, put
/// as one), and the connection it came in on.
#[derive(Debug, Clone)]
pub struct Incoming {
    pub topic: String,
    pub payload: Bytes,
    pub retain: bool,
    pub response_topic: Option<String>,
    pub correlation: Option<Bytes>,
    pub via: Option<crate::command::Via>,
}

/// Where a device's commands go.
pub struct Target {
    bus: UnboundedSender<BusCommand>,
    bus_name: String,
    unit: u8,
    /// `commands = false` also keeps the device out of scans over MQTT: its unit is neither
    /// asked nor named in the result.
    scanned: bool,
    commands: bool,
    channels: BTreeSet<String>,
    /// The device's channels are what it answers (an M-Bus meter's records): the bus knows
    /// them, not the config.
    channels_from_device: bool,
}

/// Command messages between the MQTT connection and the router: when full, the connection
/// waits (TCP pushes back on the sender) instead of the gateway buffering without bound.
pub const INCOMING_QUEUE: usize = 256;

/// How long a command waits for an offline device.
pub const EXPIRY: Duration = Duration::from_secs(10);

/// Devices by name, swapped whole when the config is reloaded.
pub type Targets = Arc<std::sync::RwLock<HashMap<String, Target>>>;

/// Where each bus takes scan requests, swapped whole when the config is reloaded.
pub type Scans = Arc<std::sync::RwLock<HashMap<String, tokio::sync::mpsc::Sender<ScanRequest>>>>;

/// The command router of a gateway.
pub struct Router {
    topics: crate::topics::Topics,
    /// Where a response topic may point (see [`ResponseRule`]).
    responses: ResponseRule,
    targets: Targets,
    out: UnboundedSender<Output>,
    dedupe: Arc<Mutex<Dedupe>>,
    admission: Arc<Mutex<Admission>>,
    log_budget: Mutex<LogBudget>,
    scans: Scans,
    /// Where a pushed config goes (`[remote] config = true`), one at a time.
    remote: Option<tokio::sync::mpsc::Sender<Incoming>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Router {
    /// A router for `config`, sending to the bus command channels by bus name.
    pub fn new(
        config: &Config,
        buses: &HashMap<String, UnboundedSender<BusCommand>>,
        out: UnboundedSender<Output>,
    ) -> Router {
        Router {
            topics: crate::topics::Topics::new(&config.mqtt.topic_root),
            responses: ResponseRule::new(
                &config.mqtt.topic_root,
                config.outputs.reserved_prefixes(),
            ),
            targets: Arc::new(std::sync::RwLock::new(targets_of(config, buses))),
            out,
            dedupe: Arc::default(),
            admission: Arc::default(),
            log_budget: Mutex::new(LogBudget::new(20)),
            scans: Arc::default(),
            remote: None,
        }
    }

    /// Pushed configs (`<root>/config/set`) go to `remote`.
    pub fn with_remote(mut self, remote: tokio::sync::mpsc::Sender<Incoming>) -> Router {
        self.remote = Some(remote);
        self
    }

    /// `<root>/config/set`: to the remote config task, which answers it (a retained one too:
    /// it is refused there, with its id); while it works on one, another is answered `busy`,
    /// and so is one that arrives while the process stops to start again.
    fn config_push(&self, msg: Incoming) {
        let Some(remote) = &self.remote else {
            return self.warn(&msg.topic, "a pushed config, but [remote] config is off");
        };
        if let Err(e) = remote.try_send(msg) {
            let (msg, message) = match e {
                tokio::sync::mpsc::error::TrySendError::Full(m) => (
                    m,
                    "a pushed config is being applied or watched: push again after its result",
                ),
                tokio::sync::mpsc::error::TrySendError::Closed(m) => (
                    m,
                    "the gateway is starting again for an earlier push: push again after its result",
                ),
            };
            let id = crate::remote::parse(&msg.payload).ok().and_then(|p| p.id);
            self.warn(&msg.topic, "a pushed config refused: busy");
            let outcome = crate::outcome::ConfigOutcome {
                id,
                status: "refused",
                error: Some("busy"),
                message: message.into(),
                hash: None,
            };
            let reply = Reply {
                topics: vec![self.topics.config_result()],
                correlation: None,
                via: None,
            };
            self.send(&reply, Outcome::Config(outcome));
        }
    }

    /// The router's table of bus scan channels, to fill at start and after a reload.
    pub fn scans(&self) -> Scans {
        self.scans.clone()
    }

    /// `<root>/bus/<bus>/scan`: a survey of the bus in its idle line time.
    fn scan(&self, bus: &str, msg: &Incoming) {
        let mut reply = Reply {
            topics: vec![crate::topics::Topics::result(&msg.topic)],
            correlation: None,
            via: msg.via.clone(),
        };
        let refuse = |reply: &Reply, code: &'static str, message: String| {
            self.warn(&msg.topic, &format!("scan refused: {message}"));
            let refused = ScanOutcome::Refused {
                bus: bus.to_string(),
                id: None,
                code,
                message,
            };
            self.send(reply, Outcome::Scan(refused));
        };
        // The same checks as for commands: nothing unsendable reaches the spool.
        if msg.payload.len() > command::MAX_PAYLOAD {
            let size = msg.payload.len();
            return refuse(&reply, "too_large", format!("the payload is {size} bytes"));
        }
        if let Some(c) = &msg.correlation
            && c.len() > command::MAX_CORRELATION
        {
            return refuse(&reply, "too_large", "correlation data too long".into());
        }
        if let Some(rt) = &msg.response_topic {
            if let Err(e) = check_response_topic(&self.responses, rt) {
                return refuse(&reply, e.code(), e.to_string());
            }
            reply.topics.push(rt.clone());
            reply.correlation = msg.correlation.clone();
        }
        let (mut units, id) = match scan::parse_scan_payload(&msg.payload) {
            Ok(p) => p,
            Err(e) => return refuse(&reply, "bad_payload", e),
        };
        let targets = self.targets.read().unwrap_or_else(|e| e.into_inner());
        units.retain(|u| {
            !targets
                .values()
                .any(|t| !t.scanned && t.bus_name == bus && t.unit == *u)
        });
        drop(targets);
        let scans = self.scans.read().unwrap_or_else(|e| e.into_inner());
        let Some(tx) = scans.get(bus) else {
            return refuse(&reply, "unknown_bus", format!("no bus {bus:?}"));
        };
        let req = ScanRequest {
            units,
            id,
            reply: reply.clone(),
            progress: crate::topics::Topics::scan_progress(&msg.topic),
        };
        if tx.try_send(req).is_err() {
            refuse(
                &reply,
                "busy",
                "a scan of this bus is already waiting".into(),
            );
        }
    }

    /// The router's device table, to update after a reload.
    pub fn targets(&self) -> Targets {
        self.targets.clone()
    }

    /// Points the router at the devices of a reloaded config.
    pub fn set_targets(
        targets: &Targets,
        config: &Config,
        buses: &HashMap<String, UnboundedSender<BusCommand>>,
    ) {
        *targets.write().unwrap_or_else(|e| e.into_inner()) = targets_of(config, buses);
    }

    /// Handles messages until the MQTT side closes the channel.
    pub async fn run(self, mut incoming: Receiver<Incoming>) {
        while let Some(msg) = incoming.recv().await {
            self.handle(msg);
        }
    }

    fn handle(&self, msg: Incoming) {
        if msg.topic == self.topics.config_set() {
            return self.config_push(msg);
        }
        if msg.retain {
            self.warn(&msg.topic, "ignoring a retained command message");
            return;
        }
        if let Some(bus) = self.topics.parse_scan(&msg.topic) {
            return self.scan(bus, &msg);
        }
        let Some((device, channel)) = self.topics.parse_command(&msg.topic) else {
            return;
        };
        let mut reply = Reply {
            topics: vec![crate::topics::Topics::result(&msg.topic)],
            correlation: None,
            via: msg.via.clone(),
        };
        if let Err(e) = reply_to(&self.responses, &msg, &mut reply) {
            return self.refuse(&msg.topic, &reply, None, None, e);
        }
        let parsed = match command::parse_payload(&msg.payload, channel.is_some()) {
            Ok(p) => p,
            Err((id, e)) => return self.refuse(&msg.topic, &reply, id.as_deref(), None, e),
        };
        let op = parsed.op.name();
        let id = parsed.id.as_deref();
        let refuse = |e: CommandError| self.refuse(&msg.topic, &reply, id, Some(op), e);
        // Refusals that need no module are not remembered: a retry is judged afresh.
        let targets = self.targets.read().unwrap_or_else(|e| e.into_inner());
        let Some(target) = targets.get(device) else {
            return refuse(CommandError::UnknownDevice(device.into()));
        };
        if !target.commands {
            return refuse(CommandError::Disabled(device.into()));
        }
        if let Some(ch) = channel
            && !target.channels_from_device
            && !target.channels.contains(ch)
        {
            return refuse(CommandError::UnknownChannel {
                device: device.into(),
                channel: ch.into(),
            });
        }
        if let Some(id) = id {
            let seen = lock(&self.dedupe).check(&msg.topic, id, Instant::now());
            match seen {
                Seen::New => {}
                Seen::InFlight => return,
                Seen::Answered(result) => return self.send(&reply, Outcome::Command(result)),
            }
        }
        if let Err(e) = lock(&self.admission).admit(device, Instant::now()) {
            if let Some(id) = id {
                lock(&self.dedupe).forget(&msg.topic, id);
            }
            return refuse(e);
        }
        self.forward(&msg.topic, &target.bus, device, channel, parsed, reply);
    }

    /// Hands an admitted command to its bus; its result is published when the bus answers.
    fn forward(
        &self,
        topic: &str,
        bus: &UnboundedSender<BusCommand>,
        device: &str,
        channel: Option<&str>,
        parsed: command::Parsed,
        reply: Reply,
    ) {
        let (op, id) = (parsed.op.name(), parsed.id.as_deref());
        let now = Instant::now();
        let (done, result) = oneshot::channel();
        let request = Request {
            device: device.into(),
            channel: channel.map(Into::into),
            op: parsed.op,
            id: parsed.id.clone(),
            reply: reply.clone(),
            received: now,
            expires: now + EXPIRY,
        };
        if bus.send(BusCommand { request, done }).is_err() {
            lock(&self.admission).done(device);
            return self.finish(
                topic,
                &reply,
                id,
                op,
                &Err(CommandError::Offline(device.into())),
            );
        }
        let out = self.out.clone();
        let dedupe = self.dedupe.clone();
        let admission = self.admission.clone();
        let topic = topic.to_string();
        let id = parsed.id.clone();
        let device = device.to_string();
        tokio::spawn(async move {
            let outcome = result
                .await
                .unwrap_or_else(|_| Err(CommandError::Offline("gateway stopping".into())));
            lock(&admission).done(&device);
            let outcome = CommandOutcome {
                op: Some(op.to_string()),
                id,
                result: outcome,
            };
            if let Some(id) = &outcome.id {
                lock(&dedupe).answered(&topic, id, outcome.clone());
            }
            let _ = out.send(Output::CommandResult {
                reply,
                outcome: Outcome::Command(outcome),
            });
        });
    }

    /// Answers a command refused before it reached a bus; logs within the budget.
    fn refuse(
        &self,
        topic: &str,
        reply: &Reply,
        id: Option<&str>,
        op: Option<&str>,
        e: CommandError,
    ) {
        self.warn(topic, &format!("command refused: {e}"));
        let outcome = CommandOutcome {
            id: id.map(str::to_string),
            op: op.map(str::to_string),
            result: Err(e),
        };
        self.send(reply, Outcome::Command(outcome));
    }

    /// A warning about a command message, at most 20 lines a minute (a flood is counted).
    fn warn(&self, topic: &str, text: &str) {
        let (allowed, suppressed) = lock(&self.log_budget).allow(Instant::now());
        if let Some(n) = suppressed {
            tracing::warn!(
                "{n} more command messages were refused in the last minute (not logged one by one)"
            );
        }
        if allowed {
            // The topic may come from anyone who can publish: cut it for the log.
            let shown: String = topic.chars().take(200).collect();
            tracing::warn!(topic = %shown, "{text}");
        }
    }

    fn finish(
        &self,
        topic: &str,
        reply: &Reply,
        id: Option<&str>,
        op: &str,
        outcome: &Result<Option<i64>, CommandError>,
    ) {
        if let Err(e) = outcome {
            self.warn(topic, &format!("command failed: {e}"));
        }
        let outcome = CommandOutcome {
            id: id.map(str::to_string),
            op: Some(op.to_string()),
            result: outcome.clone(),
        };
        if let Some(id) = id {
            lock(&self.dedupe).answered(topic, id, outcome.clone());
        }
        self.send(reply, Outcome::Command(outcome));
    }

    fn send(&self, reply: &Reply, outcome: Outcome) {
        let _ = self.out.send(Output::CommandResult {
            reply: reply.clone(),
            outcome,
        });
    }
}
/// Checks the MQTT v5 properties of a command before anything is published to them (a
/// response topic the gateway cannot publish to must not reach the spool) and adds the response
/// topic and correlation data to `reply`.
fn reply_to(rule: &ResponseRule, msg: &Incoming, reply: &mut Reply) -> Result<(), CommandError> {
    if let Some(c) = &msg.correlation
        && c.len() > command::MAX_CORRELATION
    {
        return Err(CommandError::TooLarge {
            what: "the correlation data",
            size: c.len(),
            limit: command::MAX_CORRELATION,
        });
    }
    if let Some(rt) = &msg.response_topic {
        check_response_topic(rule, rt)?;
        reply.topics.push(rt.clone());
        reply.correlation = msg.correlation.clone();
    }
    Ok(())
}

/// A response topic's shape (length, wildcards, `$`) and place (not into the gateway's own
/// topics or Home Assistant's): refused before anything is published there.
fn check_response_topic(rule: &ResponseRule, topic: &str) -> Result<(), CommandError> {
    command::check_response_topic(topic)?;
    rule.check(topic).map_err(CommandError::BadResponseTopic)
}

#[cfg(test)]
#[path = "dispatch_tests.rs"]
mod tests;
