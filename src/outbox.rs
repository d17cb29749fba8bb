//! The outbox: store-and-forward plus the MQTT send window, as one state machine without I/O.
//!
//! Every message is stored first and leaves the store only when the broker acknowledges it.
//! The MQTT client is never trusted with more than a small window of them: rumqttc forgets what
//! it holds when it reconnects with a clean session, so after a connection loss the outbox hands
//! the same messages out again, in order. The MQTT task ([`crate::publish::mqtt`]) is a shell that
//! feeds events in (`enqueue`, `connected`, `sent`, `acked`, `lost`) and hands the client what
//! [`Outbox::next`] returns; the store ([`crate::publish::spool::Spool`] on disk, a memory store
//! in tests) only keeps messages in order within a byte bound.
//!
//! The window is a list of the store's oldest sequence numbers, so the bound can be enforced
//! without touching them: a full store drops the oldest messages *after* the window, never one
//! the client still holds, and the acknowledgements that follow release exactly the messages
//! they were for.
//!
//! Messages come in two classes ([`Class`]). Readings and statuses are *owed*: stored, spooled,
//! in order, evicted only by the store's own byte bound. What the gateway can make again
//! (discovery configs, command and scan results, bus stats) is *chatter*: a small queue of its
//! own in memory ([`chatter::Chatter`]) with its own small window, dropped first and counted, so
//! no flood of chatter can push a reading out or write a byte to disk.
//!
//! Time is tokio's, so outages and stalls are tested on paused time.

mod chatter;
#[cfg(test)]
mod memory;
mod message;
pub mod stored;
mod window;

use std::time::Duration;

use tokio::time::Instant;

pub use chatter::{CHATTER_BYTES, CHATTER_MESSAGES, CHATTER_WINDOW, Chatter};
#[cfg(test)]
pub use memory::MemoryStore;
pub use message::{Class, Content, Message, Properties, Will};
use window::{Held, Window};

use bytes::Bytes;

/// A stored message waiting for the broker. Its form in a spool file is [`stored`]'s.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// Store sequence number: strictly increasing, across restarts.
    pub seq: u64,
    pub topic: String,
    /// Shared, so handing it to the MQTT client (and again after a reconnect) copies nothing.
    pub payload: Bytes,
    pub qos: u8,
    pub retain: bool,
    pub correlation: Option<Vec<u8>>,
}

impl Entry {
    /// What the store accounts for it (bytes plus a fixed overhead).
    pub fn size(&self) -> u64 {
        (self.topic.len() + self.payload.len() + 64) as u64
    }
}

/// Where the outbox keeps its messages, oldest first.
pub trait Store {
    type Error: std::fmt::Display;
    /// Appends a message; returns its sequence number.
    fn push(&mut self, message: Message) -> Result<u64, Self::Error>;
    /// The `i`-th oldest message.
    fn get(&mut self, i: usize) -> Option<&Entry>;
    /// Forgets the oldest `n` messages (acknowledged).
    fn ack_front(&mut self, n: usize);
    /// While over the byte bound, drops the oldest messages after the first `keep` (those the
    /// client holds); returns how many were dropped.
    fn evict(&mut self, keep: usize) -> u64;
    /// Messages stored.
    fn len(&self) -> u64;
    /// The sequence number the next message will get (everything below it was stored before).
    fn next_seq(&self) -> u64;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The broker went away (`true`) or came back: a store on disk writes new messages out.
    fn broker_away(&mut self, _away: bool) {}
}

/// What to do next, from [`Outbox::next`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Step {
    /// Hand this message to the client (then [`Outbox::refused`] if it could not take it).
    /// `replay`: an owed message stored before this connection was made (sent late).
    Send { entry: Entry, replay: bool },
    /// This message can never be sent (it would block everything behind it): it was dropped.
    Dropped { topic: String, why: String },
}

/// What [`Outbox::enqueue`] did with a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Enqueued {
    /// Stored with this sequence number; `evicted` older ones were dropped to make room.
    Stored { seq: u64, evicted: u64 },
    /// A transient message while the broker is away: not stored.
    Skipped,
    /// A chatter message, queued; `dropped` older chatter made room for it.
    Chatter { dropped: u64 },
}

