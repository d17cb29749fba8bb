//! The outbox's store for its tests.

use std::collections::VecDeque;

use super::{Entry, Message, Store};

/// A store in memory only, bounded in bytes: the outbox's tests run on it (the gateway's
/// store is the spool).
#[derive(Debug, Default)]
pub struct MemoryStore {
    entries: VecDeque<Entry>,
    bytes: u64,
    max_bytes: u64,
    next_seq: u64,
}

impl MemoryStore {
    pub fn new(max_bytes: u64) -> MemoryStore {
        MemoryStore {
            max_bytes,
            next_seq: 1,
            ..MemoryStore::default()
        }
    }

    /// Sequence numbers stored, oldest first.
    pub fn seqs(&self) -> Vec<u64> {
        self.entries.iter().map(|e| e.seq).collect()
    }
}

impl Store for MemoryStore {
    type Error = std::convert::Infallible;

    fn push(&mut self, m: Message) -> Result<u64, Self::Error> {
        let entry = Entry::of(self.next_seq, m);
        self.next_seq += 1;
        self.bytes += entry.size();
        self.entries.push_back(entry);
        Ok(self.next_seq - 1)
    }

    fn get(&mut self, i: usize) -> Option<&Entry> {
        self.entries.get(i)
    }

    fn ack_front(&mut self, n: usize) {
        for e in self.entries.drain(..n.min(self.entries.len())) {
            self.bytes -= e.size();
        }
    }

    fn evict(&mut self, keep: usize) -> u64 {
        let mut dropped = 0;
        while self.bytes > self.max_bytes && self.entries.len() > keep {
            let e = self.entries.remove(keep).expect("index checked");
            self.bytes -= e.size();
            dropped += 1;
        }
        dropped
    }

    fn len(&self) -> u64 {
        self.entries.len() as u64
    }

    fn next_seq(&self) -> u64 {
        self.next_seq
    }
}
