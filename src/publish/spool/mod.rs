//! Store and forward: messages stay here until the broker acknowledges them (QoS 1 PUBACK).
//!
//! While the broker answers, messages live in memory only (no disk wear on the edge PC's flash).
//! When it is away they are written to segment files in `<state_dir>/spool/<output>/`
//! ([`segment`]), so an outage longer than memory allows, or a gateway restart, loses nothing.
//! The spool is bounded in bytes; when full the oldest messages are dropped and counted (totals
//! stay exact: every reading carries the running total).
//!
//! Order is kept: memory holds the oldest messages, files the newer ones, files in sequence
//! order, and the *tail*, messages newer than every file that are not written yet, last. The
//! tail is written in chunks and at every flush; when a write fails (a full disk, an I/O error)
//! it stays in memory, bounded, and is tried again at the next flush: a message is counted as
//! on disk only once its write returned, and as durable only once the sync thread ([`sync`])
//! synced it without a failure. Failures are counted and logged within a budget ([`faults`]).

mod faults;
mod queue;
pub mod segment;
mod spill;
mod sync;
#[cfg(test)]
mod tests;
mod writer;

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::Receiver;

pub use crate::outbox::Entry;
pub use segment::is_segment_name;
pub use sync::Durability;

use faults::Faults;
use sync::{Report, Syncer};
use writer::Appender;

/// The spool cannot be opened (its directory or a segment file cannot be read).
#[derive(Debug, thiserror::Error)]
#[error("spool {path}: {source}")]
pub struct SpoolError {
    path: String,
    source: std::io::Error,
}

impl SpoolError {
    /// A failure at `path`.
    pub fn new(path: &Path, source: std::io::Error) -> SpoolError {
        SpoolError {
            path: path.display().to_string(),
            source,
        }
    }
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> SpoolError + '_ {
    move |source| SpoolError::new(path, source)
}

#[derive(Debug)]
struct MemEntry {
    entry: Entry,
    /// Also in a segment file (loaded from one, or spilled).
    on_disk: bool,
}

#[derive(Debug)]
struct Segment {
    first: u64,
    last: u64,
    count: u64,
    bytes: u64,
    path: PathBuf,
    /// Its entries are in memory now.
    loaded: bool,
    /// Lines in it that are not entries: it is kept (renamed) rather than removed.
    unreadable: u64,
    /// A sync of it failed: its messages are not trusted to be on disk.
    unsure: bool,
}

/// Largest segment file before a new one is started (smaller for small spools).
const SEGMENT_BYTES: u64 = 1 << 20;

/// The tail is written once it holds this much (or a quarter of the memory share, if less),
/// and at every flush.
const CHUNK_BYTES: u64 = 8 << 10;

/// The spool of one output.
#[derive(Debug)]
pub struct Spool {
    dir: PathBuf,
    max_bytes: u64,
    mem_limit: u64,
    mem: VecDeque<MemEntry>,
    /// Bytes of the entries in `mem` that are in memory only.
    mem_bytes: u64,
    /// Segment files, oldest first.
    segments: VecDeque<Segment>,
    /// Messages newer than every segment, not written yet.
    tail: VecDeque<Entry>,
    tail_bytes: u64,
    /// The newest segment, open for appending.
    appender: Option<Appender>,
    next_seq: u64,
    /// New messages go to disk (the broker is away).
    spilling: bool,
    /// A write failed: the tail waits for the next flush rather than trying at every message.
    blocked: bool,
    /// Messages dropped since start: the spool was full, or memory's share for messages that
    /// could not be written was.
    pub dropped: u64,
    /// Bytes written to segment files, since start.
    pub written: u64,
    faults: Faults,
    syncer: Syncer,
    reports: Receiver<Report>,
    /// `NotPublished` and `Unsure` reports taken in.
    reports_taken: u64,
}

impl Drop for Spool {
    /// Whatever was asked of the disk is done before the spool is gone (a restart in the same
    /// process, or the end of the gateway), within reason.
    fn drop(&mut self) {
        let _ = self
            .syncer
            .barrier()
            .recv_timeout(std::time::Duration::from_secs(5));
    }
}

