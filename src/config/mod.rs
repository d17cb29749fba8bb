//! Configuration: one TOML file plus `PULSEGATE__…` environment overrides, checked into typed
//! [`Config`] in one place that reports every error at once.
//!
//! Buses and devices are maps keyed by name (not arrays) so that an environment variable such as
//! `PULSEGATE__BUSES__LINE1__DEVICES__PRESS1__POLL=2s` can address one of them.

pub mod channel;
mod check;
mod metering;
mod metrics;
pub mod policy;
pub mod publish;
mod socket;
pub mod sparkplug;
pub mod tls;
pub mod units;
mod walk;

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use crate::profile::Profile;

pub use channel::{ChannelConfig, Run};
pub use check::{from_tree, host_name_raw, id_from_host};
pub use metrics::Metrics as MetricsEndpoint;
pub use publish::HomeAssistant;
pub use sparkplug::Sparkplug;

use crate::config::policy::{PayloadMode, PolicyOverride};

/// Default configuration file.
pub const DEFAULT_PATH: &str = "/etc/pulsegate/pulsegate.toml";

/// One problem in the configuration, with where it is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError {
    /// Key path, e.g. `buses.line1.devices.press1.poll`.
    pub path: String,
    /// The file the value came from, or "the environment".
    pub origin: String,
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}: {}", self.origin, self.path, self.message)
    }
}

/// Every problem found in a configuration.
#[derive(Debug, Clone, thiserror::Error)]
pub struct ConfigErrors(pub Vec<ConfigError>);

impl fmt::Display for ConfigErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.0.len();
        writeln!(
            f,
            "{n} error{} in the configuration:",
            if n == 1 { "" } else { "s" }
        )?;
        for e in &self.0 {
            writeln!(f, "  {e}")?;
        }
        Ok(())
    }
}

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
    /// `[homeassistant]`: MQTT discovery.
    pub homeassistant: HomeAssistant,
    /// `[sparkplug]`: present exactly when `mqtt.format` names `"sparkplug"`.
    pub sparkplug: Option<Sparkplug>,
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
}

/// A secret (the MQTT password): never printed, never logged.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(pub String);

impl fmt::Debug for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Secret(***)")
    }
}

/// `[mqtt.tls]`: TLS to the broker (rustls).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tls {
    /// CA certificate(s) the broker's certificate must chain to (PEM).
    pub ca_file: PathBuf,
    /// Client certificate and key (PEM), for brokers that ask for one.
    pub cert_file: Option<PathBuf>,
    pub key_file: Option<PathBuf>,
}

/// `[mqtt]`
#[derive(Debug, Clone, PartialEq)]
pub struct Mqtt {
    /// Not used when `socket` is set.
    pub host: String,
    pub port: u16,
    /// `mqtt.socket`: a local broker's Unix domain socket, used instead of `host`/`port`
    /// (no TCP port: the socket file's permissions decide who may connect).
    pub socket: Option<PathBuf>,
    pub client_id: String,
    pub username: Option<String>,
    /// From `password`, `password_file`, `PULSEGATE__MQTT__PASSWORD`, or the systemd credential
    /// `mqtt-password` (`LoadCredential=`).
    pub password: Option<Secret>,
    pub tls: Option<Tls>,
    pub keep_alive: Duration,
    pub qos: u8,
    pub retain: bool,
    pub topic_root: String,
    /// Bound of the store-and-forward spool (memory and disk), in bytes.
    pub spool_bytes: u64,
    /// Subscribe to command topics at all (`false`: a read-only site, no clear or preset from
    /// MQTT whatever the devices say).
    pub commands: bool,
    /// `mqtt.protocol`: "5" (default) or "3.1.1".
    pub protocol: MqttProtocol,
    /// `mqtt.format`: how events become payloads, each one of [`publish::FORMAT_NAMES`]
    /// (a list runs them side by side: `["json", "sparkplug"]`).
    pub format: Vec<String>,
    /// `mqtt.batch`: how long readings may wait to go to the broker with the next polls' (see
    /// [`crate::publish::batch`]); zero sends each poll's at once.
    pub batch: Duration,
}

impl Mqtt {
    /// The broker as logs and status name it: the socket path, or `host:port`.
    pub fn broker(&self) -> String {
        match &self.socket {
            Some(path) => path.display().to_string(),
            None => format!("{}:{}", self.host, self.port),
        }
    }
}

/// The MQTT protocol version spoken to the broker.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum MqttProtocol {
    #[default]
    V5,
    /// For brokers that refuse v5 (Azure IoT Hub, older Mosquitto, some embedded brokers): no
    /// response topic or correlation data; everything else works the same.
    V311,
}

