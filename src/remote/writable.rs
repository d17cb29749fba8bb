//! Whether a gateway that takes pushed configs can write them: the config file and its
//! directory (a push is written beside the file and renamed over it) must be writable by the
//! user the gateway runs as. `pulsegate check` warns before the first push is refused with
//! `write_failed`.

use std::path::Path;

use crate::config::Config;

/// Why pushes could not be written by this user, when `[remote] config = true`.
pub fn problem(config: &Config) -> Option<String> {
    if !config.remote.config {
        return None;
    }
    let file = &config.source;
    let dir = match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let refused: Vec<String> = [file.as_path(), dir]
        .into_iter()
        .filter(|p| !writable(p))
        .map(|p| p.display().to_string())
        .collect();
    if refused.is_empty() {
        return None;
    }
    // SAFETY: getuid has no preconditions and cannot fail.
    let uid = unsafe { libc::getuid() };
    Some(format!(
        "[remote] config = true, but {} not writable by this user (uid {uid}): every push would be refused (write_failed). Run check as the service's user; under the shipped unit keep a pushed config in /var/lib/pulsegate/remote/ (docs/operations.md)",
        refused.join(" and ") + if refused.len() > 1 { " are" } else { " is" }
    ))
}

fn writable(path: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt as _;
    let Ok(c) = std::ffi::CString::new(path.as_os_str().as_bytes()) else {
        return false;
    };
    // SAFETY: `c` is a valid NUL-terminated path for the duration of the call.
    unsafe { libc::access(c.as_ptr(), libc::W_OK) == 0 }
}