impl Spool {
    /// Opens the spool in `dir`, picking up segment files a previous run left. Only files with
    /// a segment's name are read; an empty one (or one holding only a line a crash cut short)
    /// and a temp file a crash left are removed; nothing else is touched.
    pub fn open(dir: &Path, max_bytes: u64) -> Result<Spool, SpoolError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let mut faults = Faults::new();
        let mut segments = Vec::new();
        let mut removed = false;
        for entry in std::fs::read_dir(dir).map_err(io_err(dir))? {
            let entry = entry.map_err(io_err(dir))?;
            let name = entry.file_name();
            let name = name.to_string_lossy();
            // A link or a directory with our name is not ours either.
            let regular = entry.file_type().is_ok_and(|t| t.is_file());
            if regular && writer::is_temp_name(&name) {
                removed |= std::fs::remove_file(entry.path()).is_ok();
                continue;
            }
            if !regular || !is_segment_name(&name) {
                continue;
            }
            let path = entry.path();
            match Self::found(path, &mut faults)? {
                Some(s) => segments.push(s),
                None => removed = true,
            }
        }
        if removed {
            let _ = crate::state::sync_dir(dir);
        }
        segments.sort_by_key(|s| s.first);
        let next_seq = segments.iter().map(|s| s.last + 1).max().unwrap_or(1);
        let (syncer, reports) = Syncer::start(dir.to_path_buf());
        Ok(Spool {
            dir: dir.to_path_buf(),
            max_bytes,
            mem_limit: (max_bytes / 8).clamp(64 * 1024, 4 << 20),
            mem: VecDeque::new(),
            mem_bytes: 0,
            segments: segments.into(),
            tail: VecDeque::new(),
            tail_bytes: 0,
            appender: None,
            next_seq,
            spilling: false,
            blocked: false,
            dropped: 0,
            written: 0,
            faults,
            syncer,
            reports,
            reports_taken: 0,
        })
    }

    /// A segment file a previous run left, read through; `None` when it holds no entry (then
    /// removed, or kept as unreadable).
    fn found(path: PathBuf, faults: &mut Faults) -> Result<Option<Segment>, SpoolError> {
        let scan = segment::scan(&path, |_| {}).map_err(io_err(&path))?;
        for u in &scan.unreadable {
            faults.unreadable(&path, u.offset, &u.why);
        }
        if let Some(offset) = scan.torn {
            faults.torn(&path, offset);
        }
        if scan.count == 0 {
            if scan.unreadable.is_empty() {
                let _ = std::fs::remove_file(&path);
            } else if let Err(e) = std::fs::rename(&path, segment::quarantine_path(&path)) {
                faults.other(&path, "cannot set aside the unreadable", &e);
            }
            return Ok(None);
        }
        Ok(Some(Segment {
            first: scan.first,
            last: scan.last,
            count: scan.count,
            bytes: scan.bytes,
            path,
            loaded: false,
            unreadable: scan.unreadable.len() as u64,
            unsure: false,
        }))
    }

    /// The directory of the spool's files.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Messages waiting (in memory and on disk).
    pub fn len(&self) -> u64 {
        self.in_memory_only() + self.segments.iter().map(|s| s.count).sum::<u64>()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Messages waiting that are in memory only (not written, or their write failed).
    pub fn in_memory_only(&self) -> u64 {
        self.mem.iter().filter(|m| !m.on_disk).count() as u64 + self.tail.len() as u64
    }

    /// Messages waiting in segment files no failed sync puts in doubt.
    pub fn on_disk(&self) -> u64 {
        self.segments
            .iter()
            .filter(|s| !s.unsure)
            .map(|s| s.count)
            .sum()
    }

    /// Writes (or syncs) of the spool's files that failed, since start.
    pub fn write_failures(&self) -> u64 {
        self.faults.write_failures
    }

    /// Lines of spool files that were not a stored message, skipped, since start.
    pub fn unreadable_lines(&self) -> u64 {
        self.faults.unreadable_lines
    }

    /// Bytes the waiting messages take (memory and disk).
    pub fn total_bytes(&self) -> u64 {
        self.mem_bytes + self.tail_bytes + self.segments.iter().map(|s| s.bytes).sum::<u64>()
    }

    /// Adds a message; returns its sequence number. Drops the oldest messages while over the
    /// bound: stand-alone use, with nothing in flight (the outbox evicts around its window;
    /// the gateway stores through it, `Store::push`).
    #[cfg(test)]
    pub fn push(
        &mut self,
        topic: String,
        payload: String,
        qos: u8,
        retain: bool,
        correlation: Option<Vec<u8>>,
    ) -> u64 {
        let mut m = crate::outbox::Message::new(topic, payload, qos, retain);
        m.properties.correlation = correlation.map(bytes::Bytes::from);
        let seq = self.insert(m);
        self.enforce_bound(0);
        seq
    }

    /// Stores a message without enforcing the bound.
    fn insert(&mut self, m: crate::outbox::Message) -> u64 {
        let entry = Entry::of(self.next_seq, m);
        self.next_seq += 1;
        let seq = entry.seq;
        let size = entry.size();
        let to_tail = self.spilling
            || !self.tail.is_empty()
            || self.segments.iter().any(|s| !s.loaded)
            || self.mem_bytes + size > self.mem_limit;
        if to_tail {
            self.tail_bytes += size;
            self.tail.push_back(entry);
            if self.tail_bytes >= CHUNK_BYTES.min(self.mem_limit / 4) && !self.blocked {
                self.write_tail();
            }
            self.cap_tail();
        } else {
            self.mem_bytes += size;
            self.mem.push_back(MemEntry {
                entry,
                on_disk: false,
            });
        }
        seq
    }

    /// Messages that could not be written take at most the memory share of the spool; the
    /// oldest of them beyond it are dropped and counted.
    fn cap_tail(&mut self) {
        while self.tail_bytes > self.mem_limit {
            let Some(e) = self.tail.pop_front() else {
                break;
            };
            self.tail_bytes -= e.size();
            self.dropped += 1;
        }
    }
}
