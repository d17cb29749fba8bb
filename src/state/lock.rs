//! The running gateway's claim on its state directory: an advisory `flock` on
//! `<state_dir>/pulsegate.lock`, held for the whole run. `pulsegate state prune --apply` takes
//! the same lock first and refuses while a gateway holds it (the gateway rewrites its state files
//! at every flush and would undo the prune, or the prune its counts). The kernel drops the lock
//! when the process ends, however it ends: no stale lock after a crash.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};

/// The lock file's name in the state directory.
pub const LOCK_FILE: &str = "pulsegate.lock";

/// The state directory could not be claimed.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error(
        "another process holds {path} (a running pulsegate on this state directory): stop it first"
    )]
    Held { path: String },
    #[error("state directory lock {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
}

/// A held claim on a state directory; released when dropped (or when the process ends).
#[derive(Debug)]
pub struct StateLock {
    _file: File,
    path: PathBuf,
}

impl StateLock {
    /// Claims `state_dir` (created if missing) without waiting: `Held` when another process
    /// has it.
    pub fn take(state_dir: &Path) -> Result<StateLock, LockError> {
        let path = state_dir.join(LOCK_FILE);
        let io = |source| LockError::Io {
            path: path.display().to_string(),
            source,
        };
        std::fs::create_dir_all(state_dir).map_err(io)?;
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .map_err(io)?;
        // SAFETY: flock on a file descriptor this function owns, open for the call.
        let r = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
        if r != 0 {
            let e = std::io::Error::last_os_error();
            return Err(if e.raw_os_error() == Some(libc::EWOULDBLOCK) {
                LockError::Held {
                    path: path.display().to_string(),
                }
            } else {
                io(e)
            });
        }
        Ok(StateLock { _file: file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_claim_is_refused_while_the_first_is_held_and_taken_after_it_is_dropped() {
        let dir = std::env::temp_dir().join(format!("pulsegate-lock-{}", std::process::id()));
        let first = StateLock::take(&dir).unwrap();
        // flock locks belong to the open file description: a second open in this process is
        // refused as another process's would be.
        assert!(matches!(StateLock::take(&dir), Err(LockError::Held { .. })));
        assert!(first.path().ends_with(LOCK_FILE));
        drop(first);
        assert!(StateLock::take(&dir).is_ok());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
