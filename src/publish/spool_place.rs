//! Where the spool lives: `<state_dir>/spool`, or, when that cannot be used, a fresh private
//! directory made for this run (`mkdtemp`: a new name, created `0700`, never one that already
//! exists). Never a shared, predictable path: a directory someone else made beforehand could
//! hold `*.jsonl` files the gateway would publish under its own credentials, or watch what it
//! spools. The fallback is said loudly (an error in the log, `pulsegate check`, the metric
//! `pulsegate_spool_private_fallback`): what is spooled there is lost at reboot.

use std::ffi::{CString, OsString};
use std::os::unix::ffi::{OsStrExt, OsStringExt};
use std::path::{Path, PathBuf};

use super::spool::{Spool, SpoolError};

/// The spool directory of the output (or connection) `name`: `<state_dir>/spool/<name>`.
pub fn output_dir(state_dir: &Path, name: &str) -> PathBuf {
    state_dir.join("spool").join(name)
}

/// Segments an earlier version left in `<state_dir>/spool` itself (one spool for every format)
/// move into `into`, the spool of the output that now sends what they hold, so nothing spooled
/// before an upgrade is lost. Only the spool's own files (`<20 digits>.jsonl`) are moved;
/// returns how many.
pub fn adopt_legacy(state_dir: &Path, into: &Path) -> std::io::Result<usize> {
    let legacy = state_dir.join("spool");
    let entries = match std::fs::read_dir(&legacy) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut moved = 0;
    for entry in entries {
        let entry = entry?;
        let path = entry.path();
        let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
            continue;
        };
        // A link with a segment's name is not ours: never moved (nor what it points to).
        let regular = entry.file_type().is_ok_and(|t| t.is_file());
        if !super::spool::is_segment_name(name) || !regular {
            continue;
        }
        std::fs::create_dir_all(into)?;
        let target = into.join(name);
        if target.exists() {
            continue; // never over a file of the new layout
        }
        std::fs::rename(&path, &target)?;
        moved += 1;
    }
    if moved > 0 {
        crate::state::sync_dir(into)?;
        crate::state::sync_dir(&legacy)?;
    }
    Ok(moved)
}

/// An opened spool, and the private directory it fell back to, if it did.
pub struct Opened {
    pub spool: Spool,
    pub fallback: Option<PathBuf>,
}

/// Opens the spool in `dir`; when that fails, in a fresh private temporary directory (logged
/// as an error). Blocking: call off the runtime thread.
pub fn open(dir: &Path, max_bytes: u64) -> Result<Opened, SpoolError> {
    let cause = match Spool::open(dir, max_bytes) {
        Ok(spool) => {
            return Ok(Opened {
                spool,
                fallback: None,
            });
        }
        Err(e) => e,
    };
    let private = private_dir(&std::env::temp_dir()).map_err(|e| SpoolError::new(dir, e))?;
    tracing::error!(spool = %private.display(), "{cause}; spooling in a fresh private directory instead: messages spooled there are lost at reboot, and nothing a previous run spooled is sent. Fix the state directory's spool and restart");
    let spool = Spool::open(&private, max_bytes)?;
    Ok(Opened {
        spool,
        fallback: Some(private),
    })
}

/// A new directory under `parent`, `pulsegate-spool-XXXXXX` with a random suffix, created
/// `0700` by `mkdtemp(3)`: it fails rather than take an existing path.
pub fn private_dir(parent: &Path) -> std::io::Result<PathBuf> {
    let template = parent.join("pulsegate-spool-XXXXXX");
    let mut bytes = CString::new(template.as_os_str().as_bytes())
        .map_err(|_| std::io::Error::other("temporary directory path contains NUL"))?
        .into_bytes_with_nul();
    // SAFETY: a NUL-terminated buffer this function owns; mkdtemp rewrites the X's in place.
    let made = unsafe { libc::mkdtemp(bytes.as_mut_ptr().cast()) };
    if made.is_null() {
        return Err(std::io::Error::last_os_error());
    }
    bytes.pop(); // the NUL
    Ok(PathBuf::from(OsString::from_vec(bytes)))
}

/// Whether the gateway (this user) can keep its spool in `dir`, checked without creating
/// anything (for `pulsegate check`): the directory, or the nearest existing one above it, must
/// be a writable directory.
pub fn usable(dir: &Path) -> Result<(), String> {
    let mut at = dir;
    loop {
        match std::fs::metadata(at) {
            Ok(m) if !m.is_dir() => return Err(format!("{} is not a directory", at.display())),
            Ok(_) => break,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => match at.parent() {
                Some(p) if !p.as_os_str().is_empty() => at = p,
                _ => break,
            },
            Err(e) => return Err(format!("{}: {e}", at.display())),
        }
    }
    let c = CString::new(at.as_os_str().as_bytes()).map_err(|_| "path contains NUL")?;
    // SAFETY: access(2) on a NUL-terminated path this function owns.
    if unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) } != 0 {
        let e = std::io::Error::last_os_error();
        return Err(format!("{}: {e}", at.display()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pulsegate-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_private_directory_is_new_each_time_and_only_its_owner_may_enter() {
        use std::os::unix::fs::PermissionsExt;
        let parent = scratch("private-dirs");
        let a = private_dir(&parent).unwrap();
        let b = private_dir(&parent).unwrap();
        assert_ne!(a, b);
        assert!(a.starts_with(&parent));
        let mode = std::fs::metadata(&a).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o700);
        let _ = std::fs::remove_dir_all(&parent);
    }

    #[test]
    fn an_unusable_spool_directory_falls_back_to_a_fresh_one_and_publishes_nothing_planted() {
        let state = scratch("spool-fallback");
        // The spool's place is a file: it cannot be made a directory.
        std::fs::write(state.join("spool"), "").unwrap();
        // A directory at the old, predictable fallback path with a planted segment.
        let planted = std::env::temp_dir().join(format!("pulsegate-spool-{}", std::process::id()));
        std::fs::create_dir_all(&planted).unwrap();
        let entry = crate::outbox::Entry {
            seq: 1,
            topic: "pulsegate/edge-01/status".into(),
            payload: bytes::Bytes::from_static(b"offline"),
            qos: 1,
            retain: true,
            correlation: None,
        };
        let line = serde_json::to_string(&entry).unwrap();
        std::fs::write(
            planted.join("00000000000000000001.jsonl"),
            format!("{line}\n"),
        )
        .unwrap();
        assert_eq!(
            Spool::open(&planted, 1 << 20).unwrap().len(),
            1,
            "a valid segment"
        );
        let opened = open(&state.join("spool"), 1 << 20).unwrap();
        let fallback = opened.fallback.expect("fell back");
        assert_ne!(fallback, planted);
        assert!(opened.spool.is_empty(), "nothing adopted");
        assert!(usable(&state.join("spool")).is_err());
        assert!(usable(&state.join("new/deeper")).is_ok());
        let _ = std::fs::remove_dir_all(&fallback);
        let _ = std::fs::remove_dir_all(&planted);
        let _ = std::fs::remove_dir_all(&state);
    }
}
