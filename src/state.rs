//! Persisted state of one bus: counter state per channel and the register holes its devices
//! refused. One JSON file per bus in `gateway.state_dir`, written atomically (temp file, fsync,
//! rename, fsync of the directory) so a power cut leaves either the old or the new file.

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
}

/// A state file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    #[error("state file {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("state file {path} is not valid state ({source}); starting from empty state")]
    Corrupt {
        path: String,
        source: serde_json::Error,
    },
}

/// Makes a create, rename or delete in `dir` durable: without it a power cut can undo the
/// directory entry even though the file's data was synced.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    std::fs::File::open(dir)?.sync_all()
}

/// The key of a channel's state.
pub fn channel_key(unit: u8, model: &str, channel: &str) -> String {
    format!("{unit}/{model}/{channel}")
}

/// The key of a device's holes.
pub fn device_key(unit: u8, model: &str) -> String {
    format!("{unit}/{model}")
}

/// Where bus `bus` keeps its state.
pub fn bus_path(state_dir: &Path, bus: &str) -> PathBuf {
    state_dir.join(format!("bus-{bus}.json"))
}

impl BusState {
    /// Loads a bus's state; a missing file is empty state.
    pub fn load(path: &Path) -> Result<BusState, StateError> {
        match std::fs::read(path) {
            Ok(bytes) => serde_json::from_slice(&bytes).map_err(|source| StateError::Corrupt {
                path: path.display().to_string(),
                source,
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(BusState::default()),
            Err(source) => Err(StateError::Io {
                path: path.display().to_string(),
                source,
            }),
        }
    }

    /// Writes atomically: a reader (or a restart after power loss) sees old or new, never half.
    pub fn save(&self, path: &Path) -> Result<(), StateError> {
        let io = |source| StateError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut this = self.clone();
        this.version = VERSION;
        let bytes = serde_json::to_vec_pretty(&this).expect("state serializes");
        let dir = path.parent().unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(io)?;
        let tmp = path.with_extension("json.tmp");
        {
            let mut f = std::fs::File::create(&tmp).map_err(io)?;
            f.write_all(&bytes).map_err(io)?;
            f.sync_all().map_err(io)?;
        }
        std::fs::rename(&tmp, path).map_err(io)?;
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
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

    #[test]
    fn a_corrupt_file_is_an_error_naming_the_file() {
        let path =
            std::env::temp_dir().join(format!("pulsegate-corrupt-{}.json", std::process::id()));
        std::fs::write(&path, b"{not json").unwrap();
        let err = BusState::load(&path).unwrap_err().to_string();
        assert!(err.contains(&path.display().to_string()), "{err}");
        std::fs::remove_file(&path).unwrap();
    }
}
