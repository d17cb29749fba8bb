//! Persisted state of one bus: counter state per channel and the register holes its devices
//! refused. One JSON file per bus in `gateway.state_dir`, written atomically (temp file, fsync,
//! rename, fsync of the directory) so a power cut leaves either the old or the new file.
//!
//! A file that cannot be read, does not parse, or was written by a newer version is never
//! overwritten: it is moved aside (`bus-<name>.json.bad-<unix time>`) and the bus refuses to
//! start from zero on its own guess. The operator restores it or deletes the moved-aside file.

pub mod lock;
pub mod prune;

use std::collections::BTreeMap;
use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::counter::CounterState;

/// State file format version.
const VERSION: u32 = 1;

/// Saved state of a bus.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BusState {
    #[serde(default)]
    pub version: u32,
    /// Keyed by [`channel_key`]: unit, model and channel, so state is never attached to a
    /// different meter after the config changes.
    #[serde(default)]
    pub channels: BTreeMap<String, CounterState>,
    /// Register ranges each unit refused (exception 02), keyed by `unit/model`.
    #[serde(default)]
    pub holes: BTreeMap<String, Vec<(u16, u16)>>,
    /// Written at a clean shutdown, after the last reading was published: seq can go on from
    /// here. Any other save may be followed by readings the crash did not let us save.
    #[serde(default)]
    pub clean: bool,
}

/// A state file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    #[error(
        "save put off: the readings before it are not durable yet (neither acknowledged by the MQTT broker nor synced in the spool)"
    )]
    NotDurable,
    #[error("state file {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("state file {path} is not valid state ({source})")]
    Corrupt {
        path: String,
        source: serde_json::Error,
    },
    #[error(
        "state file {path} was written by a newer pulsegate (format {found}, this one reads up to {VERSION})"
    )]
    Newer { path: String, found: u32 },
    #[error(
        "{cause}; it was moved aside to {moved} (never overwritten). This bus does not start from zero totals on its own: restore the file as {path}, or delete {moved} to start from zero, then restart"
    )]
    MovedAside {
        cause: Box<StateError>,
        path: String,
        moved: String,
    },
    #[error(
        "{cause}; it could not be moved aside ({rename}). This bus does not start: fix or remove the file, then restart"
    )]
    Stuck {
        cause: Box<StateError>,
        rename: std::io::Error,
    },
    #[error(
        "an earlier state file of this bus was moved aside to {moved}. This bus does not start from zero totals on its own: restore it as {path}, or delete {moved} to start from zero, then restart"
    )]
    Quarantined { path: String, moved: String },
}

/// Makes a create, rename or delete in `dir` durable: without it a power cut can undo the
/// directory entry even though the file's data was synced.
/// Writes `bytes` to `path` so that a crash leaves the old file or the new one, never half of
/// one: into `tmp` (synced), renamed over `path`, the directory synced. The one way the
/// gateway replaces a small file (state, boot id, Sparkplug's bdSeq). A failed write (a full
/// disk) leaves no temporary file behind.
pub fn write_atomic(path: &Path, tmp: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let written = std::fs::File::create(tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|()| std::fs::rename(tmp, path)) {
        let _ = std::fs::remove_file(tmp);
        return Err(e);
    }
    sync_dir(dir)
}

pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    std::fs::File::open(dir)?.sync_all()
}

/// The key of a channel's state.
pub fn channel_key(unit: impl std::fmt::Display, model: &str, channel: &str) -> String {
    format!("{unit}/{model}/{channel}")
}

/// The key of a device's holes.
pub fn device_key(unit: impl std::fmt::Display, model: &str) -> String {
    format!("{unit}/{model}")
}

/// The unit, model and channel a channel key names (the reverse of [`channel_key`]).
pub fn split_channel_key(key: &str) -> Option<(&str, &str, &str)> {
    let mut parts = key.splitn(3, '/');
    Some((parts.next()?, parts.next()?, parts.next()?))
}

