//! `pulsegate state list|prune`: what the state files hold, and which of it matches no
//! configured device. Pure where it can be: files in, a table or a pruned state out.

use std::path::{Path, PathBuf};

use crate::config::Config;
use crate::counter::CounterState;
use crate::state::{BusState, StateError};

/// One saved channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    pub bus: String,
    /// `unit/model/channel`.
    pub key: String,
    pub state: CounterState,
    /// The configured device it belongs to (enabled or not), if any.
    pub device: Option<String>,
}

/// The bus name of a state file `bus-<name>.json`.
fn bus_of(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    Some(
        name.strip_prefix("bus-")?
            .strip_suffix(".json")?
            .to_string(),
    )
}

/// The state files in `dir`, sorted.
pub fn files(dir: &Path) -> Result<Vec<(String, PathBuf)>, StateError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(StateError::Io {
                path: dir.display().to_string(),
                source,
            });
        }
    };
    let mut out: Vec<(String, PathBuf)> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter_map(|p| bus_of(&p).map(|b| (b, p)))
        .collect();
    out.sort();
    Ok(out)
}

/// The configured device (on `bus`) that state `key` belongs to.
pub fn owner(config: &Config, bus: &str, key: &str) -> Option<String> {
    let (unit, model, channel) = crate::state::split_channel_key(key)?;
    let b = config.buses.iter().find(|b| b.name == bus)?;
    b.devices
        .iter()
        .find(|d| {
            d.place() == unit
                && d.model == model
                // A meter's channels are its records: any name of its may be one of them.
                && (d.channels_from_device()
                    || d.profile.all_channels().iter().any(|c| c.name == channel))
        })
        .map(|d| d.name.clone())
}

/// Every saved channel of `bus`, with its owner.
pub fn entries(config: &Config, bus: &str, state: &BusState) -> Vec<Entry> {
    state
        .channels
        .iter()
        .map(|(key, s)| Entry {
            bus: bus.to_string(),
            key: key.clone(),
            state: s.clone(),
            device: owner(config, bus, key),
        })
        .collect()
}

/// `state` without what matches no configured device.
pub fn pruned(config: &Config, bus: &str, state: &BusState) -> BusState {
    let mut out = state.clone();
    out.channels
        .retain(|key, _| owner(config, bus, key).is_some());
    let units: Vec<String> = config
        .buses
        .iter()
        .filter(|b| b.name == bus)
        .flat_map(|b| b.devices.iter())
        .map(|d| crate::state::device_key(d.unit, &d.model))
        .collect();
    out.holes.retain(|key, _| units.contains(key));
    out
}

/// One line of `state list`.
pub fn line(e: &Entry) -> String {
    let when = humantime::format_rfc3339_seconds(
        std::time::UNIX_EPOCH + std::time::Duration::from_millis(e.state.at_ms),
    );
    let count = e
        .state
        .count
        .map_or_else(|| "-".to_string(), |c| c.to_string());
    let owner = match &e.device {
        Some(d) => format!("device {d}"),
        None => "matches no configured device".to_string(),
    };
    format!(
        "{:<12} {:<24} total {:>14}  count {:>12}  seq {:>8}  read {when}  {owner}",
        e.bus, e.key, e.state.total, count, e.state.seq
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> Config {
        Config::from_toml(
            "[gateway]\nid = \"t\"\n[buses.line1]\nport = \"/dev/ttyS0\"\n\
             [buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\nenabled = false\n",
            Path::new("/nonexistent/pulsegate.toml"),
            Some(Default::default()),
        )
        .unwrap()
    }

    fn state() -> BusState {
        let mut s = BusState::default();
        for key in ["1/yl67/a0", "1/yl67/enc0", "2/yl67/a0", "1/wj157/a0"] {
            s.channels.insert(key.into(), CounterState::default());
        }
        s.holes.insert("2/yl67".into(), vec![(24, 32)]);
        s
    }

    #[test]
    fn saved_channels_are_owned_by_the_configured_device_of_the_same_unit_model_and_channel() {
        let c = config();
        let owners: Vec<Option<String>> = entries(&c, "line1", &state())
            .into_iter()
            .map(|e| e.device)
            .collect();
        // Sorted keys: 1/wj157/a0, 1/yl67/a0, 1/yl67/enc0, 2/yl67/a0.
        let meter = Some("meter".to_string());
        assert_eq!(owners, [None, meter.clone(), meter, None]);
        assert!(
            entries(&c, "line2", &state())
                .iter()
                .all(|e| e.device.is_none())
        );
    }

    #[test]
    fn pruning_keeps_what_a_configured_device_owns_even_when_disabled() {
        let p = pruned(&config(), "line1", &state());
        let keys: Vec<&str> = p.channels.keys().map(String::as_str).collect();
        assert_eq!(keys, ["1/yl67/a0", "1/yl67/enc0"]);
        assert!(p.holes.is_empty());
    }

    #[test]
    fn state_files_are_named_by_bus() {
        assert_eq!(
            bus_of(Path::new("/x/bus-line1.json")).as_deref(),
            Some("line1")
        );
        assert_eq!(bus_of(Path::new("/x/bus-line1.json.tmp")), None);
        assert_eq!(bus_of(Path::new("/x/spool")), None);
    }
}
