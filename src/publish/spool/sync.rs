//! The slow part of the spool's disk I/O (fsync of files and of the directory after a create,
//! rename or delete) on a thread of its own, in order: the gateway's runtime thread only writes
//! into the page cache. A spilled segment becomes visible under its name (rename) only after its
//! data is synced, and a deletion never overtakes the rename before it.
//!
//! What fails here is reported back to the spool ([`Report`]), never just logged: a segment
//! that could not be published is taken back (its temp file removed, its entries in memory
//! only again), one whose sync failed is not trusted to be on disk. A [`Barrier`] is answered
//! with how many such failures there were, so a state save is told "durable" only when none
//! happened that the spool had not taken in before it wrote.

use std::fs::File;
use std::path::PathBuf;
use std::sync::mpsc::{Receiver, Sender};
use std::time::Duration;

/// A file-system step done off the runtime thread, in order.
#[derive(Debug)]
pub enum Job {
    /// A segment file was created: sync the directory so its name survives a crash.
    Created(PathBuf),
    /// Sync the data appended to a segment.
    Sync(File, PathBuf),
    /// Sync the temp file's data, rename it to its name, sync the directory; on any failure the
    /// temp file (or the renamed one) is removed.
    Publish {
        file: File,
        tmp: PathBuf,
        path: PathBuf,
    },
    /// A segment whose every entry is acknowledged (or dropped).
    Remove(PathBuf),
    /// A segment with unreadable lines, kept under a name that is not a segment's.
    Quarantine { path: PathBuf, to: PathBuf },
    /// Answered, with the failures so far, once every job before it is done.
    Barrier(Sender<u64>),
}

/// Something the sync thread could not do.
#[derive(Debug)]
pub enum Report {
    /// The spilled segment at `path` is not on disk (its temp file is removed): its entries
    /// are in memory only.
    NotPublished {
        path: PathBuf,
        error: std::io::Error,
    },
    /// The data or the name of the segment at `path` may not be on disk (a sync failed).
    Unsure {
        path: PathBuf,
        error: std::io::Error,
    },
    /// A removal or a rename of a finished segment failed: no message is at stake.
    Trouble {
        path: PathBuf,
        error: std::io::Error,
    },
}

/// Carries out jobs for one spool directory, counting and reporting what fails.
#[derive(Debug)]
struct Worker {
    dir: PathBuf,
    /// `NotPublished` and `Unsure` reports sent so far.
    failures: u64,
    reports: Sender<Report>,
}

impl Worker {
    fn failed(&mut self, report: Report) {
        if !matches!(report, Report::Trouble { .. }) {
            self.failures += 1;
        }
        let _ = self.reports.send(report);
    }

    fn run(&mut self, job: Job) {
        match job {
            Job::Created(path) => {
                if let Err(error) = crate::state::sync_dir(&self.dir) {
                    self.failed(Report::Unsure { path, error });
                }
            }
            Job::Sync(file, path) => {
                if let Err(error) = file.sync_data() {
                    self.failed(Report::Unsure { path, error });
                }
            }
            Job::Publish { file, tmp, path } => {
                if let Err(error) = self.publish(&file, &tmp, &path) {
                    self.failed(Report::NotPublished { path, error });
                }
            }
            Job::Remove(path) => match std::fs::remove_file(&path) {
                Ok(()) => self.sync_dir_after(path),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(error) => self.failed(Report::Trouble { path, error }),
            },
            Job::Quarantine { path, to } => match std::fs::rename(&path, &to) {
                Ok(()) => self.sync_dir_after(to),
                Err(error) => self.failed(Report::Trouble { path, error }),
            },
            Job::Barrier(done) => {
                let _ = done.send(self.failures);
            }
        }
    }

    fn sync_dir_after(&mut self, path: PathBuf) {
        if let Err(error) = crate::state::sync_dir(&self.dir) {
            self.failed(Report::Trouble { path, error });
        }
    }

    fn publish(&self, file: &File, tmp: &PathBuf, path: &PathBuf) -> std::io::Result<()> {
        if let Err(e) = file.sync_data().and_then(|()| std::fs::rename(tmp, path)) {
            let _ = std::fs::remove_file(tmp);
            return Err(e);
        }
        if let Err(e) = crate::state::sync_dir(&self.dir) {
            // Its name may not survive a crash: taken back, written again at the next spill.
            let _ = std::fs::remove_file(path);
            return Err(e);
        }
        Ok(())
    }
}

/// The thread that carries out [`Job`]s for one spool directory (or, when no thread can be
/// started, the caller itself, slowly but in order).
#[derive(Debug)]
pub struct Syncer {
    jobs: Option<Sender<Job>>,
    inline: Option<Worker>,
}

impl Syncer {
    /// A syncer for `dir`, and the receiver of what it could not do.
    pub fn start(dir: PathBuf) -> (Syncer, Receiver<Report>) {
        let (reports, reported) = std::sync::mpsc::channel();
        let worker = |reports| Worker {
            dir: dir.clone(),
            failures: 0,
            reports,
        };
        let mut threaded = worker(reports.clone());
        let (jobs, rx) = std::sync::mpsc::channel::<Job>();
        let spawned = std::thread::Builder::new()
            .name("pulsegate-spool-sync".into())
            .spawn(move || {
                for job in rx {
                    threaded.run(job);
                }
            });
        let syncer = match spawned {
            Ok(_) => Syncer {
                jobs: Some(jobs),
                inline: None,
            },
            Err(e) => {
                tracing::error!("spool: cannot start the sync thread ({e}): syncing inline");
                Syncer {
                    jobs: None,
                    inline: Some(worker(reports)),
                }
            }
        };
        (syncer, reported)
    }

    pub fn send(&mut self, job: Job) {
        match (&self.jobs, &mut self.inline) {
            (Some(jobs), _) => {
                let _ = jobs.send(job);
            }
            (None, Some(worker)) => worker.run(job),
            (None, None) => {}
        }
    }

    /// A receiver answered, with the failures so far, once every job sent before is done.
    pub fn barrier(&mut self) -> Receiver<u64> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.send(Job::Barrier(tx));
        rx
    }
}

/// A state save's question, "is everything stored so far on disk?", to be answered off the
/// runtime thread: yes when the spool wrote everything, trusted every segment, and the sync
/// thread reported no failure it had not taken in before writing.
#[derive(Debug)]
pub struct Durability {
    pub(super) answer: Receiver<u64>,
    /// Failures the spool had taken in when it wrote.
    pub(super) seen: u64,
    /// Everything was written and no segment is in doubt.
    pub(super) clean: bool,
}

impl Durability {
    /// Waits (blocking) up to `timeout` for the sync thread; whether the messages are durable.
    pub fn wait(self, timeout: Duration) -> bool {
        self.clean && matches!(self.answer.recv_timeout(timeout), Ok(f) if f == self.seen)
    }
}
