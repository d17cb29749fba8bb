//! The command router as a plain value: [`Router::handle`] takes an [`Event`] and the time and
//! returns [`Action`]s. No channel, no lock, no clock.

use std::collections::{BTreeSet, HashMap};
use std::time::Duration;

use bytes::Bytes;
use tokio::time::Instant;

use crate::admission::Admission;
use crate::command::{self, CommandError, Reply, Request};
use crate::config::Config;
use crate::dedupe::{Dedupe, Seen};
use crate::log_budget::LogBudget;
use crate::outcome::{CommandOutcome, ConfigOutcome, Outcome, ScanOutcome};
use crate::reading::Output;
use crate::scan::{self, ScanRequest};
use crate::topics::ResponseRule;

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
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    bus: String,
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

/// The devices of `config` on the buses that run, by name.
pub fn targets_of(config: &Config, running: &BTreeSet<String>) -> HashMap<String, Target> {
    config
        .devices()
        .filter(|(bus, _)| running.contains(&bus.name))
        .map(|(bus, d)| {
            let target = Target {
                bus: bus.name.clone(),
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
            (d.name.clone(), target)
        })
        .collect()
}

/// Command messages between the MQTT connection and the router: when full, the connection
/// waits (TCP pushes back on the sender) instead of the gateway buffering without bound.
pub const INCOMING_QUEUE: usize = 256;

/// How long a command waits for an offline device.
pub const EXPIRY: Duration = Duration::from_secs(10);

/// A command handed to a bus, as the router will answer it.
#[derive(Debug, Clone)]
pub struct Pending {
    pub device: String,
    pub topic: String,
    pub reply: Reply,
    /// `None` when the payload did not say (a refusal of a payload that is not a command).
    pub op: Option<&'static str>,
    pub id: Option<String>,
}

/// What the router hears.
#[derive(Debug)]
pub enum Event {
    /// A message on a command, scan or config topic.
    Message(Incoming),
    /// A bus answered a command (or could not take it: `offline`).
    Answered(Pending, Result<Option<i64>, CommandError>),
    /// The bus's scan queue did not take a survey.
    ScanNotTaken {
        bus: String,
        reply: Reply,
        refusal: ScanRefusal,
    },
    /// The remote config task did not take a push: it works on one (`closed` false), or the
    /// gateway is starting again for an earlier one (`closed` true).
    PushNotTaken { msg: Incoming, closed: bool },
    /// A reloaded config: its devices on the buses that run.
    Reconfigured(HashMap<String, Target>),
}

/// Why a survey is refused.
#[derive(Debug, Clone, PartialEq)]
pub enum ScanRefusal {
    /// A survey of this bus already waits.
    Busy,
    /// The bus does not run.
    UnknownBus,
    /// The payload is over [`command::MAX_PAYLOAD`] bytes.
    TooLarge(usize),
    /// The payload is not a survey's.
    BadPayload(String),
    /// The response topic or correlation data cannot be answered on.
    BadReply(CommandError),
}

impl ScanRefusal {
    /// The answer's `error` code.
    pub fn code(&self) -> &'static str {
        match self {
            ScanRefusal::Busy => "busy",
            ScanRefusal::UnknownBus => "unknown_bus",
            ScanRefusal::TooLarge(_) => "too_large",
            ScanRefusal::BadPayload(_) => "bad_payload",
            ScanRefusal::BadReply(e) => e.code(),
        }
    }

    /// What the answer and the log say, for bus `bus`.
    fn message(&self, bus: &str) -> String {
        match self {
            ScanRefusal::Busy => "a scan of this bus is already waiting".into(),
            ScanRefusal::UnknownBus => format!("no bus {bus:?}"),
            ScanRefusal::TooLarge(size) => format!("the payload is {size} bytes"),
            ScanRefusal::BadPayload(why) => why.clone(),
            ScanRefusal::BadReply(e) => e.to_string(),
        }
    }
}

/// What the router wants done.
#[derive(Debug)]
pub enum Action {
    /// Publish a result.
    Publish(Output),
    /// Hand an admitted command to its bus (named first); its answer comes back as
    /// [`Event::Answered`].
    Forward(String, Box<Request>, Pending),
    /// A survey to its bus's scan queue.
    Scan(String, ScanRequest),
    /// A pushed config to the remote config task.
    Push(Incoming),
}

/// The command router of a gateway.
pub struct Router {
    topics: crate::topics::Topics,
    /// Where a response topic may point (see [`ResponseRule`]).
    responses: ResponseRule,
    targets: HashMap<String, Target>,
    dedupe: Dedupe,
    admission: Admission,
    log_budget: LogBudget,
    /// Pushed configs (`[remote] config = true`) are taken.
    remote: bool,
}

