//! A fingerprint of the config in force: the same config gives the same hash at every start
//! (and on every machine running the same build), any change to what the gateway does gives
//! another, and no secret is in it.
//!
//! What is hashed is the checked [`Config`] (defaults filled in, environment overrides and
//! profile files applied: what the gateway works with, not the text it was read from), written
//! out by its `Debug` form with two things left out:
//! - the path it was read from (the same settings under another name are the same config;
//!   the folder counts where it is the default `profile_dir`, beside the file);
//! - secret values (`password`, `token`): their `Debug` is `Secret(***)`, so whether a secret
//!   is set counts and its value does not. A hash that changed with a password could be used
//!   to test guesses of it against the published hash.
//!
//! Every typed config value derives or writes a deterministic `Debug` (maps are `BTreeMap`s,
//! profiles by their contents), so the text is stable across restarts; a new field in a later
//! build may change it, which is right: the gateway then runs another config.

use std::fmt;

use super::model::Config;

/// SHA-256 of the config in force (see the module's documentation).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConfigHash([u8; 32]);

impl ConfigHash {
    /// The first 12 hex digits: enough to tell two configs apart on a page or a dashboard.
    pub fn short(&self) -> String {
        self.to_string()[..12].to_string()
    }
}

impl fmt::Display for ConfigHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for b in self.0 {
            write!(f, "{b:02x}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for ConfigHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ConfigHash({self})")
    }
}

impl Config {
    /// The hash of this config (see [`ConfigHash`]).
    pub fn hash(&self) -> ConfigHash {
        let Config {
            source: _,
            gateway,
            mqtt,
            metrics,
            buses,
            outputs,
            remote,
        } = self;
        let text =
            format!("{gateway:?}\n{mqtt:?}\n{metrics:?}\n{buses:?}\n{outputs:?}\n{remote:?}");
        let digest = ring::digest::digest(&ring::digest::SHA256, text.as_bytes());
        let mut bytes = [0u8; 32];
        bytes.copy_from_slice(digest.as_ref());
        ConfigHash(bytes)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    const BASE: &str = r#"
[gateway]
id = "press-hall"
state_dir = "/tmp/pulsegate-hash-test"
[mqtt]
host = "broker"
password = "first secret"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.meter]
unit = 1
model = "yl67"
"#;

    fn hash_of(text: &str, path: &str) -> ConfigHash {
        Config::from_toml(text, Path::new(path), Some(Default::default()))
            .expect("valid config")
            .hash()
    }

    #[test]
    fn the_same_config_read_twice_or_from_another_path_has_the_same_hash() {
        let a = hash_of(BASE, "/etc/pulsegate/pulsegate.toml");
        assert_eq!(a, hash_of(BASE, "/etc/pulsegate/pulsegate.toml"));
        assert_eq!(a, hash_of(BASE, "/etc/pulsegate/copy.toml"));
        assert_eq!(a.to_string().len(), 64);
        assert_eq!(a.short(), a.to_string()[..12]);
    }

    #[test]
    fn a_change_that_matters_changes_the_hash_and_formatting_does_not() {
        let a = hash_of(BASE, "a.toml");
        let poll = BASE.replace("model = \"yl67\"", "model = \"yl67\"\npoll = \"2s\"");
        assert_ne!(a, hash_of(&poll, "a.toml"), "a device's poll interval");
        let host = BASE.replace("host = \"broker\"", "host = \"broker2\"");
        assert_ne!(a, hash_of(&host, "a.toml"), "the broker");
        let reformatted = BASE.replace("unit = 1", "unit   =   1 # the first module");
        assert_eq!(a, hash_of(&reformatted, "a.toml"), "spaces and comments");
        let default_spelled_out = BASE.replace("[mqtt]", "[mqtt]\nport = 1883");
        assert_eq!(
            a,
            hash_of(&default_spelled_out, "a.toml"),
            "a default written out is the same config"
        );
    }

    #[test]
    fn a_secret_counts_by_its_presence_never_by_its_value() {
        let a = hash_of(BASE, "a.toml");
        let other = BASE.replace("first secret", "second secret");
        assert_eq!(a, hash_of(&other, "a.toml"));
        let none = BASE.replace("password = \"first secret\"\n", "");
        assert_ne!(a, hash_of(&none, "a.toml"));
        let config = Config::from_toml(BASE, Path::new("a.toml"), Some(Default::default()))
            .expect("valid config");
        let text = format!("{:?}", config.mqtt);
        assert!(!text.contains("first secret"), "{text}");
    }
}
