//! Configuration: one TOML file plus `PULSEGATE__…` environment overrides, checked into typed
//! [`Config`] in one place that reports every error at once.
//!
//! Buses and devices are maps keyed by name (not arrays) so that an environment variable such as
//! `PULSEGATE__BUSES__LINE1__DEVICES__PRESS1__POLL=2s` can address one of them.

pub mod bus;
pub mod buses;
pub mod channel;
pub(crate) mod check;
pub(crate) mod connection;
pub(crate) mod error;
pub mod hash;
pub(crate) mod metering;
pub mod metrics;
pub(crate) mod model;
mod mqtt;
pub(crate) mod names;
pub mod outputs;
pub(crate) mod parity;
pub mod policy;
pub mod protocols;
pub mod publish;
pub mod remote;
mod socket;
mod tariffs;
pub mod tls;
pub mod units;
pub(crate) mod walk;

use std::collections::HashMap;
use std::path::Path;

pub use channel::{ChannelConfig, Run};
pub use check::{Known, from_tree, host_name_raw, id_from_host};
pub use hash::ConfigHash;
pub use metrics::Metrics as MetricsEndpoint;
pub use outputs::{Kinds, OutputConfig, OutputKind, Outputs};
pub use protocols::Protocols;

pub use model::*;

/// `Config::load`, `Config::load_with_env` and `Config::from_toml` check with the gateway's own
/// registries: they are defined beside the protocol registry (`crate::protocols`), which stands
/// above everything it registers, and call the two below.
impl Config {
    /// Reads and checks `path` against `known`, with the environment given (`None`: the
    /// process's `PULSEGATE__…` overrides).
    pub fn load_with(
        path: &Path,
        env: Option<HashMap<String, String>>,
        known: &Known,
    ) -> Result<Config, ConfigErrors> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| {
            ConfigErrors(vec![ConfigError {
                path: String::new(),
                origin: origin.clone(),
                message: format!("cannot read: {e}"),
            }])
        })?;
        Self::from_toml_with(&text, path, env, known)
    }

    /// Checks TOML text as if it had been read from `path`, against `known`.
    pub fn from_toml_with(
        text: &str,
        path: &Path,
        env: Option<HashMap<String, String>>,
        known: &Known,
    ) -> Result<Config, ConfigErrors> {
        let origin = path.display().to_string();
        let mut env_source = config::Environment::with_prefix("PULSEGATE")
            .prefix_separator("__")
            .separator("__")
            .try_parsing(true);
        if let Some(env) = env {
            env_source = env_source.source(Some(env.into_iter().collect()));
        }
        let tree = config::Config::builder()
            .add_source(config::File::from_str(text, config::FileFormat::Toml))
            .add_source(env_source)
            .build()
            .map_err(|e| {
                ConfigErrors(vec![ConfigError {
                    path: String::new(),
                    origin: origin.clone(),
                    message: e.to_string(),
                }])
            })?;
        from_tree(&tree.cache, path, known)
    }

    /// Every device with its bus, in bus and name order.
    pub fn devices(&self) -> impl Iterator<Item = (&Bus, &Device)> {
        self.buses
            .iter()
            .flat_map(|b| b.devices.iter().map(move |d| (b, d)))
    }

    /// The devices that are polled and published: neither they nor their bus have
    /// `enabled = false`.
    pub fn enabled_devices(&self) -> impl Iterator<Item = (&Bus, &Device)> {
        self.devices().filter(|(b, d)| b.enabled && d.enabled)
    }
}

#[cfg(test)]
mod socket_tests;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod units_tests;