/// The spool and the send window of one gateway.
#[derive(Debug)]
pub struct Outbox<S> {
    store: S,
    /// What the client has, in the order it was handed over: the store's oldest messages (in
    /// order) and chatter between them.
    window: Window,
    capacity: usize,
    /// What the gateway can make again, waiting.
    chatter: Chatter,
    /// Owed messages with a sequence number below this were stored before this connection.
    replay_below: u64,
    connected: bool,
    /// The broker's maximum packet size (CONNACK), if it announced one.
    broker_max: Option<u32>,
    /// The last time the broker acknowledged something, or the window was empty.
    progress: Instant,
    /// Publishes outside the store (gateway status) whose send event is still to come.
    direct: usize,
    /// Messages dropped because the store was full, since start.
    pub evicted: u64,
}

impl<S: Store> Outbox<S> {
    /// An outbox over `store` that lets the client hold at most `window` messages.
    pub fn new(store: S, window: usize, now: Instant) -> Outbox<S> {
        Outbox {
            store,
            window: Window::default(),
            capacity: window.max(1),
            chatter: Chatter::default(),
            replay_below: 0,
            connected: false,
            broker_max: None,
            progress: now,
            direct: 0,
            evicted: 0,
        }
    }

    pub fn store(&self) -> &S {
        &self.store
    }

    pub fn store_mut(&mut self) -> &mut S {
        &mut self.store
    }

    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// Messages the client holds.
    pub fn in_flight(&self) -> usize {
        self.window.len()
    }

    /// Owed messages the client holds.
    fn owed_in_flight(&self) -> usize {
        self.window.owed()
    }

    /// A window kept something back: the owed window is full, or chatter waits (its window
    /// full, or the client's queue). The next acknowledgement should let more out.
    pub fn backlogged(&self) -> bool {
        self.owed_in_flight() >= self.capacity || !self.chatter.is_empty()
    }

    /// The chatter waiting (and what it dropped).
    pub fn chatter(&self) -> &Chatter {
        &self.chatter
    }

    /// Stores an owed message (the bound is kept without dropping what the client holds) or
    /// queues a chatter message.
    pub fn enqueue(&mut self, message: Message) -> Result<Enqueued, S::Error> {
        if message.transient && !self.connected {
            return Ok(Enqueued::Skipped);
        }
        if message.class == Class::Chatter {
            let dropped = self.chatter.push(message);
            return Ok(Enqueued::Chatter { dropped });
        }
        let seq = self.store.push(message)?;
        let evicted = self.store.evict(self.owed_in_flight());
        self.evicted += evicted;
        Ok(Enqueued::Stored { seq, evicted })
    }

    /// The broker accepted the connection (`max_packet` from its CONNACK).
    pub fn connected(&mut self, max_packet: Option<u32>, now: Instant) {
        self.connected = true;
        self.broker_max = max_packet;
        self.progress = now;
        self.replay_below = self.store.next_seq();
        self.store.broker_away(false);
    }

    /// The connection failed: everything the client held is gone with it and will be handed
    /// out again, in order, after the next [`Outbox::connected`] (chatter too, ahead of the
    /// chatter that came since).
    pub fn lost(&mut self) {
        self.connected = false;
        self.chatter.requeue(self.window.lost());
        self.direct = 0;
        self.store.broker_away(true);
    }

    /// The sequence number the next owed message will get.
    pub fn next_seq(&self) -> u64 {
        self.store.next_seq()
    }

    /// The oldest owed message not yet acknowledged, if any.
    pub fn oldest_unacked(&mut self) -> Option<u64> {
        self.store.get(0).map(|e| e.seq)
    }

    /// A publish outside the store (the gateway's status) was handed to the client: its send
    /// event is not one of ours.
    pub fn direct(&mut self) {
        self.direct += 1;
    }

    /// The client sent a publish with `pkid` (0 for QoS 0, which needs no acknowledgement).
    pub fn sent(&mut self, pkid: u16) {
        if self.direct > 0 {
            self.direct -= 1;
            return;
        }
        self.window.sent(pkid);
    }

    /// The broker acknowledged `pkid`.
    pub fn acked(&mut self, pkid: u16, now: Instant) {
        self.progress = now;
        self.window.acked(pkid);
    }

