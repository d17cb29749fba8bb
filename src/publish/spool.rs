//! Store and forward: messages stay here until the broker acknowledges them (QoS 1 PUBACK).
//!
//! While the broker answers, messages live in memory only (no disk wear on the edge PC's flash).
//! When it is away they are written to segment files in `<state_dir>/spool/`, so an outage longer
//! than memory allows, or a gateway restart, loses nothing. The spool is bounded in bytes; when
//! full the oldest messages are dropped and counted (totals stay exact: every reading carries the
//! running total).
//!
//! Order is kept: memory holds the oldest messages, files the newer ones, files in sequence order.
//!
//! The slow part of disk I/O (fsync of files and of the directory after a create, rename or
//! delete) runs on a thread of its own, in order: the gateway's runtime thread only writes into
//! the page cache. A spilled segment becomes visible under its name (rename) only after its data
//! is synced, and a deletion never overtakes the rename before it.

use std::collections::VecDeque;
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

pub use crate::outbox::Entry;

/// A spool failure (disk full, permissions): logged by the caller; memory keeps working.
#[derive(Debug, thiserror::Error)]
#[error("spool {path}: {source}")]
pub struct SpoolError {
    path: String,
    source: std::io::Error,
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
}

/// Largest segment file before a new one is started (smaller for small spools).
const SEGMENT_BYTES: u64 = 1 << 20;

impl Drop for Spool {
    /// Whatever was asked of the disk is done before the spool is gone (a restart in the same
    /// process, or the end of the gateway), within reason.
    fn drop(&mut self) {
        let _ = self
            .barrier()
            .recv_timeout(std::time::Duration::from_secs(5));
    }
}

/// A file-system step done off the runtime thread, in order.
#[derive(Debug)]
enum Job {
    SyncFile(File, PathBuf),
    /// Sync the temp file's data, rename it to its name, sync the directory.
    Publish {
        file: File,
        tmp: PathBuf,
        path: PathBuf,
    },
    Remove(PathBuf),
    SyncDir,
    /// Answered when every job before it is done.
    Barrier(std::sync::mpsc::Sender<()>),
}

/// The thread that carries out [`Job`]s for one spool directory.
#[derive(Debug)]
struct Syncer {
    jobs: std::sync::mpsc::Sender<Job>,
}

impl Syncer {
    fn start(dir: PathBuf) -> Syncer {
        let (jobs, rx) = std::sync::mpsc::channel::<Job>();
        let spawned = std::thread::Builder::new()
            .name("pulsegate-spool-sync".into())
            .spawn(move || {
                let sync_dir = || {
                    if let Err(e) = crate::state::sync_dir(&dir) {
                        tracing::error!("spool {}: sync of the directory: {e}", dir.display());
                    }
                };
                for job in rx {
                    let result = match job {
                        Job::SyncFile(f, path) => f.sync_data().map_err(|e| (path, e)),
                        Job::Publish { file, tmp, path } => file
                            .sync_data()
                            .and_then(|()| std::fs::rename(&tmp, &path))
                            .map(|()| sync_dir())
                            .map_err(|e| (path, e)),
                        Job::Remove(path) => match std::fs::remove_file(&path) {
                            Ok(()) => {
                                sync_dir();
                                Ok(())
                            }
                            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
                            Err(e) => Err((path, e)),
                        },
                        Job::SyncDir => {
                            sync_dir();
                            Ok(())
                        }
                        Job::Barrier(done) => {
                            let _ = done.send(());
                            Ok(())
                        }
                    };
                    if let Err((path, e)) = result {
                        tracing::error!("spool {}: {e}", path.display());
                    }
                }
            });
        if let Err(e) = spawned {
            tracing::error!("spool: cannot start the sync thread: {e}");
        }
        Syncer { jobs }
    }

    fn send(&self, job: Job) {
        let _ = self.jobs.send(job);
    }
}

