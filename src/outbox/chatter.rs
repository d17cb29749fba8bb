//! Chatter: messages the gateway can make again (discovery configs, command and scan results,
//! bus stats), kept apart from the owed readings so that no flood of them can cost a reading.
//! A bounded queue in memory, never written to disk; when full, the oldest chatter goes first
//! and is counted. A retained message replaces the one queued for the same topic (only the
//! newest retained value matters), so announcing the same configs again costs no room. Pure.

use std::collections::VecDeque;

use super::message::Message;

/// Most chatter messages waiting at once: a burst of ten thousand refused commands is still
/// answered in full while the broker keeps up; a flood beyond it costs only its oldest answers.
pub const CHATTER_MESSAGES: usize = 16 * 1024;

/// Most bytes (topics and payloads) of chatter waiting at once.
pub const CHATTER_BYTES: usize = 4 << 20;

/// Chatter messages the client may hold at once, beside the owed messages' window.
pub const CHATTER_WINDOW: usize = 64;

/// The chatter queue.
#[derive(Debug, Default)]
pub struct Chatter {
    queue: VecDeque<Message>,
    bytes: usize,
    /// Chatter dropped to keep the bound, since start.
    pub dropped: u64,
}

fn size(m: &Message) -> usize {
    m.topic.len() + m.payload.len() + 64
}

impl Chatter {
    /// Queues `m` (replacing a queued retained message on its topic); returns how many older
    /// messages were dropped to keep the bound.
    pub fn push(&mut self, m: Message) -> u64 {
        if m.retain
            && let Some(i) = self
                .queue
                .iter()
                .position(|q| q.retain && q.topic == m.topic)
        {
            let old = self.queue.remove(i).expect("index found");
            self.bytes -= size(&old);
        }
        self.bytes += size(&m);
        self.queue.push_back(m);
        let mut dropped = 0;
        while self.queue.len() > CHATTER_MESSAGES || self.bytes > CHATTER_BYTES {
            let Some(old) = self.queue.pop_front() else {
                break;
            };
            self.bytes -= size(&old);
            dropped += 1;
        }
        self.dropped += dropped;
        dropped
    }

    /// The oldest message waiting.
    pub fn pop(&mut self) -> Option<Message> {
        let m = self.queue.pop_front()?;
        self.bytes -= size(&m);
        Some(m)
    }

    /// Messages the client held when its connection went (or could not take): first again,
    /// in their order, unless newer ones replaced them or the bound is full.
    pub fn requeue(&mut self, held: Vec<Message>) {
        for m in held.into_iter().rev() {
            let replaced = m.retain && self.queue.iter().any(|q| q.retain && q.topic == m.topic);
            if replaced || self.queue.len() >= CHATTER_MESSAGES {
                continue;
            }
            self.bytes += size(&m);
            self.queue.push_front(m);
        }
    }

    /// Messages waiting.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(n: usize, payload: &str) -> Message {
        Message::chatter(
            format!("homeassistant/sensor/x/{n}/config"),
            payload.to_string(),
            1,
            true,
        )
    }

    #[test]
    fn announcing_the_same_configs_again_takes_no_more_room() {
        let mut c = Chatter::default();
        for round in 0..100 {
            for n in 0..250 {
                c.push(config(n, &format!("{{\"round\":{round}}}")));
            }
        }
        assert_eq!(c.len(), 250);
        assert_eq!(c.dropped, 0);
        assert_eq!(
            c.pop().unwrap().payload,
            "{\"round\":99}",
            "the newest value of the oldest topic"
        );
    }

    #[test]
    fn a_flood_of_results_keeps_the_bound_and_drops_the_oldest() {
        let mut c = Chatter::default();
        for n in 0..30_000 {
            c.push(Message::chatter(
                "pg/nosuch/cmd/result".into(),
                format!("{n}"),
                1,
                false,
            ));
        }
        assert_eq!(c.len(), CHATTER_MESSAGES);
        assert_eq!(c.dropped, (30_000 - CHATTER_MESSAGES) as u64);
        assert_eq!(
            c.pop().unwrap().payload,
            format!("{}", 30_000 - CHATTER_MESSAGES)
        );
    }

    #[test]
    fn chatter_held_by_a_lost_connection_goes_first_again() {
        let mut c = Chatter::default();
        c.push(Message::chatter("r/3".into(), "3", 1, false));
        c.requeue(vec![
            Message::chatter("r/1".into(), "1", 1, false),
            Message::chatter("r/2".into(), "2", 1, false),
        ]);
        let order: Vec<String> = std::iter::from_fn(|| c.pop()).map(|m| m.topic).collect();
        assert_eq!(order, ["r/1", "r/2", "r/3"]);
    }
}
