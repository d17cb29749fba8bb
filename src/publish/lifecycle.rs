//! The MQTT parts of a format, apart from its encoder ([`super::format::Format`]): a format
//! owns its protocol's lifecycle on the wire, as Telegraf's outputs own
//! `Connect`/`Write`/`Close`: what it publishes at every connection (Sparkplug's births), the
//! will it leaves with the broker, what it publishes when the gateway stops, what its
//! subscriptions mean (Home Assistant's birth message; commands of its own protocol, handed to
//! the command router), timers of its own (`tick`), its hold (Sparkplug's primary host), and a
//! last look at each stored message as it leaves (a protocol that numbers its messages on the
//! wire). The MQTT task ([`super::mqtt`]) runs an output's formats as one [`Stage`] and only
//! calls these hooks; it knows no format. Pure.

use bytes::Bytes;
use tokio::time::Instant;

use super::delivery::classified;
use super::format::Format;
use crate::config::Config;
use crate::dispatch::Incoming;
use crate::outbox::{Message, Will};
use crate::reading::Output;

/// What a format makes of a message on one of its subscriptions.
#[derive(Debug, Default)]
pub struct Reaction {
    /// To publish.
    pub messages: Vec<Message>,
    /// For the command router, as if they had arrived on a command topic (with all its
    /// checks and admission).
    pub commands: Vec<Incoming>,
    /// Published at once, ahead of the outbox's backlog, and not stored, like what
    /// [`Lifecycle::connected`] returns (Sparkplug's births when its primary host comes online,
    /// before what was held for it).
    pub at_once: Vec<Message>,
    /// Answers the format gave itself (a command of its protocol it refused before the router
    /// saw it): `Output::CommandResult`s, counted and routed back like every answer.
    pub answers: Vec<Output>,
    /// What its protocol asked of the output or the gateway (Sparkplug's node controls).
    pub control: Vec<Control>,
}

/// A request of an output's protocol to the output or the gateway.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    /// Move this output to its next broker now.
    NextServer,
    /// Stop the gateway cleanly (state saved) with an exit status the service restarts on.
    Reboot,
}

impl From<Vec<Message>> for Reaction {
    fn from(messages: Vec<Message>) -> Reaction {
        Reaction {
            messages,
            ..Reaction::default()
        }
    }
}

/// What a format does on an MQTT connection besides encoding: every hook has a default that
/// does nothing, so a plain encoder needs none ([`plain`]).
pub trait Lifecycle {
    /// Topic filters this format reads, subscribed at every connection.
    fn subscriptions(&self) -> Vec<String> {
        Vec::new()
    }

    /// What it publishes at start, before any event.
    fn start(&mut self) -> Vec<Message> {
        Vec::new()
    }

    /// A message arrived on one of the formats' subscriptions (any format's: take only yours).
    fn received(&mut self, _topic: &str, _payload: &[u8]) -> Reaction {
        Reaction::default()
    }

    /// The same for a retained message: what the broker kept, not what was just sent. By
    /// default the same as [`Lifecycle::received`]; a format whose subscriptions carry commands
    /// ignores retained ones (a stale retained clear must not fire at every connection).
    fn received_retained(&mut self, topic: &str, payload: &[u8]) -> Reaction {
        self.received(topic, payload)
    }

    /// Published at every CONNACK, before the outbox's backlog, and not stored (a new
    /// connection makes them again).
    fn connected(&mut self) -> Vec<Message> {
        Vec::new()
    }

    /// The connection is gone: the next [`Lifecycle::connected`] starts a new session.
    fn disconnected(&mut self) {}

    /// The will to leave with the broker at the next connection (asked before each one).
    fn will(&mut self) -> Option<Will> {
        None
    }

    /// Published, not stored, as the gateway stops while connected (what the will would
    /// have said, said cleanly).
    fn stopping(&mut self) -> Vec<Message> {
        Vec::new()
    }

    /// About once a second, on tokio's clock: work the format put off (coalescing).
    fn tick(&mut self, _now: Instant) -> Vec<Message> {
        Vec::new()
    }

    /// While a format holds, the outbox hands nothing stored to the client: it is kept (and
    /// spooled) as during an outage. Sparkplug holds while its primary host is offline (the
    /// spec has the node go quiet then). `Some` says why (for health and the status line).
    fn held(&self) -> Option<String> {
        None
    }

    /// A stored message of this format leaves for the broker now, in wire order: `Some`
    /// bytes to send instead of the stored ones. `replay`: it was stored before this
    /// connection (an outage's backlog). Any format's messages pass: change only yours.
    fn outgoing(&mut self, _topic: &str, _payload: &Bytes, _replay: bool) -> Option<Bytes> {
        None
    }