/// The spool of one gateway.
#[derive(Debug)]
pub struct Spool {
    dir: PathBuf,
    max_bytes: u64,
    mem_limit: u64,
    mem: VecDeque<MemEntry>,
    mem_bytes: u64,
    /// Segment files, oldest first.
    segments: VecDeque<Segment>,
    writer: Option<BufWriter<File>>,
    next_seq: u64,
    /// New messages go to disk (the broker is away).
    spilling: bool,
    /// Messages dropped because the spool was full, since start.
    pub dropped: u64,
    /// Bytes written to segment files, since start.
    pub written: u64,
    syncer: Syncer,
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
    move |source| SpoolError {
        path: path.display().to_string(),
        source,
    }
}

/// Whether `name` is the name of one of the spool's segment files: `<20 digits>.jsonl`.
pub fn is_segment_name(name: &str) -> bool {
    name.strip_suffix(".jsonl")
        .is_some_and(|stem| stem.len() == 20 && stem.bytes().all(|b| b.is_ascii_digit()))
}

impl Spool {
    /// Opens the spool in `dir`, picking up segment files a previous run left.
    pub fn open(dir: &Path, max_bytes: u64) -> Result<Spool, SpoolError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let mut segments = Vec::new();
        let mut next_seq = 1;
        for entry in std::fs::read_dir(dir).map_err(io_err(dir))? {
            let path = entry.map_err(io_err(dir))?.path();
            if path.extension().is_none_or(|x| x != "jsonl") {
                continue;
            }
            let (mut first, mut last, mut count) = (u64::MAX, 0, 0);
            let file = File::open(&path).map_err(io_err(&path))?;
            for line in BufReader::new(file).lines() {
                let Ok(line) = line else { break };
                // A line cut short by a crash is skipped, not fatal.
                if let Ok(e) = serde_json::from_str::<Entry>(&line) {
                    first = first.min(e.seq);
                    last = last.max(e.seq);
                    count += 1;
                }
            }
            let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
            if count == 0 {
                let _ = std::fs::remove_file(&path);
                let _ = crate::state::sync_dir(dir);
                continue;
            }
            next_seq = next_seq.max(last + 1);
            segments.push(Segment {
                first,
                last,
                count,
                bytes,
                path,
                loaded: false,
            });
        }
        segments.sort_by_key(|s| s.first);
        Ok(Spool {
            dir: dir.to_path_buf(),
            max_bytes,
            mem_limit: (max_bytes / 8).clamp(64 * 1024, 4 << 20),
            mem: VecDeque::new(),
            mem_bytes: 0,
            segments: segments.into(),
            writer: None,
            next_seq,
            spilling: false,
            dropped: 0,
            written: 0,
            syncer: Syncer::start(dir.to_path_buf()),
        })
    }

    /// The directory of the spool's files.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Messages waiting (in memory and on disk).
    pub fn len(&self) -> u64 {
        self.mem.iter().filter(|m| !m.on_disk).count() as u64
            + self.segments.iter().map(|s| s.count).sum::<u64>()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes the waiting messages take (memory and disk).
    pub fn total_bytes(&self) -> u64 {
        self.mem_bytes + self.segments.iter().map(|s| s.bytes).sum::<u64>()
    }

    /// Adds a message; returns its sequence number. Drops the oldest messages while over the
    /// bound: stand-alone use, with nothing in flight (the outbox evicts around its window).
    pub fn push(
        &mut self,
        topic: String,
        payload: String,
        qos: u8,
        retain: bool,
        correlation: Option<Vec<u8>>,
    ) -> Result<u64, SpoolError> {
        let mut m = crate::outbox::Message::new(topic, payload, qos, retain);
        m.properties.correlation = correlation.map(bytes::Bytes::from);
        let seq = self.insert(m)?;
        self.enforce_bound(0);
        Ok(seq)
    }

    /// Stores a message without enforcing the bound.
    fn insert(&mut self, m: crate::outbox::Message) -> Result<u64, SpoolError> {
        let entry = Entry::of(self.next_seq, m);
        self.next_seq += 1;
        let seq = entry.seq;
        let to_disk = self.spilling
            || self.segments.iter().any(|s| !s.loaded)
            || self.mem_bytes + entry.size() > self.mem_limit;
        if to_disk {
            self.append(&entry)?;
        } else {
            self.mem_bytes += entry.size();
            self.mem.push_back(MemEntry {
                entry,
                on_disk: false,
            });
        }
        Ok(seq)
    }

    /// Appends to the newest segment file, starting one when needed.
    fn append(&mut self, entry: &Entry) -> Result<(), SpoolError> {
        let line = serde_json::to_string(entry).expect("entry serializes") + "\n";
        let need_new = match self.segments.back() {
            Some(s) => {
                s.loaded
                    || s.bytes + line.len() as u64 > SEGMENT_BYTES.min(self.max_bytes / 8)
                    || self.writer.is_none()
            }
            None => true,
        };
        if need_new {
            self.flush()?;
            let path = self.dir.join(format!("{:020}.jsonl", entry.seq));
            let file = OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .map_err(io_err(&path))?;
            self.writer = Some(BufWriter::new(file));
            self.syncer.send(Job::SyncDir);
            self.segments.push_back(Segment {
                first: entry.seq,
                last: entry.seq,
                count: 0,
                bytes: 0,
                path,
                loaded: false,
            });
        }
        let seg = self.segments.back_mut().expect("just ensured");
        let w = self.writer.as_mut().expect("just ensured");
        w.write_all(line.as_bytes()).map_err(io_err(&seg.path))?;
        self.written += line.len() as u64;
        seg.last = entry.seq;
        seg.count += 1;
        seg.bytes += line.len() as u64;
        Ok(())
    }

    /// Flushes the newest segment to the OS (called at each state flush and at shutdown).
    pub fn flush(&mut self) -> Result<(), SpoolError> {
        if let Some(w) = self.writer.as_mut() {
            let path = self
                .segments
                .back()
                .map(|s| s.path.clone())
                .unwrap_or_default();
            w.flush().map_err(io_err(&path))?;
            let file = w.get_ref().try_clone().map_err(io_err(&path))?;
            self.syncer.send(Job::SyncFile(file, path));
        }
        Ok(())
    }

    /// A receiver answered once every file-system step asked so far is done (at shutdown:
    /// wait on it off the runtime thread).
    pub fn barrier(&self) -> std::sync::mpsc::Receiver<()> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.syncer.send(Job::Barrier(tx));
        rx
    }

    /// The broker went away (`true`) or came back (`false`). While away, new messages go to
    /// disk and the ones in memory are written out at the next [`Spool::spill`].
    pub fn set_spilling(&mut self, spilling: bool) {
        self.spilling = spilling;
    }

    /// Writes the messages that exist only in memory to a segment of their own, so a restart
    /// (or a crash) finds them. Their file sorts before newer ones by its first sequence number.
    pub fn spill(&mut self) -> Result<(), SpoolError> {
        let pending: Vec<usize> = (0..self.mem.len())
            .filter(|&i| !self.mem[i].on_disk)
            .collect();
        if pending.is_empty() {
            return self.flush();
        }
        let first = self.mem[pending[0]].entry.seq;
        let path = self.dir.join(format!("{first:020}.jsonl"));
        let tmp = path.with_extension("tmp");
        let mut w = BufWriter::new(File::create(&tmp).map_err(io_err(&tmp))?);
        let (mut last, mut bytes) = (first, 0);
        for &i in &pending {
            let line = serde_json::to_string(&self.mem[i].entry).expect("entry serializes") + "\n";
            w.write_all(line.as_bytes()).map_err(io_err(&tmp))?;
            last = self.mem[i].entry.seq;
            bytes += line.len() as u64;
        }
        w.flush().map_err(io_err(&tmp))?;
        self.written += bytes;
        let file = w.into_inner().map_err(|e| io_err(&tmp)(e.into_error()))?;
        self.syncer.send(Job::Publish {
            file,
            tmp,
            path: path.clone(),
        });
        for &i in &pending {
            self.mem[i].on_disk = true;
            self.mem_bytes -= self.mem[i].entry.size();
        }
        let seg = Segment {
            first,
            last,
            count: pending.len() as u64,
            bytes,
            path,
            loaded: true,
        };
        let at = self
            .segments
            .iter()
            .position(|s| s.first > first)
            .unwrap_or(self.segments.len());
        self.segments.insert(at, seg);
        self.flush()
    }

    /// The `i`-th oldest waiting message, loading segment files into memory as needed.
    pub fn get(&mut self, i: usize) -> Option<&Entry> {
        while i >= self.mem.len() {
            if !self.load_next() {
                return None;
            }
        }
        self.mem.get(i).map(|m| &m.entry)
    }

    fn load_next(&mut self) -> bool {
        let Some(idx) = self.segments.iter().position(|s| !s.loaded) else {
            return false;
        };
        if idx == self.segments.len() - 1 {
            // The segment being written: finish it first.
            let _ = self.flush();
            self.writer = None;
        }
        let seg = &mut self.segments[idx];
        seg.loaded = true;
        let Ok(file) = File::open(&seg.path) else {
            return true;
        };
        for line in BufReader::new(file).lines() {
            let Ok(line) = line else { break };
            if let Ok(entry) = serde_json::from_str::<Entry>(&line) {
                self.mem.push_back(MemEntry {
                    entry,
                    on_disk: true,
                });
            }
        }
        true
    }

    /// The broker acknowledged the oldest `n` messages: forget them, and delete segment files
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
            self.syncer.send(Job::Remove(s.path));
        }
    }

    /// Drops the oldest messages beyond the first `keep` (those in flight) while over the bound;
    /// returns how many.
    fn enforce_bound(&mut self, keep: usize) -> u64 {
        let before = self.dropped;
        while self.total_bytes() > self.max_bytes {
            if let Some(i) = (keep..self.mem.len()).find(|&i| !self.mem[i].on_disk) {
                let m = self.mem.remove(i).expect("index checked");
                self.mem_bytes -= m.entry.size();
                self.dropped += 1;
                continue;
            }
            // A loaded segment none of whose messages is in flight goes whole.
            let in_flight_upto = if keep == 0 {
                None
            } else {
                self.mem.get(keep - 1).map(|m| m.entry.seq)
            };
            let idx = self
                .segments
                .iter()
                .position(|s| s.loaded && in_flight_upto.is_none_or(|f| s.first > f))
                .or_else(|| self.segments.iter().position(|s| !s.loaded));
            let Some(idx) = idx else { break };
            if idx == self.segments.len() - 1 {
                self.writer = None;
            }
            let s = self.segments.remove(idx).expect("index checked");
            if s.loaded {
                self.mem
                    .retain(|m| m.entry.seq < s.first || m.entry.seq > s.last);
            }
            self.syncer.send(Job::Remove(s.path.clone()));
            self.dropped += s.count;
        }
        self.dropped - before
    }
}

