//! The birth/death sequence number, kept in the state directory: each MQTT session takes the
//! next one (0..255), so a host can match the NDEATH the broker sends for a killed gateway to
//! its NBIRTH, and tell the births of a restart from those of the run before.

use std::path::{Path, PathBuf};

/// The file under the state directory (of the output named `sparkplug`, as `mqtt.format`
/// names it; another output's is `sparkplug-bdseq.<name>`).
pub const FILE: &str = "sparkplug-bdseq";

/// The file of the output `output`.
pub fn file(output: &str) -> String {
    if output == "sparkplug" {
        FILE.to_string()
    } else {
        format!("{FILE}.{output}")
    }
}

/// The bdSeq of the next session, persisted.
#[derive(Debug)]
pub struct BdSeq {
    path: PathBuf,
    next: u8,
    /// Failures to save, logged once a minute.
    log: crate::log_budget::LogBudget,
}

impl BdSeq {
    /// Reads the next bdSeq of `output` from its file under `state_dir` ([`file`]); 0 when
    /// there is none yet, or (logged) when the file is unreadable or not a number 0..255.
    pub fn load(state_dir: &Path, output: &str) -> BdSeq {
        let path = state_dir.join(file(output));
        let next = match std::fs::read_to_string(&path) {
            Ok(text) => text.trim().parse::<u8>().unwrap_or_else(|_| {
                tracing::warn!(file = %path.display(), "Sparkplug bdSeq file is not a number 0..255: starting at 0");
                0
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => 0,
            Err(e) => {
                tracing::warn!(file = %path.display(), "cannot read the Sparkplug bdSeq: {e}; starting at 0");
                0
            }
        };
        BdSeq {
            path,
            next,
            log: crate::log_budget::LogBudget::new(1),
        }
    }

    /// The bdSeq of a new session; the one after it is written down first (atomically), so a
    /// crash at any point never gives two sessions the same number.
    pub fn take(&mut self) -> u8 {
        let this = self.next;
        self.next = this.wrapping_add(1);
        if let Err(e) = self.save() {
            // Each connection attempt takes one: said at most once a minute (a full disk).
            let (log, suppressed) = self.log.allow(tokio::time::Instant::now());
            if log {
                let more = suppressed
                    .map(|n| format!(" ({n} more not logged)"))
                    .unwrap_or_default();
                tracing::error!(file = %self.path.display(), "cannot save the Sparkplug bdSeq: {e}; a restart may repeat bdSeq {this}{more}");
            }
        }
        this
    }

    fn save(&self) -> std::io::Result<()> {
        let tmp = self.path.with_extension("tmp");
        crate::state::write_atomic(&self.path, &tmp, format!("{}\n", self.next).as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pg-bdseq-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn each_session_takes_the_next_number_across_restarts_and_wraps_after_255() {
        let d = dir("restart");
        let mut b = BdSeq::load(&d, "sparkplug");
        assert_eq!((b.take(), b.take()), (0, 1));
        let mut again = BdSeq::load(&d, "sparkplug");
        assert_eq!(again.take(), 2);
        std::fs::write(d.join(FILE), "255\n").unwrap();
        let mut wrap = BdSeq::load(&d, "sparkplug");
        assert_eq!((wrap.take(), wrap.take()), (255, 0));
    }

    #[test]
    fn a_garbled_file_starts_again_at_zero() {
        let d = dir("garbled");
        std::fs::write(d.join(FILE), "9000").unwrap();
        assert_eq!(BdSeq::load(&d, "sparkplug").take(), 0);
    }
}