impl Router {
    /// A router for `config`, its devices on the buses in `running`.
    pub fn new(config: &Config, running: &BTreeSet<String>) -> Router {
        Router {
            topics: crate::topics::Topics::new(&config.mqtt.topic_root),
            responses: ResponseRule::new(
                &config.mqtt.topic_root,
                config.outputs.reserved_prefixes(),
            ),
            targets: targets_of(config, running),
            dedupe: Dedupe::default(),
            admission: Admission::default(),
            log_budget: LogBudget::new(20),
            remote: false,
        }
    }

    /// Pushed configs (`<root>/config/set`) are taken (to the remote config task).
    pub fn with_remote(mut self) -> Router {
        self.remote = true;
        self
    }

    /// Takes what happened at `now`; returns what to do.
    pub fn handle(&mut self, event: Event, now: Instant) -> Vec<Action> {
        match event {
            Event::Message(msg) => self.message(msg, now),
            Event::Answered(pending, result) => vec![self.answered(pending, result, now)],
            Event::ScanNotTaken {
                bus,
                reply,
                refusal,
            } => {
                let topic = reply.topics.first().cloned().unwrap_or_default();
                vec![self.refuse_scan(&topic, &bus, reply, &refusal, now)]
            }
            Event::PushNotTaken { msg, closed } => vec![self.push_busy(&msg, closed, now)],
            Event::Reconfigured(targets) => {
                self.targets = targets;
                Vec::new()
            }
        }
    }

    fn message(&mut self, msg: Incoming, now: Instant) -> Vec<Action> {
        if msg.topic == self.topics.config_set() {
            if !self.remote {
                self.warn(
                    &msg.topic,
                    "a pushed config, but [remote] config is off",
                    now,
                );
                return Vec::new();
            }
            // An empty message is a retained push being cleared, never a push: it must not
            // take the remote task's one place from the push that follows it.
            if msg.payload.is_empty() {
                tracing::info!("the retained message on the config topic was cleared");
                return Vec::new();
            }
            return vec![Action::Push(msg)];
        }
        if msg.retain {
            self.warn(&msg.topic, "ignoring a retained command message", now);
            return Vec::new();
        }
        if let Some(bus) = self.topics.parse_scan(&msg.topic) {
            let bus = bus.to_string();
            return vec![self.scan(&bus, &msg, now)];
        }
        self.command(msg, now)
    }

