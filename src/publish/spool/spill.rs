//! The way to disk: the tail appended to the newest segment, memory spilled to segments of its
//! own, the flush, the sync thread's reports taken in, and the durability a state save waits on.

use std::ops::Range;

use super::sync::{Durability, Job, Report};
use super::writer::{Appender, Refused};
use super::{MemEntry, SEGMENT_BYTES, Segment, Spool, segment, writer};

impl Spool {
    /// Largest segment file for this spool.
    fn segment_limit(&self) -> u64 {
        SEGMENT_BYTES.min(self.max_bytes / 8).max(1)
    }

    /// Appends the tail to the newest segment (a new one when needed) until it is written or a
    /// write fails; what failed stays in the tail, and `blocked` until the next flush.
    pub(super) fn write_tail(&mut self) {
        while let Some(front) = self.tail.front() {
            let first = front.seq;
            let fresh = match self.segments.back() {
                Some(s) => s.loaded || self.appender.is_none() || s.bytes >= self.segment_limit(),
                None => true,
            };
            if fresh && !self.start_segment(first) {
                return;
            }
            let seg = self.segments.back().expect("a segment to append to");
            let room = self.segment_limit().saturating_sub(seg.bytes);
            let mut lines = Vec::new();
            let mut n = 0;
            for e in &self.tail {
                let line = segment::line(e);
                if n > 0 && (lines.len() + line.len()) as u64 > room {
                    break;
                }
                lines.extend_from_slice(&line);
                n += 1;
            }
            let appended = self.appender.as_mut().expect("open").append(&lines);
            if let Err(refused) = appended {
                return self.append_failed(refused);
            }
            let seg = self.segments.back_mut().expect("a segment to append to");
            for e in self.tail.drain(..n) {
                self.tail_bytes -= e.size();
                seg.last = e.seq;
            }
            seg.count += n as u64;
            seg.bytes += lines.len() as u64;
            self.written += lines.len() as u64;
        }
    }

    /// A new segment file for entries from `first` on, open for appending.
    fn start_segment(&mut self, first: u64) -> bool {
        self.close_appender();
        let path = segment::path_of(&self.dir, first);
        match Appender::create(&path) {
            Ok(a) => {
                self.appender = Some(a);
                self.syncer.send(Job::Created(path.clone()));
                self.segments.push_back(Segment {
                    first,
                    last: first,
                    count: 0,
                    bytes: 0,
                    path,
                    loaded: false,
                    unreadable: 0,
                    unsure: false,
                });
                true
            }
            Err(e) => {
                self.blocked = true;
                let waiting = self.in_memory_only();
                self.faults.write_failed(&path, &e, waiting);
                false
            }
        }
    }

    /// An append failed: the file is cut back (an empty new one removed, one that may end in
    /// half a line gets no more appends); the entries stay in the tail.
    fn append_failed(&mut self, refused: Refused) {
        self.blocked = true;
        let seg = self.segments.back().expect("appending to it");
        let path = seg.path.clone();
        if seg.count == 0 {
            self.appender = None;
            let _ = std::fs::remove_file(&path);
            self.segments.pop_back();
        } else if !refused.intact {
            self.close_appender();
        }
        let waiting = self.in_memory_only();
        self.faults.write_failed(&path, &refused.error, waiting);
    }

    /// No more appends to the newest segment; what was appended is synced.
    pub(super) fn close_appender(&mut self) {
        if let Some(mut a) = self.appender.take()
            && let Some(s) = self.segments.back()
            && let Some(job) = a.sync_job(&s.path)
        {
            self.syncer.send(job);
        }
    }

    /// Writes the tail (again, after a failure) and syncs the newest segment (called at each
    /// state flush and at shutdown).
    pub fn flush(&mut self) {
        self.take_reports();
        self.blocked = false;
        self.flush_tail();
    }

    fn flush_tail(&mut self) {
        if !self.blocked {
            self.write_tail();
        }
        if let (Some(a), Some(s)) = (self.appender.as_mut(), self.segments.back())
            && let Some(job) = a.sync_job(&s.path)
        {
            self.syncer.send(job);
        }
    }

    /// The broker went away (`true`) or came back (`false`). While away, new messages go to
    /// disk and the ones in memory are written out at the next [`Spool::spill`].
    pub fn set_spilling(&mut self, spilling: bool) {
        self.spilling = spilling;
    }

