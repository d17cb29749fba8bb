//! Writing segment files. Appends go to the newest segment; one that fails is cut back to the
//! last whole line, so the next append never joins a half-written one (when even that fails,
//! the file gets no more appends). A spill writes a temp file that the sync thread publishes;
//! a temp file whose write failed is removed at once. Nothing here claims a message is on disk
//! before the write of its line returned.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use super::sync::Job;

/// Whether `name` is one of the spool's temp files (`<20 digits>.tmp`, a spill a crash cut
/// short: never published, so never counted as on disk).
pub fn is_temp_name(name: &str) -> bool {
    name.strip_suffix(".tmp")
        .is_some_and(|stem| stem.len() == 20 && stem.bytes().all(|b| b.is_ascii_digit()))
}

/// The newest segment file, open for appending.
#[derive(Debug)]
pub struct Appender {
    file: File,
    /// Bytes of whole lines in the file.
    len: u64,
    /// Written since its last sync job.
    dirty: bool,
}

/// An append that failed.
#[derive(Debug)]
pub struct Refused {
    pub error: std::io::Error,
    /// The file is as it was before (cut back); `false`: it may end in a partial line.
    pub intact: bool,
}

impl Appender {
    /// A new segment file at `path` (never an existing file: a name is used once).
    pub fn create(path: &Path) -> std::io::Result<Appender> {
        let file = OpenOptions::new()
            .create_new(true)
            .append(true)
            .open(path)?;
        Ok(Appender {
            file,
            len: 0,
            dirty: false,
        })
    }

    /// Appends whole lines.
    pub fn append(&mut self, lines: &[u8]) -> Result<(), Refused> {
        match self.file.write_all(lines) {
            Ok(()) => {
                self.len += lines.len() as u64;
                self.dirty = true;
                Ok(())
            }
            Err(error) => Err(Refused {
                intact: self.file.set_len(self.len).is_ok(),
                error,
            }),
        }
    }

    /// The job that syncs what was appended since the last one, if anything was.
    pub fn sync_job(&mut self, path: &Path) -> Option<Job> {
        if !std::mem::take(&mut self.dirty) {
            return None;
        }
        match self.file.try_clone() {
            Ok(f) => Some(Job::Sync(f, path.to_path_buf())),
            Err(_) => {
                // No descriptor to spare: sync here rather than not at all.
                let _ = self.file.sync_data();
                None
            }
        }
    }
}

/// Writes `lines` to the temp file of the segment at `path`; the open file and the temp path,
/// for the sync thread to publish. On failure nothing is left behind.
pub fn write_temp(path: &Path, lines: &[u8]) -> std::io::Result<(File, PathBuf)> {
    let tmp = path.with_extension("tmp");
    let written = File::create(&tmp).and_then(|mut f| f.write_all(lines).map(|()| f));
    match written {
        Ok(file) => Ok((file, tmp)),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}