/// `[buses.<name>]`
#[derive(Debug, Clone, PartialEq)]
pub struct Bus {
    pub name: String,
    pub link: Link,
    /// Answer timeout for the bus's devices (each may override; default: its profile's).
    pub timeout: Option<Duration>,
    /// Extra quiet time added to the Modbus silent interval between frames.
    pub guard: Duration,
    /// Consecutive failures after which a device is offline.
    pub offline_after: u32,
    /// Backoff between probes of an offline device: first and longest.
    pub backoff_min: Duration,
    pub backoff_max: Duration,
    /// How often slow registers (mode, pulses per revolution) are re-read.
    pub slow_poll: Duration,
    /// `false`: the bus is not opened; its devices' saved state is kept.
    pub enabled: bool,
    pub devices: Vec<Device>,
}

/// How a bus reaches its devices.
#[derive(Debug, Clone, PartialEq)]
pub enum Link {
    /// Modbus RTU on a serial port.
    Rtu {
        port: PathBuf,
        baud: u32,
        parity: Parity,
        stop_bits: u8,
    },
    /// Modbus TCP.
    Tcp { host: String, port: u16 },
}

impl Bus {
    /// Character timing of the bus's serial line; `None` for Modbus TCP.
    pub fn line_timing(&self) -> Option<crate::plan::LineTiming> {
        line_timing(&self.link, self.guard)
    }
}

/// Character timing of a serial link with `guard` after the silent interval: start bit, 8 data
/// bits, parity if any, stop bits. `None` for Modbus TCP.
pub fn line_timing(link: &Link, guard: Duration) -> Option<crate::plan::LineTiming> {
    match link {
        Link::Rtu {
            baud,
            parity,
            stop_bits,
            ..
        } => Some(crate::plan::LineTiming {
            baud: *baud,
            bits_per_char: crate::plan::bits_per_char(*parity != Parity::None, *stop_bits),
            guard,
        }),
        Link::Tcp { .. } => None,
    }
}

/// Serial parity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Parity {
    None,
    Even,
    Odd,
}

/// `[buses.<bus>.devices.<name>]`
#[derive(Debug, Clone)]
pub struct Device {
    pub name: String,
    pub unit: u8,
    pub model: String,
    pub profile: Arc<Profile>,
    pub poll: Duration,
    pub timeout: Option<Duration>,
    /// Whether clear/preset commands are accepted for this device.
    pub commands: bool,
    /// The device's own baud rate where it differs from its bus's (RTU): the port is switched
    /// to it for this device's transactions.
    pub baud: Option<u32>,
    /// Per-channel settings keyed by channel name.
    pub channels: BTreeMap<String, ChannelConfig>,
    /// `false`: not polled or published; its saved state is kept.
    pub enabled: bool,
    /// Publish policy keys of this device (over the gateway's).
    pub publish: PolicyOverride,
    /// `payload` of this device, when it overrides the gateway's.
    pub payload: Option<PayloadMode>,
    /// `intervals` of this device, when it overrides the gateway's.
    pub intervals: Option<Vec<crate::metering::Period>>,
}

impl PartialEq for Device {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
            && self.unit == other.unit
            && self.model == other.model
            && self.poll == other.poll
            && self.timeout == other.timeout
            && self.commands == other.commands
            && self.baud == other.baud
            && self.channels == other.channels
            && self.enabled == other.enabled
            // A profile file edited since: the bus restarts with the new profile.
            && self.profile.fingerprint == other.profile.fingerprint
            && self.publish == other.publish
            && self.payload == other.payload
            && self.intervals == other.intervals
    }
}

impl Device {
    /// The interval periods of `channel`: its own `intervals`, else the device's, else the
    /// gateway's.
    pub fn intervals_of<'a>(
        &'a self,
        gateway: Option<&'a [crate::metering::Period]>,
        channel: &str,
    ) -> &'a [crate::metering::Period] {
        self.channels
            .get(channel)
            .and_then(|c| c.intervals.as_deref())
            .or(self.intervals.as_deref())
            .or(gateway)
            .unwrap_or_default()
    }

    /// Answer timeout of this device on `bus`.
    pub fn answer_timeout(&self, bus: &Bus) -> Duration {
        self.timeout
            .or(bus.timeout)
            .unwrap_or(self.profile.answer_timeout)
    }
}

impl Config {
    /// Reads and checks `path`, with `PULSEGATE__…` overrides from the process environment.
    pub fn load(path: &Path) -> Result<Config, ConfigErrors> {
        Self::load_with_env(path, None)
    }

    /// Like [`Config::load`], with the environment given (for tests).
    pub fn load_with_env(
        path: &Path,
        env: Option<HashMap<String, String>>,
    ) -> Result<Config, ConfigErrors> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| {
            ConfigErrors(vec![ConfigError {
                path: String::new(),
                origin: origin.clone(),
                message: format!("cannot read: {e}"),
            }])
        })?;
        Self::from_toml(&text, path, env)
    }

    /// Checks TOML text as if it had been read from `path`.
    pub fn from_toml(
        text: &str,
        path: &Path,
        env: Option<HashMap<String, String>>,
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
        from_tree(&tree.cache, path)
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