    /// Writes every message that is in memory only to disk, so a restart (or a crash) finds
    /// them: runs of them in memory to segments of their own (sorted before newer files by
    /// their first sequence number), then the tail. What cannot be written stays in memory.
    pub fn spill(&mut self) {
        self.take_reports();
        self.write_out();
    }

    fn write_out(&mut self) {
        self.blocked = false;
        for run in self.memory_runs() {
            if !self.spill_run(run) {
                break;
            }
        }
        self.flush_tail();
    }

    /// Runs of consecutive entries in memory that are in memory only.
    fn memory_runs(&self) -> Vec<Range<usize>> {
        let mut runs: Vec<Range<usize>> = Vec::new();
        for i in (0..self.mem.len()).filter(|&i| !self.mem[i].on_disk) {
            match runs.last_mut() {
                Some(r) if r.end == i => r.end = i + 1,
                _ => runs.push(i..i + 1),
            }
        }
        runs
    }

    fn spill_run(&mut self, run: Range<usize>) -> bool {
        let first = self.mem[run.start].entry.seq;
        let last = self.mem[run.end - 1].entry.seq;
        let path = segment::path_of(&self.dir, first);
        let mut lines = Vec::new();
        for m in self.mem.range(run.clone()) {
            lines.extend_from_slice(&segment::line(&m.entry));
        }
        let (file, tmp) = match writer::write_temp(&path, &lines) {
            Ok(written) => written,
            Err(e) => {
                self.blocked = true;
                let waiting = self.in_memory_only();
                self.faults.write_failed(&path, &e, waiting);
                return false;
            }
        };
        self.syncer.send(Job::Publish {
            file,
            tmp,
            path: path.clone(),
        });
        for m in self.mem.range_mut(run.clone()) {
            m.on_disk = true;
            self.mem_bytes -= m.entry.size();
        }
        self.written += lines.len() as u64;
        let at = self.segments.partition_point(|s| s.first < first);
        self.segments.insert(
            at,
            Segment {
                first,
                last,
                count: run.len() as u64,
                bytes: lines.len() as u64,
                path,
                loaded: true,
                unreadable: 0,
                unsure: false,
            },
        );
        true
    }

    /// Takes in what the sync thread could not do: a spilled segment it could not publish is
    /// in memory only again (written at the next spill), one it could not sync is in doubt.
    pub(super) fn take_reports(&mut self) {
        while let Ok(report) = self.reports.try_recv() {
            match report {
                Report::NotPublished { path, error } => {
                    self.reports_taken += 1;
                    self.unpublish(&path);
                    let waiting = self.in_memory_only();
                    self.faults.write_failed(&path, &error, waiting);
                }
                Report::Unsure { path, error } => {
                    self.reports_taken += 1;
                    if let Some(s) = self.segments.iter_mut().find(|s| s.path == path) {
                        s.unsure = true;
                    }
                    self.faults.sync_failed(&path, &error);
                }
                Report::Trouble { path, error } => {
                    self.faults
                        .other(&path, "cannot remove or set aside", &error)
                }
            }
        }
    }

    /// The spilled segment at `path` is not on disk: its entries still in memory are in
    /// memory only again.
    fn unpublish(&mut self, path: &std::path::Path) {
        let Some(idx) = self
            .segments
            .iter()
            .position(|s| s.loaded && s.path == path)
        else {
            return;
        };
        let s = self.segments.remove(idx).expect("index checked");
        let spilled = |m: &&mut MemEntry| m.on_disk && (s.first..=s.last).contains(&m.entry.seq);
        for m in self.mem.iter_mut().filter(spilled) {
            m.on_disk = false;
            self.mem_bytes += m.entry.size();
        }
    }

    /// Writes out what is in memory only and asks the sync thread to finish; the answer says
    /// whether everything stored so far is durable (wait on it off the runtime thread).
    pub fn durable(&mut self) -> Durability {
        self.take_reports();
        let seen = self.reports_taken;
        self.write_out();
        let clean = self.in_memory_only() == 0 && !self.segments.iter().any(|s| s.unsure);
        Durability {
            answer: self.syncer.barrier(),
            seen,
            clean,
        }
    }

    /// A receiver answered once every file-system step asked so far is done.
    pub fn barrier(&mut self) -> std::sync::mpsc::Receiver<u64> {
        self.syncer.barrier()
    }

    /// Takes in the sync thread's reports (after a barrier: all of them up to it), so that
    /// [`Spool::on_disk`] and [`Spool::in_memory_only`] tell the truth.
    pub fn settle(&mut self) {
        self.take_reports();
    }
}
