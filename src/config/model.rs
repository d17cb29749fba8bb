//! The checked, typed configuration: what the gateway works with (the raw TOML is checked
//! into it in `check.rs`, loaded in `mod.rs`). Types only, so every file of `config/` can use
//! them without going through the loader.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

pub use super::error::{ConfigError, ConfigErrors};

use super::metrics::Metrics as MetricsEndpoint;
use super::outputs::Outputs;

pub(crate) use super::bus::BusParts;
pub use super::bus::{Bus, Device};
pub use super::connection::{Mqtt, MqttProtocol, Secret, Tls};
pub use super::parity::Parity;
pub use super::protocols::{Address, Link, Protocol};

use super::policy::{PayloadMode, PolicyOverride};

/// Default configuration file.
pub const DEFAULT_PATH: &str = "/etc/pulsegate/pulsegate.toml";

/// A checked configuration.
#[derive(Debug, Clone)]
pub struct Config {
    /// The file it was read from.
    pub source: PathBuf,
    pub gateway: Gateway,
    pub mqtt: Mqtt,
    /// `[metrics]`: the Prometheus endpoint, when configured.
    pub metrics: Option<MetricsEndpoint>,
    /// Buses sorted by name.
    pub buses: Vec<Bus>,
    /// `[outputs]` (or `mqtt.format`): where readings go, and their formats' settings.
    pub outputs: Outputs,
    /// `[remote]`: config pushed from the broker.
    pub remote: super::remote::Remote,
}

/// `[gateway]`
#[derive(Debug, Clone, PartialEq)]
pub struct Gateway {
    pub id: String,
    /// The hostname the id was derived from, when `gateway.id` is not set (logged at start so
    /// the derived id is never a surprise).
    pub id_from_hostname: Option<String>,
    pub state_dir: PathBuf,
    /// How often counter state is written to disk (it is also written at shutdown).
    pub state_flush: Duration,
    /// How often bus statistics are logged and published.
    pub stats_interval: Duration,
    /// Where user profiles (`*.toml`) are looked up.
    pub profile_dir: PathBuf,
    /// Publish policy of every channel unless a device or channel says otherwise.
    pub publish: PolicyOverride,
    /// One message per channel or per device, unless a device says otherwise.
    pub payload: PayloadMode,
    /// `timezone`: the local clock interval boundaries follow (default UTC).
    pub clock: crate::metering::Clock,
    /// `intervals` of every channel unless a device or channel says otherwise.
    pub intervals: Option<Vec<crate::metering::Period>>,
    /// `[tariffs]` (a table of its own, kept here because every bus books by it).
    pub tariffs: Option<Arc<crate::metering::tariff::Calendar>>,
    /// `[billing]` (likewise).
    pub billing: Option<Arc<crate::metering::billing::BillingConfig>>,
}
