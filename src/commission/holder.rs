//! Who else has a serial port open: a running gateway holds its port exclusively, and a second
//! program on the same adapter would garble every frame. Found by scanning `/proc/*/fd`.

use std::os::unix::fs::MetadataExt;
use std::path::Path;

/// A process that has the port open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    pub pid: u32,
    /// Its command line, arguments joined by spaces.
    pub command: String,
}

impl Holder {
    /// A pulsegate gateway (`pulsegate run`), as opposed to any other program.
    pub fn is_gateway(&self) -> bool {
        let mut words = self.command.split(' ');
        let exe = words.next().unwrap_or_default();
        exe.rsplit('/')
            .next()
            .is_some_and(|n| n.starts_with("pulsegate"))
            && words.any(|w| w == "run")
    }
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "process {} ({})", self.pid, self.command)
    }
}

/// Processes other than this one with `port` open (the same device, whatever path they used).
/// Without root, other users' processes cannot be seen.
pub fn holders(port: &Path) -> Vec<Holder> {
    let Ok(meta) = std::fs::metadata(port) else {
        return Vec::new();
    };
    let device = meta.rdev();
    if device == 0 {
        return Vec::new();
    }
    let me = std::process::id();
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for entry in procs.flatten() {
        let Some(pid) = entry
            .file_name()
            .to_str()
            .and_then(|s| s.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == me {
            continue;
        }
        let Ok(fds) = std::fs::read_dir(entry.path().join("fd")) else {
            continue;
        };
        let holds = fds.flatten().any(|fd| {
            std::fs::metadata(fd.path()).is_ok_and(|m| m.rdev() == device && m.file_type_is_char())
        });
        if holds {
            let command = std::fs::read(entry.path().join("cmdline"))
                .map(|b| {
                    String::from_utf8_lossy(&b)
                        .split('\0')
                        .filter(|s| !s.is_empty())
                        .collect::<Vec<_>>()
                        .join(" ")
                })
                .unwrap_or_default();
            out.push(Holder { pid, command });
        }
    }
    out
}

trait CharDevice {
    fn file_type_is_char(&self) -> bool;
}

impl CharDevice for std::fs::Metadata {
    fn file_type_is_char(&self) -> bool {
        use std::os::unix::fs::FileTypeExt;
        self.file_type().is_char_device()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gateway_is_pulsegate_run_whatever_its_path() {
        let h = |c: &str| Holder {
            pid: 1,
            command: c.into(),
        };
        assert!(h("/usr/bin/pulsegate run --config /etc/pulsegate/pulsegate.toml").is_gateway());
        assert!(!h("pulsegate scan --port /dev/ttyUSB0").is_gateway());
        assert!(!h("minicom -D /dev/ttyUSB0 run").is_gateway());
    }

    #[test]
    fn this_process_holding_a_pty_is_not_reported_but_another_is() {
        let (_master, slave) = serialport::TTYPort::pair().unwrap();
        use serialport::SerialPort;
        let path = std::path::PathBuf::from(slave.name().unwrap());
        assert!(holders(&path).iter().all(|h| h.pid != std::process::id()));
        let mut child = std::process::Command::new("sleep")
            .arg("5")
            .stdin(std::fs::File::open(&path).unwrap())
            .spawn()
            .unwrap();
        // Between fork and exec the child (or a child another test thread forks at that
        // moment) holds the port under an empty or foreign command line: look again until
        // the exec is seen.
        let mut found = holders(&path);
        for _ in 0..100 {
            if found
                .iter()
                .any(|h| h.pid == child.id() && h.command.starts_with("sleep"))
            {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
            found = holders(&path);
        }
        let _ = child.kill();
        let _ = child.wait();
        assert!(
            found
                .iter()
                .any(|h| h.pid == child.id() && h.command.starts_with("sleep")),
            "{found:?}"
        );
    }
}
