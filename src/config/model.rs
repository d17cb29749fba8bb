//! The checked, typed configuration: what the gateway works with (the raw TOML is checked
//! into it in `check.rs`, loaded in `mod.rs`). Types only, so every file of `config/` can use
//! them without going through the loader.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use crate::profile::Profile;

pub use super::error::{ConfigError, ConfigErrors};

use super::channel::ChannelConfig;
use super::metrics::Metrics as MetricsEndpoint;
use super::outputs::Outputs;

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

/// What a protocol's checks make of its keys of `[buses.NAME]`.
pub(crate) struct BusParts {
    pub link: Option<Link>,
    /// Extra quiet time after a frame (Modbus RTU's silent interval).
    pub guard: Duration,
    /// How often slow registers are re-read.
    pub slow_poll: Duration,
    pub devices: Vec<Device>,
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
    /// Where it answers on its bus, in its protocol's terms.
    pub address: Address,
    /// `server_unit = N`: the unit id this device answers as on a Modbus server output (by
    /// default its own address; see `modbus::server::map`). Not part of its polling.
    pub server_unit: Option<u8>,
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
            && self.address == other.address
    }
}

impl Device {
    /// Where the device answers on its bus, as the state file keys it: the Modbus unit, an
    /// M-Bus meter's primary address, or its 8-digit id.
    pub fn place(&self) -> String {
        self.address.key()
    }

    /// The same as a name part, stable across renames: `u3` (Modbus unit 3), `a5` (M-Bus
    /// primary address 5), `id12345678` (an M-Bus meter by its id).
    pub fn place_tag(&self) -> String {
        self.address.tag()
    }

    /// Whether the device's channels are what it answers rather than its profile's list.
    pub fn channels_from_device(&self) -> bool {
        self.address.channels_from_device()
    }

    /// Whether the device's counts can be cleared or preset.
    pub fn writable_counts(&self) -> bool {
        self.address.writable_counts()
    }

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
