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
