//! The way back: the oldest messages handed out (segment files loaded in order, then the tail),
//! released when acknowledged (a file goes once everything in it is), and the byte bound kept.

use std::convert::Infallible;

use super::sync::Job;
use super::{Entry, MemEntry, Segment, Spool, segment};

impl Spool {
    /// The `i`-th oldest waiting message, loading segment files into memory as needed.
    pub fn get(&mut self, i: usize) -> Option<&Entry> {
        while i >= self.mem.len() {
            if !self.load_next() && !self.tail_to_mem() {
                return None;
            }
        }
        self.mem.get(i).map(|m| &m.entry)
    }

    /// Loads the oldest segment not in memory; `false` when every one is. A line it cannot
    /// read is skipped (said once: when the spool was opened, or now for a new one).
    fn load_next(&mut self) -> bool {
        let Some(idx) = self.segments.iter().position(|s| !s.loaded) else {
            return false;
        };
        if idx == self.segments.len() - 1 {
            self.close_appender(); // the segment being written: finished first
        }
        let path = self.segments[idx].path.clone();
        let mut entries = Vec::new();
        match segment::scan(&path, |e| entries.push(e)) {
            Ok(scan) => {
                let seg = &mut self.segments[idx];
                let known = seg.unreadable as usize;
                for u in scan.unreadable.iter().skip(known) {
                    self.faults.unreadable(&path, u.offset, &u.why);
                }
                let seg = &mut self.segments[idx];
                seg.loaded = true;
                seg.count = scan.count;
                seg.bytes = scan.bytes;
                seg.unreadable = seg.unreadable.max(scan.unreadable.len() as u64);
                let on_disk = |entry| MemEntry {
                    entry,
                    on_disk: true,
                };
                self.mem.extend(entries.into_iter().map(on_disk));
            }
            Err(e) => {
                let s = self.segments.remove(idx).expect("index checked");
                self.dropped += s.count;
                self.faults.read_failed(&path, &e, s.count);
            }
        }
        true
    }

    /// Every segment is in memory: the tail joins it (in memory only, until spilled).
    fn tail_to_mem(&mut self) -> bool {
        if self.tail.is_empty() {
            return false;
        }
        for entry in self.tail.drain(..) {
            self.mem_bytes += entry.size();
            self.mem.push_back(MemEntry {
                entry,
                on_disk: false,
            });
        }
        self.tail_bytes = 0;
        true
    }

    /// The broker acknowledged the oldest `n` messages: forget them, and retire segment files
    /// whose every message is acknowledged.
    pub fn ack_front(&mut self, n: usize) {
        let mut last = None;
        for _ in 0..n {
            let Some(m) = self.mem.pop_front() else { break };
            if !m.on_disk {
                self.mem_bytes -= m.entry.size();
            }
            last = Some(m.entry.seq);
        }
        if let Some(last) = last {
            self.forget_segments_upto(last);
        }
    }

    fn forget_segments_upto(&mut self, seq: u64) {
        while let Some(s) = self.segments.front() {
            if s.last > seq || !s.loaded {
                break;
            }
            let s = self.segments.pop_front().expect("front exists");
            self.retire(s);
        }
    }

    /// A segment the spool is done with is removed; one with unreadable lines is kept under a
    /// name that is not a segment's.
    fn retire(&mut self, s: Segment) {
        let job = if s.unreadable > 0 {
            Job::Quarantine {
                to: segment::quarantine_path(&s.path),
                path: s.path,
            }
        } else {
            Job::Remove(s.path)
        };
        self.syncer.send(job);
    }

    /// Drops the oldest messages beyond the first `keep` (those in flight) while over the bound;
    /// returns how many.
    pub(super) fn enforce_bound(&mut self, keep: usize) -> u64 {
        let before = self.dropped;
        while self.total_bytes() > self.max_bytes {
            if let Some(i) = (keep..self.mem.len()).find(|&i| !self.mem[i].on_disk) {
                let m = self.mem.remove(i).expect("index checked");
                self.mem_bytes -= m.entry.size();
                self.dropped += 1;
                continue;
            }
            if self.drop_segment(keep) {
                continue;
            }
            let Some(e) = self.tail.pop_front() else {
                break;
            };
            self.tail_bytes -= e.size();
            self.dropped += 1;
        }
        self.dropped - before
    }

    /// Drops the oldest segment none of whose messages is in flight (the first `keep`), whole.
    fn drop_segment(&mut self, keep: usize) -> bool {
        let in_flight_upto = keep
            .checked_sub(1)
            .and_then(|k| self.mem.get(k))
            .map(|m| m.entry.seq);
        let idx = self
            .segments
            .iter()
            .position(|s| s.loaded && in_flight_upto.is_none_or(|f| s.first > f))
            .or_else(|| self.segments.iter().position(|s| !s.loaded));
        let Some(idx) = idx else { return false };
        if idx == self.segments.len() - 1 {
            self.appender = None;
        }
        let s = self.segments.remove(idx).expect("index checked");
        if s.loaded {
            self.mem
                .retain(|m| m.entry.seq < s.first || m.entry.seq > s.last);
        }
        self.dropped += s.count;
        self.retire(s);
        true
    }
}

impl crate::outbox::Store for Spool {
    /// A message that cannot be written is kept in memory or dropped and counted, never lost
    /// silently: storing one does not fail.
    type Error = Infallible;

    fn push(&mut self, message: crate::outbox::Message) -> Result<u64, Infallible> {
        Ok(self.insert(message))
    }

    fn get(&mut self, i: usize) -> Option<&Entry> {
        Spool::get(self, i)
    }

    fn ack_front(&mut self, n: usize) {
        Spool::ack_front(self, n)
    }

    fn evict(&mut self, keep: usize) -> u64 {
        self.enforce_bound(keep)
    }

    fn len(&self) -> u64 {
        Spool::len(self)
    }

    fn next_seq(&self) -> u64 {
        self.next_seq
    }

    fn broker_away(&mut self, away: bool) {
        self.set_spilling(away)
    }
}
