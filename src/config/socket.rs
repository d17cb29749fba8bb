//! `mqtt.socket`: the path of a local broker's Unix domain socket (Mosquitto's
//! `listener 0 /run/mosquitto/mqtt.sock`), checked before any I/O.
//!
//! The socket need not exist when the config is checked: the broker may start after the
//! gateway, which then spools until it can connect (as with a TCP broker that is down).

use std::os::unix::ffi::OsStrExt;
use std::path::PathBuf;

use super::walk::{Errors, Table, join};

/// Longest socket path in bytes: Linux's `sun_path` is 108 bytes and ends with a NUL.
pub const MAX_SOCKET_PATH: usize = 107;

/// `mqtt.socket`, or `None` when unset or refused (the error is in `errs`).
pub(crate) fn mqtt_socket(t: &mut Table<'_>, errs: &mut Errors) -> Option<PathBuf> {
    // The value's own origin: an override from the environment is named as such.
    let origin = t.raw("socket").and_then(|v| v.origin()).map(str::to_string);
    let path = t.opt::<PathBuf>("socket", errs)?;
    let key = join(&t.path, "socket");
    let problem = if t.has("tls") {
        // rumqttc cannot put TLS on a Unix socket; connecting without it would silently drop
        // a security setting the user asked for, so the config is refused instead.
        Some(format!(
            "{key} and {}.tls cannot be set together: TLS is not used over a local Unix socket \
             (filesystem permissions guard it); remove one of them",
            t.path
        ))
    } else {
        socket_path_problem(&path).map(|why| format!("{}: {why}", path.display()))
    };
    match problem {
        Some(why) => {
            errs.push(&key, origin.as_deref().or(t.origin()), why);
            None
        }
        None => Some(path),
    }
}

/// Why `path` cannot name a Unix socket, or `None` when it can.
pub fn socket_path_problem(path: &std::path::Path) -> Option<String> {
    let bytes = path.as_os_str().as_bytes();
    if bytes.contains(&0) {
        return Some("contains a NUL byte".into());
    }
    if path.to_str().is_none() {
        // rumqttc takes the broker address as a String: a lossy copy would name another file.
        return Some("is not valid UTF-8".into());
    }
    if !path.is_absolute() {
        // Relative to what: the service's working directory is not the config's folder.
        return Some("must be an absolute path (like /run/mosquitto/mqtt.sock)".into());
    }
    if bytes.len() > MAX_SOCKET_PATH {
        return Some(format!(
            "is {} bytes long; a Unix socket path holds at most {MAX_SOCKET_PATH} (Linux's \
             sun_path is 108 bytes with its closing NUL): use a shorter path",
            bytes.len()
        ));
    }
    None
}