impl crate::outbox::Store for Spool {
    type Error = SpoolError;

    fn push(&mut self, message: crate::outbox::Message) -> Result<u64, SpoolError> {
        self.insert(message)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pulsegate-spool-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    fn push(s: &mut Spool, n: u64) {
        for i in 0..n {
            s.push(format!("t/{i}"), format!("{{\"n\":{i}}}"), 1, false, None)
                .unwrap();
        }
    }

    fn drain(s: &mut Spool) -> Vec<u64> {
        let mut out = Vec::new();
        while let Some(e) = s.get(0) {
            out.push(e.seq);
            s.ack_front(1);
        }
        out
    }

    #[test]
    fn messages_come_out_in_order_and_leave_when_acknowledged() {
        let d = dir("order");
        let mut s = Spool::open(&d, 1 << 20).unwrap();
        push(&mut s, 5);
        assert_eq!(s.get(2).unwrap().seq, 3);
        s.ack_front(2);
        assert_eq!(s.len(), 3);
        assert_eq!(drain(&mut s), [3, 4, 5]);
        assert!(s.is_empty());
    }

    #[test]
    fn while_the_broker_is_away_messages_go_to_disk_and_keep_their_order() {
        let d = dir("spill");
        let mut s = Spool::open(&d, 64 << 20).unwrap();
        push(&mut s, 3);
        s.set_spilling(true);
        push(&mut s, 4);
        s.spill().unwrap();
        s.set_spilling(false);
        push(&mut s, 2);
        assert_eq!(drain(&mut s), (1..=9).collect::<Vec<_>>());
        s.barrier().recv().unwrap();
        assert_eq!(
            std::fs::read_dir(&d).unwrap().count(),
            0,
            "acknowledged files are deleted"
        );
    }

    #[test]
    fn the_spool_survives_a_restart() {
        let d = dir("restart");
        {
            let mut s = Spool::open(&d, 64 << 20).unwrap();
            push(&mut s, 3);
            s.ack_front(1);
            s.set_spilling(true);
            push(&mut s, 2);
            s.spill().unwrap();
        }
        let mut s = Spool::open(&d, 64 << 20).unwrap();
        assert_eq!(s.len(), 4);
        assert_eq!(drain(&mut s), [2, 3, 4, 5]);
        let seq = s.push("t".into(), "x".into(), 1, false, None).unwrap();
        assert_eq!(seq, 6, "sequence numbers go on after a restart");
    }

    #[test]
    fn a_full_spool_drops_the_oldest_and_counts_them() {
        let d = dir("full");
        let mut s = Spool::open(&d, 100_000).unwrap();
        s.set_spilling(true);
        push(&mut s, 5000);
        assert!(s.dropped > 0);
        assert!(s.total_bytes() <= 100_000 + SEGMENT_BYTES);
        let left = drain(&mut s);
        assert_eq!(left.len() as u64 + s.dropped, 5000);
        assert!(left.windows(2).all(|w| w[0] < w[1]), "still in order");
        assert_eq!(*left.last().unwrap(), 5000, "the newest are kept");
    }

    #[test]
    fn a_full_spool_on_disk_never_drops_what_the_outbox_has_in_flight() {
        use crate::outbox::{Message, Outbox, Step};
        let now = tokio::time::Instant::now();
        let d = dir("inflight");
        let mut spool = Spool::open(&d, 100_000).unwrap();
        spool.mem_limit = 1000;
        let mut o = Outbox::new(spool, 3, now);
        o.connected(None, now);
        let m = |i: u64| Message::new(format!("t/{i}"), format!("{{\"n\":{i}}}"), 1, false);
        for i in 0..3 {
            o.enqueue(m(i)).unwrap();
        }
        for pkid in 1..=3 {
            assert!(
                matches!(o.next(now), Some(Step::Send { entry: e, .. }) if e.seq == u64::from(pkid))
            );
            o.sent(pkid);
        }
        for i in 3..5000 {
            o.enqueue(m(i)).unwrap();
        }
        assert!(o.evicted > 0);
        let held: Vec<u64> = (0..3).map(|i| o.store_mut().get(i).unwrap().seq).collect();
        assert_eq!(held, [1, 2, 3], "the messages in flight are still stored");
        let oldest_left = o.store_mut().get(3).unwrap().seq;
        for pkid in 1..=3 {
            o.acked(pkid, now);
        }
        assert!(matches!(o.next(now), Some(Step::Send { entry: e, .. }) if e.seq == oldest_left));
        assert_eq!(
            o.store_mut().get(0).unwrap().seq,
            oldest_left,
            "1..=3 released"
        );
    }

    #[test]
    fn a_binary_payload_comes_back_unchanged_after_a_restart() {
        let d = dir("binary");
        let payload = vec![0u8, 0xff, 0x80, b'\n', b'"'];
        {
            let mut s = Spool::open(&d, 64 << 20).unwrap();
            s.set_spilling(true);
            let m = crate::outbox::Message::new("t".into(), payload.clone(), 1, false);
            crate::outbox::Store::push(&mut s, m).unwrap();
            s.spill().unwrap();
        }
        let mut s = Spool::open(&d, 64 << 20).unwrap();
        assert_eq!(&s.get(0).unwrap().payload[..], &payload[..]);
    }

    #[test]
    fn memory_overflow_goes_to_disk_without_reordering() {
        let d = dir("overflow");
        let mut s = Spool::open(&d, 64 << 20).unwrap();
        s.mem_limit = 1000;
        push(&mut s, 100);
        s.barrier().recv().unwrap();
        assert!(std::fs::read_dir(&d).unwrap().count() > 0);
        assert_eq!(drain(&mut s), (1..=100).collect::<Vec<_>>());
    }
}