    /// The client did not take the message [`Lifecycle::outgoing`] last looked at (its queue was
    /// full): it is offered again later.
    fn unsent(&mut self) {}

    /// Events of its protocol it counted since start, by name (Sparkplug: STATE messages
    /// ignored, rebirths asked for and done), for the metrics.
    fn tallies(&self) -> Vec<(&'static str, u64)> {
        Vec::new()
    }
}

/// A format on an MQTT connection: its encoder and its lifecycle.
pub trait MqttFormat: Format + Lifecycle {}

impl<T: Format + Lifecycle> MqttFormat for T {}

/// An encoder with no lifecycle of its own (the JSON topics), as a stage takes it.
pub struct Plain<F>(pub F);

impl<F: Format> Format for Plain<F> {
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        self.0.messages(event)
    }

    fn reload(&mut self, config: &Config) -> Vec<Message> {
        self.0.reload(config)
    }
}

impl<F> Lifecycle for Plain<F> {}

/// `format` as a stage takes it, with no lifecycle.
pub fn plain(format: impl Format + 'static) -> Box<dyn MqttFormat> {
    Box::new(Plain(format))
}

/// The formats in use, run one after the other on every event.
pub struct Stage {
    formats: Vec<Box<dyn MqttFormat>>,
}

impl Stage {
    pub fn new(formats: Vec<Box<dyn MqttFormat>>) -> Stage {
        Stage { formats }
    }

    /// Every format's messages for `event`, in the formats' order, classified for delivery.
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
    pub fn received(&mut self, topic: &str, payload: &[u8]) -> Reaction {
        self.react(|f| f.received(topic, payload))
    }

    /// A retained message on one of the subscriptions, offered to every format.
    pub fn received_retained(&mut self, topic: &str, payload: &[u8]) -> Reaction {
        self.react(|f| f.received_retained(topic, payload))
    }

    fn react(&mut self, mut f: impl FnMut(&mut dyn MqttFormat) -> Reaction) -> Reaction {
        let mut out = Reaction::default();
        for format in &mut self.formats {
            let r = f(&mut **format);
            out.messages.extend(classified(r.messages));
            out.commands.extend(r.commands);
            out.at_once.extend(r.at_once);
            out.answers.extend(r.answers);
            out.control.extend(r.control);
        }
        out
    }

    /// Some format holds the outbox ([`Lifecycle::held`]), and why.
    pub fn held(&self) -> Option<String> {
        self.formats.iter().find_map(|f| f.held())
    }

    pub fn reload(&mut self, config: &Config) -> Vec<Message> {
        self.each(|f| f.reload(config))
    }

    /// Every format's messages for a new connection.
    pub fn connected(&mut self) -> Vec<Message> {
        self.each(|f| f.connected())
    }

    pub fn disconnected(&mut self) {
        for format in &mut self.formats {
            format.disconnected();
        }
    }

    /// The first will a format sets (an output's kind has one format with a will, at most).
    pub fn will(&mut self) -> Option<Will> {
        self.formats.iter_mut().find_map(|f| f.will())
    }

    pub fn stopping(&mut self) -> Vec<Message> {
        self.each(|f| f.stopping())
    }

    pub fn tick(&mut self, now: Instant) -> Vec<Message> {
        self.each(|f| f.tick(now))
    }

    /// The bytes to send for a stored message, after every format has had its look.
    pub fn outgoing(&mut self, topic: &str, payload: &Bytes, replay: bool) -> Option<Bytes> {
        let mut changed: Option<Bytes> = None;
        for format in &mut self.formats {
            let current = changed.as_ref().unwrap_or(payload);
            if let Some(b) = format.outgoing(topic, current, replay) {
                changed = Some(b);
            }
        }
        changed
    }

    /// Every format's tallies.
    pub fn tallies(&self) -> Vec<(&'static str, u64)> {
        self.formats.iter().flat_map(|f| f.tallies()).collect()
    }

    /// The last message offered to [`Stage::outgoing`] was not taken.
    pub fn unsent(&mut self) {
        for format in &mut self.formats {
            format.unsent();
        }
    }

    /// Every format's messages from `f`, classified for delivery ([`super::delivery`]).
    fn each(&mut self, mut f: impl FnMut(&mut dyn MqttFormat) -> Vec<Message>) -> Vec<Message> {
        let mut out = Vec::new();
        for format in &mut self.formats {
            out.extend(classified(f(&mut **format)));
        }
        out
    }
}
