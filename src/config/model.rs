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
    /// Wired M-Bus: a serial level converter, or raw frames on a TCP socket.
    Mbus(MbusLine),
}

/// How an M-Bus bus reaches its meters.
#[derive(Debug, Clone, PartialEq)]
pub enum MbusLine {
    /// A serial M-Bus level converter (the master): 8 data bits, `parity`, 1 stop bit.
    Serial {
        port: PathBuf,
        baud: u32,
        parity: Parity,
    },
    /// An M-Bus-to-Ethernet converter passing raw frames on a TCP socket.
    Tcp { host: String, port: u16 },
}

/// The protocol a bus speaks (`[buses.NAME] protocol`); one list, parsed with `FromStr`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    Modbus,
    Mbus,
}

impl Protocol {
    /// Every protocol, in the order an error lists them.
    pub const ALL: [Protocol; 2] = [Protocol::Modbus, Protocol::Mbus];

    /// The name a config writes.
    pub fn name(self) -> &'static str {
        match self {
            Protocol::Modbus => "modbus",
            Protocol::Mbus => "mbus",
        }
    }
}

impl std::str::FromStr for Protocol {
    type Err = String;

    fn from_str(s: &str) -> Result<Protocol, String> {
        Protocol::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                let names: Vec<String> = Protocol::ALL
                    .iter()
                    .map(|p| format!("{:?}", p.name()))
                    .collect();
                format!("unknown protocol {s:?}: use {}", names.join(" or "))
            })
    }
}

impl Link {
    /// The protocol of the link.
    pub fn protocol(&self) -> Protocol {
        match self {
            Link::Rtu { .. } | Link::Tcp { .. } => Protocol::Modbus,
            Link::Mbus(_) => Protocol::Mbus,
        }
    }
}

impl std::fmt::Display for Link {
    /// How logs, `check` and the status page name the link.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Link::Rtu { port, baud, .. } => write!(f, "RTU {} at {baud} baud", port.display()),
            Link::Tcp { host, port } => write!(f, "TCP {host}:{port}"),
            Link::Mbus(MbusLine::Serial { port, baud, parity }) => {
                write!(
                    f,
                    "M-Bus {} at {baud} baud, parity {parity:?}",
                    port.display()
                )
            }
            Link::Mbus(MbusLine::Tcp { host, port }) => write!(f, "M-Bus over TCP {host}:{port}"),
        }
    }
}

impl Bus {
    /// Character timing of the bus's Modbus RTU line; `None` for Modbus TCP and M-Bus.
    pub fn line_timing(&self) -> Option<crate::plan::LineTiming> {
        line_timing(&self.link, self.guard)
    }
}

/// Character timing of a serial link with `guard` after the silent interval: start bit, 8 data
/// bits, parity if any, stop bits. `None` for Modbus TCP and for M-Bus (its driver times its
/// own line: the standard's answer time).
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
        Link::Tcp { .. } | Link::Mbus(_) => None,
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
    /// An M-Bus meter's address (`None` on a Modbus bus, where `unit` and `model` say it).
    pub meter: Option<MeterAddress>,
    /// `server_unit = N`: the unit id this device answers as on a Modbus server output (by
    /// default its own address; see `publish::modbus::map`). Not part of its polling.
    pub server_unit: Option<u8>,
}

/// Where an M-Bus meter answers: a primary address, or its secondary address (selected by its
/// 8-digit id, with manufacturer, version and medium where the config narrows it).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MeterAddress {
    /// 0 (the factory default of many meters) to 250.
    Primary(u8),
    Secondary {
        /// 8 decimal digits.
        id: String,
        /// Three letters A-Z.
        manufacturer: Option<String>,
        version: Option<u8>,
        medium: Option<u8>,
    },
}

impl MeterAddress {
    /// The address as a key part: `5` for primary address 5, the 8-digit id for a secondary
    /// address.
    pub fn place(&self) -> String {
        match self {
            MeterAddress::Primary(a) => a.to_string(),
            MeterAddress::Secondary { id, .. } => id.clone(),
        }
    }
}

/// The `model` of every M-Bus meter in the state file's keys.
pub const METER_MODEL: &str = "mbus";

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
            && self.meter == other.meter
    }
}

impl Device {
    /// Where the device answers on its bus, as the state file keys it: the Modbus unit, an
    /// M-Bus meter's primary address, or its 8-digit id.
    pub fn place(&self) -> String {
        match &self.meter {
            Some(m) => m.place(),
            None => self.unit.to_string(),
        }
    }

    /// The same as a name part, stable across renames: `u3` (Modbus unit 3), `a5` (M-Bus
    /// primary address 5), `id12345678` (an M-Bus meter by its id).
    pub fn place_tag(&self) -> String {
        match &self.meter {
            Some(MeterAddress::Primary(a)) => format!("a{a}"),
            Some(MeterAddress::Secondary { id, .. }) => format!("id{id}"),
            None => format!("u{}", self.unit),
        }
    }

    /// Whether the device's channels are what it answers (an M-Bus meter's records, found
    /// when it answers) rather than its profile's list.
    pub fn channels_from_device(&self) -> bool {
        self.meter.is_some()
    }

    /// Whether the device's counts can be cleared or preset (a Modbus module's can; an M-Bus
    /// meter's registers cannot, only its reading can be set).
    pub fn writable_counts(&self) -> bool {
        self.meter.is_none()
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