    /// The next thing to do, or `None` when both windows are full, nothing waits or the broker
    /// is away. Releases acknowledged messages first (owed ones in order: an acknowledgement
    /// that overtakes an older one waits for it). Chatter goes first within its own small
    /// window, so a discovery config leaves before the reading it describes, and never takes a
    /// place of the owed messages' window.
    pub fn next(&mut self, now: Instant) -> Option<Step> {
        self.release(now);
        if !self.connected {
            return None;
        }
        if self.window.chatter() < CHATTER_WINDOW
            && let Some(m) = self.chatter.pop()
        {
            return Some(self.hand_chatter(m));
        }
        self.next_owed()
    }

    fn hand_chatter(&mut self, m: Message) -> Step {
        let corr = m.properties.correlation.as_ref().map_or(0, Bytes::len);
        if let Some(why) = unsendable(&m.topic, m.payload.len(), corr, self.broker_max) {
            return Step::Dropped {
                topic: m.topic.chars().take(200).collect(),
                why,
            };
        }
        let entry = Entry::of(0, m.clone());
        self.window.push(Held::Chatter(Box::new(m)), false);
        Step::Send {
            entry,
            replay: false,
        }
    }

    fn next_owed(&mut self) -> Option<Step> {
        let i = self.owed_in_flight();
        if i >= self.capacity {
            return None;
        }
        let broker_max = self.broker_max;
        let e = self.store.get(i)?;
        let corr = e.correlation.as_ref().map_or(0, Vec::len);
        let unsendable = unsendable(&e.topic, e.payload.len(), corr, broker_max);
        let seq = e.seq;
        let step = match unsendable {
            Some(why) => Step::Dropped {
                topic: e.topic.chars().take(200).collect(),
                why,
            },
            None => Step::Send {
                replay: seq < self.replay_below,
                entry: e.clone(),
            },
        };
        // An unsendable message counts as acknowledged, so order and the window hold.
        let acked = matches!(step, Step::Dropped { .. });
        self.window.push(Held::Owed(seq), acked);
        Some(step)
    }

    /// The client could not take the message [`Outbox::next`] just returned (its queue is
    /// full): it is handed out again later.
    pub fn refused(&mut self) {
        if let Some(Held::Chatter(m)) = self.window.take_back_unsent() {
            self.chatter.requeue(vec![*m]);
        }
    }

    /// Forgets acknowledged chatter, and releases the acknowledged owed messages at the front
    /// of the store.
    fn release(&mut self, now: Instant) {
        let released = self.window.release();
        if released > 0 {
            self.store.ack_front(released);
        }
        if self.window.is_empty() {
            self.progress = now;
        }
    }

    /// Messages are in flight and the broker has acknowledged nothing for `limit`: the
    /// connection is not publishing, whatever the socket says.
    pub fn stalled(&self, now: Instant, limit: Duration) -> bool {
        self.connected
            && self.window.waiting()
            && now.saturating_duration_since(self.progress) > limit
    }
}

/// Why a stored message can never be sent, if it can't: it would block the outbox forever.
pub fn unsendable(
    topic: &str,
    payload: usize,
    correlation: usize,
    broker_max: Option<u32>,
) -> Option<String> {
    if crate::topics::publishable(topic).is_err() {
        return Some("not a topic one can publish to (empty, too long or a wildcard)".into());
    }
    // Fixed header (≤ 5), topic, packet id, properties (correlation data), payload.
    let size =
        5 + 2 + topic.len() + 2 + 5 + if correlation > 0 { 3 + correlation } else { 0 } + payload;
    match broker_max {
        Some(max) if size > max as usize => Some(format!(
            "{size} bytes, more than the broker's maximum packet size of {max}"
        )),
        _ => None,
    }
}

impl Entry {
    /// The stored form of `m` under sequence number `seq`.
    pub fn of(seq: u64, m: Message) -> Entry {
        Entry {
            seq,
            topic: m.topic,
            payload: m.payload,
            qos: m.qos,
            retain: m.retain,
            correlation: m.properties.correlation.map(|c| c.to_vec()),
        }
    }
}

#[cfg(test)]
#[path = "outbox_tests.rs"]
mod tests;
