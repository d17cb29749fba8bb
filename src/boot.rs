//! This run of the gateway: a random boot id, and the previous run's, kept in
//! `<state_dir>/boot.json`. The gateway publishes its boot id retained on `<root>/gateway` at
//! every connection (with its host, process id and client id); a marker there that is neither
//! this run's nor the previous run's means a second gateway publishes under the same topic root
//! (and, with the default client id, fights over the same MQTT session): it is logged loudly.
//!
//! Without a trustworthy previous boot id (`boot.json` missing after a wiped or restored state
//! directory, unreadable, or not written by the last run because the disk was full or read-only)
//! a marker from this host whose process is gone, or is this one, is this machine's previous
//! run, not a second gateway: that is said as what it is, never as the alarm.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The boot ids of this run and the run before.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Boot {
    pub id: String,
    #[serde(default)]
    pub previous: Option<String>,
    /// The public key that signs this run's records (base64 of its 32 bytes), said in the
    /// marker so that anyone can check them; not kept in `boot.json`.
    #[serde(skip)]
    pub signing_key: Option<String>,
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

/// What a boot marker found on `<root>/gateway` is.
#[derive(Debug, Clone, PartialEq)]
pub enum Marker {
    /// This run's, the previous run's (by boot id), or cleared.
    Ours,
    /// A boot id this run does not know, from this host and a process that is no longer running
    /// (or is this one): this machine's previous run, which `boot.json` did not record.
    EarlierRun(serde_json::Value),
    /// Another gateway: another host, a live other process, or a marker that does not say.
    Foreign(serde_json::Value),
}

impl Boot {
    /// A new boot id; the one found in `state_dir` becomes the previous. Written (and the
    /// directory synced) before anything is published. What is missing or cannot be read or
    /// written is said as what it means. Blocking: call off the runtime thread.
    pub fn start(state_dir: &Path) -> Boot {
        let file = path(state_dir);
        let boot = Boot {
            id: random_id(),
            previous: previous(&file),
            signing_key: None,
        };
        if let Err(e) = boot.save(state_dir) {
            tracing::warn!(
                file = %file.display(),
                "cannot write {}: {e}; the next start cannot tell this run's boot marker by its id, and recognises it by this host and its process id instead (a live second gateway under the same topic root is still reported)",
                file.display()
            );
        }
        boot
    }

    fn save(&self, state_dir: &Path) -> std::io::Result<()> {
        let bytes = serde_json::to_vec(self).expect("boot serializes");
        crate::state::write_atomic(&path(state_dir), &state_dir.join("boot.json.tmp"), &bytes)
    }

    /// The retained marker this run publishes on `<root>/gateway`, with the hash of the config
    /// in force (`Config::hash`).
    pub fn marker(&self, client_id: &str, config: &str) -> String {
        let mut marker = serde_json::json!({
            "boot": self.id,
            "host": crate::config::host_name_raw(),
            "pid": std::process::id(),
            "client_id": client_id,
            "config": config,
            "version": env!("CARGO_PKG_VERSION"),
        });
        if let Some(key) = &self.signing_key {
            marker["signing_key"] = key.as_str().into();
        }
        marker.to_string()
    }

    /// What a marker found on `<root>/gateway` is.
    pub fn judge(&self, marker: &[u8]) -> Marker {
        let host = crate::config::host_name_raw();
        self.judge_on(marker, &host, std::process::id(), gateway_running)
    }

    /// [`Boot::judge`] on `host` as process `pid`, with `running` telling whether a process of
    /// this gateway runs under a pid.
    fn judge_on(&self, marker: &[u8], host: &str, pid: u32, running: fn(u32) -> bool) -> Marker {
        let Ok(v) = serde_json::from_slice::<serde_json::Value>(marker) else {
            return Marker::Ours; // cleared (empty), or not a marker at all
        };
        let Some(boot) = v.get("boot").and_then(|b| b.as_str()) else {
            return Marker::Ours;
        };
        if boot == self.id || Some(boot) == self.previous.as_deref() {
            return Marker::Ours;
        }
        let same_host = !host.is_empty() && v.get("host").and_then(|h| h.as_str()) == Some(host);
        let their_pid = v.get("pid").and_then(|p| p.as_u64());
        match their_pid.and_then(|p| u32::try_from(p).ok()) {
            Some(p) if same_host && (p == pid || !running(p)) => Marker::EarlierRun(v),
            _ => Marker::Foreign(v),
        }
    }
}