/// Whether channel key `key` is a channel of the device `unit`/`model`.
pub fn is_channel_of(key: &str, unit: impl std::fmt::Display, model: &str) -> bool {
    split_channel_key(key).is_some_and(|(u, m, _)| u == unit.to_string() && m == model)
}

/// Where bus `bus` keeps its state.
pub fn bus_path(state_dir: &Path, bus: &str) -> PathBuf {
    state_dir.join(format!("bus-{bus}.json"))
}

/// Files a bad state file at `path` was moved aside to, oldest first.
fn moved_aside(path: &Path) -> Vec<PathBuf> {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
        return Vec::new();
    };
    let prefix = format!("{}.bad-", name.to_string_lossy());
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| {
                    p.file_name()
                        .is_some_and(|n| n.to_string_lossy().starts_with(&prefix))
                })
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    found
}

impl BusState {
    /// Reads and checks a bus's state file; a missing file is empty state.
    fn read(path: &Path) -> Result<BusState, StateError> {
        let shown = || path.display().to_string();
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(BusState::default()),
            Err(source) => {
                return Err(StateError::Io {
                    path: shown(),
                    source,
                });
            }
        };
        // The version first: a newer format may not parse, and must say so, not "corrupt".
        #[derive(Deserialize)]
        struct Version {
            #[serde(default)]
            version: u32,
        }
        if let Ok(v) = serde_json::from_slice::<Version>(&bytes)
            && v.version > VERSION
        {
            return Err(StateError::Newer {
                path: shown(),
                found: v.version,
            });
        }
        serde_json::from_slice(&bytes).map_err(|source| StateError::Corrupt {
            path: shown(),
            source,
        })
    }

    /// Loads a bus's state. A file that cannot be read, parsed, or is of a newer format is moved
    /// aside and the error says where; an earlier moved-aside file with no state file in its
    /// place is an error too, until the operator decides. Blocking: call off the runtime thread.
    pub fn load(path: &Path) -> Result<BusState, StateError> {
        match Self::read(path) {
            Ok(s) if path.exists() => Ok(s),
            Ok(s) => match moved_aside(path).pop() {
                Some(moved) => Err(StateError::Quarantined {
                    path: path.display().to_string(),
                    moved: moved.display().to_string(),
                }),
                None => Ok(s),
            },
            Err(cause) => {
                let stamp = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map(|d| d.as_secs())
                    .unwrap_or(0);
                let mut moved = PathBuf::from(format!("{}.bad-{stamp}", path.display()));
                let mut n = 1;
                while moved.exists() {
                    moved = PathBuf::from(format!("{}.bad-{stamp}-{n}", path.display()));
                    n += 1;
                }
                match std::fs::rename(path, &moved) {
                    Ok(()) => {
                        if let Some(dir) = path.parent() {
                            let _ = sync_dir(dir);
                        }
                        Err(StateError::MovedAside {
                            cause: Box::new(cause),
                            path: path.display().to_string(),
                            moved: moved.display().to_string(),
                        })
                    }
                    Err(rename) => Err(StateError::Stuck {
                        cause: Box::new(cause),
                        rename,
                    }),
                }
            }
        }
    }

    /// Reads a bus's state and changes nothing, whatever the file holds: for the operator's
    /// tools (`pulsegate state list`), which must never move a file the gateway then misses.
    /// Blocking.
    pub fn inspect(path: &Path) -> Result<BusState, StateError> {
        Self::read(path)
    }

    /// Writes atomically: a reader (or a restart after power loss) sees old or new, never half.
    pub fn save(&self, path: &Path) -> Result<(), StateError> {
        self.save_via(path, &path.with_extension("json.tmp"))
    }

    /// As [`BusState::save`], through a temporary file of the operator's tool's own
    /// (`bus-<name>.json.tool-<pid>.tmp`), never the gateway's.
    pub fn save_from_tool(&self, path: &Path) -> Result<(), StateError> {
        let tmp = format!("json.tool-{}.tmp", std::process::id());
        self.save_via(path, &path.with_extension(tmp))
    }

    fn save_via(&self, path: &Path, tmp: &Path) -> Result<(), StateError> {
        let io = |source| StateError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut this = self.clone();
        this.version = VERSION;
        let bytes = serde_json::to_vec_pretty(&this).expect("state serializes");
        write_atomic(path, tmp, &bytes).map_err(io)
    }

    /// Holes of a device as ranges.
    pub fn holes_of(&self, key: &str) -> Vec<Range<u16>> {
        self.holes
            .get(key)
            .map(|v| v.iter().map(|&(a, b)| a..b).collect())
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_operators_tool_never_writes_through_the_gateways_temporary_file() {
        let dir = std::env::temp_dir().join(format!("pulsegate-state-tool-{}", std::process::id()));
        let path = bus_path(&dir, "line1");
        std::fs::create_dir_all(&dir).unwrap();
        let gateways = path.with_extension("json.tmp");
        std::fs::write(&gateways, "the gateway's, half written").unwrap();
        BusState::default().save_from_tool(&path).unwrap();
        assert_eq!(
            std::fs::read_to_string(&gateways).unwrap(),
            "the gateway's, half written"
        );
        assert!(BusState::inspect(&path).is_ok());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn state_survives_a_save_and_load() {
        let dir = std::env::temp_dir().join(format!("pulsegate-state-{}", std::process::id()));
        let path = bus_path(&dir, "line1");
        let mut s = BusState::default();
        s.channels.insert(
            channel_key(1, "yl67", "enc0"),
            CounterState {
                count: Some(-13680),
                at_ms: 5,
                total: 42,
                seq: 7,
                ..CounterState::default()
            },
        );
        s.holes.insert(device_key(1, "yl67"), vec![(24, 32)]);
        s.save(&path).unwrap();
        let back = BusState::load(&path).unwrap();
        assert_eq!(back.channels, s.channels);
        assert_eq!(back.holes_of("1/yl67"), vec![24..32]);
        assert!(!path.with_extension("json.tmp").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_missing_file_is_empty_state() {
        let s = BusState::load(Path::new("/nonexistent/pulsegate/bus-x.json")).unwrap();
        assert!(s.channels.is_empty());
    }

    fn fresh_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pulsegate-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_corrupt_file_is_moved_aside_and_stays_an_error_until_someone_decides() {
        let dir = fresh_dir("corrupt");
        let path = bus_path(&dir, "line1");
        std::fs::write(&path, b"{not json").unwrap();
        let err = BusState::load(&path).unwrap_err().to_string();
        assert!(err.contains(&path.display().to_string()), "{err}");
        assert!(err.contains("moved aside"), "{err}");
        assert!(!path.exists());
        let moved = moved_aside(&path);
        assert_eq!(moved.len(), 1);
        assert_eq!(
            std::fs::read(&moved[0]).unwrap(),
            b"{not json",
            "kept as it was"
        );
        // The next start still refuses to begin from zero…
        assert!(matches!(
            BusState::load(&path),
            Err(StateError::Quarantined { .. })
        ));
        // …until the moved-aside file is removed (or the state restored).
        std::fs::remove_file(&moved[0]).unwrap();
        assert!(BusState::load(&path).unwrap().channels.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_of_a_newer_version_is_not_read_and_not_overwritten() {
        let dir = fresh_dir("newer");
        let path = bus_path(&dir, "line1");
        std::fs::write(&path, br#"{"version":99,"channels":{"x":"new shape"}}"#).unwrap();
        let err = BusState::load(&path).unwrap_err().to_string();
        assert!(err.contains("newer pulsegate (format 99"), "{err}");
        assert_eq!(moved_aside(&path).len(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