    /// `<root>/config/set` not taken: answered `busy` on the config result topic, with its id.
    fn push_busy(&mut self, msg: &Incoming, closed: bool, now: Instant) -> Action {
        let message = if closed {
            "the gateway is starting again for an earlier push: push again after its result"
        } else {
            "a pushed config is being applied or watched: push again after its result"
        };
        // Its id, even from a push that would be refused for other reasons (too large).
        let id = match crate::remote::parse(&msg.payload) {
            Ok(push) => push.id,
            Err((id, _)) => id,
        };
        self.warn(&msg.topic, "a pushed config refused: busy", now);
        let outcome = ConfigOutcome {
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
        publish(reply, Outcome::Config(outcome))
    }

    /// `<root>/bus/<bus>/scan`: a survey of the bus in its idle line time.
    fn scan(&mut self, bus: &str, msg: &Incoming, now: Instant) -> Action {
        let mut reply = Reply {
            topics: vec![crate::topics::Topics::result(&msg.topic)],
            correlation: None,
            via: msg.via.clone(),
        };
        // The same checks as for commands: nothing unsendable reaches the spool.
        if let Err(e) = reply_to(&self.responses, msg, &mut reply) {
            return self.refuse_scan(&msg.topic, bus, reply, &ScanRefusal::BadReply(e), now);
        }
        if msg.payload.len() > command::MAX_PAYLOAD {
            let refusal = ScanRefusal::TooLarge(msg.payload.len());
            return self.refuse_scan(&msg.topic, bus, reply, &refusal, now);
        }
        let (mut units, id) = match scan::parse_scan_payload(&msg.payload) {
            Ok(p) => p,
            Err(e) => {
                let refusal = ScanRefusal::BadPayload(e);
                return self.refuse_scan(&msg.topic, bus, reply, &refusal, now);
            }
        };
        let unscanned = |u: &u8| {
            let mut targets = self.targets.values();
            targets.any(|t| !t.scanned && t.bus == bus && t.unit == *u)
        };
        units.retain(|u| !unscanned(u));
        let request = ScanRequest {
            units,
            id,
            reply,
            progress: crate::topics::Topics::scan_progress(&msg.topic),
        };
        Action::Scan(bus.to_string(), request)
    }

    fn refuse_scan(
        &mut self,
        topic: &str,
        bus: &str,
        reply: Reply,
        refusal: &ScanRefusal,
        now: Instant,
    ) -> Action {
        let message = refusal.message(bus);
        self.warn(topic, &format!("scan refused: {message}"), now);
        let refused = ScanOutcome::Refused {
            bus: bus.to_string(),
            id: None,
            code: refusal.code(),
            message,
        };
        publish(reply, Outcome::Scan(refused))
    }

    /// A command: refused here when that needs no module, else admitted and forwarded; a
    /// repeat of one in flight is answered when that one is, a repeat of one answered gets
    /// the same answer.
    fn command(&mut self, msg: Incoming, now: Instant) -> Vec<Action> {
        let Some((device, channel)) = self.topics.parse_command(&msg.topic) else {
            return Vec::new();
        };
        let (device, channel) = (device.to_string(), channel.map(str::to_string));
        let mut pending = Pending {
            device: device.clone(),
            topic: msg.topic.clone(),
            reply: Reply {
                topics: vec![crate::topics::Topics::result(&msg.topic)],
                correlation: None,
                via: msg.via.clone(),
            },
            op: None,
            id: None,
        };
        if let Err(e) = reply_to(&self.responses, &msg, &mut pending.reply) {
            return vec![self.refuse(pending, e, now)];
        }
        let parsed = match command::parse_payload(&msg.payload, channel.is_some()) {
            Ok(p) => p,
            Err((id, e)) => {
                pending.id = id;
                return vec![self.refuse(pending, e, now)];
            }
        };
        (pending.op, pending.id) = (Some(parsed.op.name()), parsed.id.clone());
        let bus = match self.admit(&pending, channel.as_deref(), now) {
            Admitted::Yes(bus) => bus,
            Admitted::Refused(e) => return vec![self.refuse(pending, e, now)],
            Admitted::InFlight => return Vec::new(),
            Admitted::Answered(answer) => return vec![publish(pending.reply, answer)],
        };
        let request = Request {
            device,
            channel,
            op: parsed.op,
            id: parsed.id,
            reply: pending.reply.clone(),
            received: now,
            expires: now + EXPIRY,
        };
        vec![Action::Forward(bus, Box::new(request), pending)]
    }

    /// The checks a command passes before a bus sees it. Refusals that need no module are not
    /// remembered: a retry is judged afresh.
    fn admit(&mut self, p: &Pending, channel: Option<&str>, now: Instant) -> Admitted {
        let Some(target) = self.targets.get(&p.device) else {
            return Admitted::Refused(CommandError::UnknownDevice(p.device.clone()));
        };
        if !target.commands {
            return Admitted::Refused(CommandError::Disabled(p.device.clone()));
        }
        if let Some(ch) = channel
            && !target.channels_from_device
            && !target.channels.contains(ch)
        {
            return Admitted::Refused(CommandError::UnknownChannel {
                device: p.device.clone(),
                channel: ch.into(),
            });
        }
        let bus = target.bus.clone();
        if let Some(id) = &p.id {
            match self.dedupe.check(&p.topic, id, now) {
                Seen::New => {}
                Seen::InFlight => return Admitted::InFlight,
                Seen::Answered(result) => return Admitted::Answered(Outcome::Command(result)),
            }
        }
        if let Err(e) = self.admission.admit(&p.device, now) {
            if let Some(id) = &p.id {
                self.dedupe.forget(&p.topic, id);
            }
            return Admitted::Refused(e);
        }
        Admitted::Yes(bus)
    }

    /// A bus's answer (or a bus that could not take the command): the device's admission
    /// slot is free again, the answer remembered for a repeat and published.
    fn answered(
        &mut self,
        p: Pending,
        result: Result<Option<i64>, CommandError>,
        now: Instant,
    ) -> Action {
        self.admission.done(&p.device);
        if let Err(e) = &result {
            self.warn(&p.topic, &format!("command failed: {e}"), now);
        }
        let outcome = CommandOutcome {
            id: p.id.clone(),
            op: p.op.map(str::to_string),
            result,
        };
        if let Some(id) = &p.id {
            self.dedupe.answered(&p.topic, id, outcome.clone());
        }
        publish(p.reply, Outcome::Command(outcome))
    }

    /// Answers a command refused before it reached a bus; logs within the budget.
    fn refuse(&mut self, p: Pending, e: CommandError, now: Instant) -> Action {
        self.warn(&p.topic, &format!("command refused: {e}"), now);
        let outcome = CommandOutcome {
            id: p.id,
            op: p.op.map(str::to_string),
            result: Err(e),
        };
        publish(p.reply, Outcome::Command(outcome))
    }

    /// A warning about a command message, at most 20 lines a minute (a flood is counted).
    fn warn(&mut self, topic: &str, text: &str, now: Instant) {
        let (allowed, suppressed) = self.log_budget.allow(now);
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
}

/// What the checks before a bus say of a command.
enum Admitted {
    /// Admitted, to the bus named.
    Yes(String),
    Refused(CommandError),
    /// A repeat of a command in flight: answered when that one is.
    InFlight,
    /// A repeat of a command answered: the same answer.
    Answered(Outcome),
}

fn publish(reply: Reply, outcome: Outcome) -> Action {
    Action::Publish(Output::CommandResult { reply, outcome })
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
#[path = "router_tests.rs"]
mod tests;
