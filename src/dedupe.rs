//! A memory of recent command ids, so a repeated command is answered again without a second
//! write. Bounded in entries and bytes. Pure.

use std::collections::{HashMap, VecDeque};
use std::time::Duration;

use tokio::time::Instant;

use crate::outcome::CommandOutcome;

/// How long an answered id is remembered.
pub const DEDUPE_WINDOW: Duration = Duration::from_secs(600);

/// Most ids remembered at once, and most bytes their keys and results may take: a flood of
/// distinct ids evicts the oldest instead of growing the gateway.
pub const DEDUPE_ENTRIES: usize = 4096;
pub const DEDUPE_BYTES: usize = 2 << 20;

type Key = (String, String);

/// Recently seen command ids (per topic) and their results, bounded in entries and bytes.
#[derive(Debug, Default)]
pub struct Dedupe {
    seen: HashMap<Key, (Instant, Option<CommandOutcome>, usize)>,
    /// Keys in the order they were first seen (the oldest is evicted first).
    order: VecDeque<(Key, Instant)>,
    bytes: usize,
}

/// What to do with a command whose id may have been seen.
#[derive(Debug, Clone, PartialEq)]
pub enum Seen {
    /// New: go ahead.
    New,
    /// Answered before: send this result again, write nothing.
    Answered(CommandOutcome),
    /// Still being carried out: its result will come; write nothing.
    InFlight,
}

impl Dedupe {
    /// Records `id` on `topic` at `now` and says whether it is new.
    pub fn check(&mut self, topic: &str, id: &str, now: Instant) -> Seen {
        while let Some((_, t)) = self.order.front() {
            if now.duration_since(*t) < DEDUPE_WINDOW {
                break;
            }
            self.evict_oldest();
        }
        let key = (topic.to_string(), id.to_string());
        match self.seen.get(&key) {
            Some((_, Some(result), _)) => Seen::Answered(result.clone()),
            Some((_, None, _)) => Seen::InFlight,
            None => {
                let size = topic.len() + id.len() + 64;
                self.bytes += size;
                self.order.push_back((key.clone(), now));
                self.seen.insert(key, (now, None, size));
                // `order` may hold keys already forgotten: bound it too.
                while self.seen.len() > DEDUPE_ENTRIES
                    || self.bytes > DEDUPE_BYTES
                    || self.order.len() > 2 * DEDUPE_ENTRIES
                {
                    self.evict_oldest();
                }
                Seen::New
            }
        }
    }

    fn evict_oldest(&mut self) {
        if let Some((key, at)) = self.order.pop_front()
            && let Some((t, _, size)) = self.seen.get(&key)
            && *t == at
        {
            self.bytes -= size;
            self.seen.remove(&key);
        }
    }

    /// Stores the result of a command so a repeat is answered with it.
    pub fn answered(&mut self, topic: &str, id: &str, result: CommandOutcome) {
        if let Some(entry) = self.seen.get_mut(&(topic.to_string(), id.to_string())) {
            let extra = result.id.as_ref().map_or(0, String::len) + 128;
            self.bytes += extra;
            entry.2 += extra;
            entry.1 = Some(result);
        }
    }

    /// Forgets an id whose command was refused before it did anything, so a retry is judged
    /// afresh.
    pub fn forget(&mut self, topic: &str, id: &str) {
        if let Some((_, _, size)) = self.seen.remove(&(topic.to_string(), id.to_string())) {
            self.bytes -= size;
        }
    }

    /// Ids remembered, and the bytes they take.
    pub fn size(&self) -> (usize, usize) {
        (self.seen.len(), self.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::MAX_ID;

    fn ok() -> CommandOutcome {
        CommandOutcome {
            id: Some("1".into()),
            op: Some("clear".into()),
            result: Ok(None),
        }
    }

    #[test]
    fn the_same_id_within_ten_minutes_is_answered_again_without_a_write() {
        let mut d = Dedupe::default();
        let t0 = Instant::now();
        assert_eq!(d.check("t", "1", t0), Seen::New);
        assert_eq!(d.check("t", "1", t0), Seen::InFlight);
        d.answered("t", "1", ok());
        assert_eq!(
            d.check("t", "1", t0 + Duration::from_secs(599)),
            Seen::Answered(ok())
        );
        assert_eq!(d.check("t", "1", t0 + Duration::from_secs(601)), Seen::New);
        assert_eq!(d.check("other", "1", t0), Seen::New);
    }

    #[test]
    fn a_flood_of_distinct_ids_evicts_the_oldest_instead_of_growing() {
        let mut d = Dedupe::default();
        let t0 = Instant::now();
        let long = "x".repeat(MAX_ID);
        for i in 0..50_000 {
            d.check("pg/e1/ghost/cmd", &format!("{long}{i}"), t0);
        }
        let (entries, bytes) = d.size();
        assert!(entries <= DEDUPE_ENTRIES, "{entries} entries");
        assert!(bytes <= DEDUPE_BYTES, "{bytes} bytes");
        assert_eq!(
            d.check("pg/e1/ghost/cmd", &format!("{long}49999"), t0),
            Seen::InFlight,
            "the newest are remembered"
        );
        assert_eq!(
            d.check("pg/e1/ghost/cmd", &format!("{long}0"), t0),
            Seen::New
        );
    }
}