/// The boot id the last run recorded in `file`, if it can be known (said when it cannot).
fn previous(file: &Path) -> Option<String> {
    let why = match std::fs::read(file) {
        Ok(bytes) => match serde_json::from_slice::<Boot>(&bytes) {
            Ok(b) => return Some(b.id),
            Err(e) => format!("is not a boot record ({e})"),
        },
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            tracing::info!(
                file = %file.display(),
                "no {}: a first start, or a state directory wiped or restored; the previous run's boot marker is recognised by this host and its process id instead of its boot id",
                file.display()
            );
            return None;
        }
        Err(e) => format!("cannot be read ({e})"),
    };
    tracing::warn!(
        file = %file.display(),
        "{} {why}: the previous run's boot id is unknown, so its boot marker is recognised by this host and its process id instead",
        file.display()
    );
    None
}

/// Whether a process of this program runs under `pid` (a pid the kernel gave to something else
/// since is not one).
fn gateway_running(pid: u32) -> bool {
    let comm = |p: &str| std::fs::read_to_string(format!("/proc/{p}/comm")).ok();
    match (comm(&pid.to_string()), comm("self")) {
        (Some(theirs), Some(ours)) => theirs == ours,
        (None, Some(_)) => false,
        // No /proc to read: whether anything runs under that pid.
        _ => {
            let Ok(p) = libc::pid_t::try_from(pid) else {
                return false;
            };
            // SAFETY: signal 0 only checks that the process exists; nothing is sent.
            let alive = unsafe { libc::kill(p, 0) } == 0;
            alive || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn boot() -> Boot {
        Boot {
            id: "aaaa".into(),
            previous: Some("bbbb".into()),
            signing_key: None,
        }
    }

    #[test]
    fn the_marker_says_the_public_key_that_signs_records_when_there_is_one() {
        let mut b = boot();
        let plain: serde_json::Value = serde_json::from_str(&b.marker("c", "h")).unwrap();
        assert!(plain.get("signing_key").is_none(), "{plain}");
        b.signing_key = Some("AAAA".into());
        let signed: serde_json::Value = serde_json::from_str(&b.marker("c", "h")).unwrap();
        assert_eq!(signed["signing_key"], "AAAA");
        assert_eq!(signed["boot"], "aaaa");
    }

    fn judge(b: &Boot, marker: &str) -> Marker {
        // This is edge-1, process 100; processes 200 and 300 run, 400 does not.
        b.judge_on(marker.as_bytes(), "edge-1", 100, |p| p == 200 || p == 300)
    }

    #[test]
    fn a_marker_of_this_run_or_the_last_is_ours() {
        let b = boot();
        assert_eq!(judge(&b, r#"{"boot":"aaaa"}"#), Marker::Ours);
        assert_eq!(
            judge(&b, r#"{"boot":"bbbb","host":"edge-2"}"#),
            Marker::Ours
        );
        assert_eq!(judge(&b, ""), Marker::Ours, "a cleared marker");
    }

    #[test]
    fn an_unknown_boot_from_another_host_or_a_live_other_process_is_another_gateway() {
        let b = boot();
        for other in [
            r#"{"boot":"cccc","host":"edge-2","pid":400}"#,
            r#"{"boot":"cccc","host":"edge-1","pid":200}"#,
            r#"{"boot":"cccc"}"#,
            r#"{"boot":"cccc","host":"edge-1"}"#,
        ] {
            assert!(matches!(judge(&b, other), Marker::Foreign(_)), "{other}");
        }
    }

    #[test]
    fn an_unknown_boot_from_this_host_whose_process_is_gone_or_is_us_is_an_earlier_run() {
        let b = Boot {
            id: "aaaa".into(),
            previous: None,
            signing_key: None,
        };
        for earlier in [
            r#"{"boot":"cccc","host":"edge-1","pid":400}"#,
            r#"{"boot":"cccc","host":"edge-1","pid":100}"#,
        ] {
            assert!(
                matches!(judge(&b, earlier), Marker::EarlierRun(_)),
                "{earlier}"
            );
        }
    }

    #[test]
    fn a_start_without_boot_json_or_with_a_broken_one_knows_no_previous_run() {
        let dir = std::env::temp_dir().join(format!("pulsegate-boot-gone-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(Boot::start(&dir).previous, None);
        std::fs::write(dir.join("boot.json"), "not json").unwrap();
        assert_eq!(Boot::start(&dir).previous, None);
        assert!(Boot::start(&dir).previous.is_some(), "written again");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_boot_json_that_cannot_be_written_leaves_no_temp_file() {
        let dir = std::env::temp_dir().join(format!("pulsegate-boot-ro-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("boot.json")).unwrap(); // in the way of the rename
        Boot::start(&dir);
        assert!(!dir.join("boot.json.tmp").exists());
        std::fs::remove_dir_all(&dir).unwrap();
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
