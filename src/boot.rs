//! This run of the gateway: a random boot id, and the previous run's, kept in
//! `<state_dir>/boot.json`. The gateway publishes its boot id retained on `<root>/gateway` at
//! every connection; a boot id there that is neither this run's nor the previous run's means a
//! second gateway publishes under the same topic root (and, with the default client id, fights
//! over the same MQTT session): it is logged loudly.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The boot ids of this run and the run before.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Boot {
    pub id: String,
    #[serde(default)]
    pub previous: Option<String>,
}

fn random_id() -> String {
    let mut bytes = [0u8; 8];
    if let Ok(mut f) = std::fs::File::open("/dev/urandom") {
        let _ = std::io::Read::read_exact(&mut f, &mut bytes);
    }
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    let mixed = u64::from_le_bytes(bytes) ^ nanos ^ u64::from(std::process::id()).rotate_left(32);
    format!("{mixed:016x}")
}

fn path(state_dir: &Path) -> PathBuf {
    state_dir.join("boot.json")
}

impl Boot {
    /// A new boot id; the one found in `state_dir` becomes the previous. Written (and the
    /// directory synced) before anything is published. Blocking: call off the runtime thread.
    pub fn start(state_dir: &Path) -> Boot {
        let previous = std::fs::read(path(state_dir))
            .ok()
            .and_then(|b| serde_json::from_slice::<Boot>(&b).ok())
            .map(|b| b.id);
        let boot = Boot {
            id: random_id(),
            previous,
        };
        if let Err(e) = boot.save(state_dir) {
            tracing::warn!(
                "cannot record the boot id in {}: {e}",
                path(state_dir).display()
            );
        }
        boot
    }

    fn save(&self, state_dir: &Path) -> std::io::Result<()> {
        std::fs::create_dir_all(state_dir)?;
        let tmp = state_dir.join("boot.json.tmp");
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(&serde_json::to_vec(self).expect("boot serializes"))?;
        f.sync_all()?;
        std::fs::rename(&tmp, path(state_dir))?;
        crate::state::sync_dir(state_dir)
    }

    /// The retained marker this run publishes on `<root>/gateway`, with the hash of the config
    /// in force (`Config::hash`).
    pub fn marker(&self, client_id: &str, config: &str) -> String {
        serde_json::json!({
            "boot": self.id,
            "host": crate::config::host_name_raw(),
            "pid": std::process::id(),
            "client_id": client_id,
            "config": config,
            "version": env!("CARGO_PKG_VERSION"),
        })
        .to_string()
    }

    /// Whether a marker found on `<root>/gateway` comes from another gateway: a boot id that is
    /// neither ours nor our previous run's. `None` when it is ours (or empty: cleared).
    pub fn foreign(&self, marker: &[u8]) -> Option<serde_json::Value> {
        let v: serde_json::Value = serde_json::from_slice(marker).ok()?;
        let boot = v.get("boot")?.as_str()?;
        (boot != self.id && Some(boot) != self.previous.as_deref()).then_some(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_marker_of_this_run_or_the_last_is_ours_and_any_other_is_foreign() {
        let b = Boot {
            id: "aaaa".into(),
            previous: Some("bbbb".into()),
        };
        assert!(b.foreign(br#"{"boot":"aaaa"}"#).is_none());
        assert!(b.foreign(br#"{"boot":"bbbb"}"#).is_none());
        assert!(b.foreign(br#"{"boot":"cccc","host":"edge-2"}"#).is_some());
        assert!(b.foreign(b"").is_none(), "a cleared marker");
    }

    #[test]
    fn each_start_gets_a_new_id_and_remembers_the_last() {
        let dir = std::env::temp_dir().join(format!("pulsegate-boot-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let first = Boot::start(&dir);
        let second = Boot::start(&dir);
        assert_ne!(first.id, second.id);
        assert_eq!(second.previous.as_deref(), Some(first.id.as_str()));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
