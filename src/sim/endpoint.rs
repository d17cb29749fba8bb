//! Where the gateway reaches a simulated bus or segment, and the symlink a serial one may
//! have.

use std::net::SocketAddr;
use std::path::PathBuf;

/// Where a simulated bus can be reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A pseudo-terminal: open this path as a serial port.
    Serial(PathBuf),
    Tcp(SocketAddr),
}

/// Points `link` at `target`, replacing what was there.
pub fn relink(target: &std::path::Path, link: &std::path::Path) -> std::io::Result<()> {
    let _ = std::fs::remove_file(link);
    if let Some(dir) = link.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::os::unix::fs::symlink(target, link)
}

/// Marks a descriptor close-on-exec: a pseudo-terminal end inherited by a child process (the
/// gateway started by a test) would keep the line up after the simulator drops it.
pub fn private(port: serialport::TTYPort) -> serialport::TTYPort {
    use std::os::fd::AsRawFd;
    // SAFETY: F_SETFD on a descriptor `port` owns and keeps open; no memory is passed.
    let _ = unsafe { libc::fcntl(port.as_raw_fd(), libc::F_SETFD, libc::FD_CLOEXEC) };
    port
}
