//! A bus of the checked config ([`Bus`], its [`Device`]s) and the protocol it speaks: the
//! protocol's part of the config ([`BusProtocol`], implemented in its folder,
//! `src/<protocol>/config/`, behind the [`Protocol`] handle), the list a config is checked
//! against ([`Protocols`]) and the bus's [`Link`] (its protocol's own line type). One file, as
//! a bus holds its link, a link knows its protocol and a protocol makes the bus.

use std::any::Any;
use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use super::channel::ChannelConfig;
use super::policy::{PayloadMode, PolicyOverride};
use super::protocols::address::Address;
use super::walk::{Errors, Table};
use crate::profile::{Profile, Profiles};

/// One protocol's part of the config: its names, its checks of `[buses.NAME]` and its bus in
/// words. Implemented once per protocol, in its folder.
pub(crate) trait BusProtocol: Sync + 'static {
    /// The name a config writes (`protocol = "NAME"`).
    fn name(&self) -> &'static str;
    /// The protocol as a person writes it.
    fn title(&self) -> &'static str;
    /// What a bus of this protocol reaches, for an error that points to it.
    fn devices(&self) -> &'static str;
    /// Its own keys of `[buses.NAME]`, checked: its link, devices and timing.
    fn bus(
        &self,
        t: &mut Table<'_>,
        path: &str,
        checking: &Checking<'_>,
        errs: &mut Errors,
    ) -> BusParts;
    /// The bus in the protocol's words for `check` and `plan`, a line each, ending in a newline.
    fn in_words(&self, bus: &Bus) -> String;
}

/// What a protocol's checks of a bus are given besides the table.
#[derive(Clone, Copy)]
pub(crate) struct Checking<'a> {
    /// The protocol of the bus being checked.
    pub protocol: Protocol,
    /// The module profiles, built in and the gateway's own.
    pub profiles: &'a Profiles,
    /// Every protocol the config may name, for an error that points to the others.
    pub protocols: &'a Protocols,
}

/// A protocol a bus speaks: one of the registry's.
#[derive(Clone, Copy)]
pub struct Protocol(&'static dyn BusProtocol);

impl Protocol {
    /// The protocol whose config part is `p`.
    pub(crate) const fn of(p: &'static dyn BusProtocol) -> Protocol {
        Protocol(p)
    }

    /// The name a config writes.
    pub fn name(self) -> &'static str {
        self.0.name()
    }

    /// The protocol as a person writes it.
    pub fn title(self) -> &'static str {
        self.0.title()
    }

    /// What a bus of this protocol reaches (`M-Bus meters`).
    pub fn devices(self) -> &'static str {
        self.0.devices()
    }

    /// Its keys of `[buses.NAME]`, checked.
    pub(crate) fn bus(
        self,
        t: &mut Table<'_>,
        path: &str,
        checking: &Checking<'_>,
        errs: &mut Errors,
    ) -> BusParts {
        self.0.bus(t, path, checking, errs)
    }

    /// The bus in its protocol's words (`check`, `plan`).
    pub fn in_words(self, bus: &Bus) -> String {
        self.0.in_words(bus)
    }
}

impl PartialEq for Protocol {
    /// Protocols are told apart by name (a registry holds no two of one name).
    fn eq(&self, other: &Protocol) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Protocol {}

impl std::fmt::Debug for Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::fmt::Display for Protocol {
    /// The name a config (and `--protocol`) writes.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The protocols a config is checked against, in the order an error lists them: the
/// registry's (`crate::protocols::Registry::protocols`).
#[derive(Clone, Debug)]
pub struct Protocols(Vec<Protocol>);

impl Protocols {
    /// These protocols; two of one name are a bug of the registry.
    pub fn new(list: Vec<Protocol>) -> Protocols {
        for (i, p) in list.iter().enumerate() {
            assert!(!list[..i].contains(p), "two protocols named {p}");
        }
        Protocols(list)
    }

    /// Every one, in order.
    pub fn all(&self) -> &[Protocol] {
        &self.0
    }

    /// The protocol a config names `name`, or an error that lists them.
    pub fn find(&self, name: &str) -> Result<Protocol, String> {
        self.0
            .iter()
            .copied()
            .find(|p| p.name() == name)
            .ok_or_else(|| {
                let names: Vec<String> = self.0.iter().map(|p| format!("{:?}", p.name())).collect();
                format!("unknown protocol {name:?}: use {}", names.join(" or "))
            })
    }

    /// How the protocols other than `p` are asked for, for an error on a bus of `p`:
    /// `` `protocol = "mbus"` for M-Bus meters ``.
    pub fn others(&self, p: Protocol) -> String {
        let others: Vec<String> = (self.0.iter())
            .filter(|o| **o != p)
            .map(|o| format!("`protocol = {:?}` for {}", o.name(), o.devices()))
            .collect();
        others.join(", or ")
    }
}

/// A protocol's line: how a bus of that protocol reaches its devices (a serial port, a host).
pub trait LineOf: fmt::Debug + fmt::Display + PartialEq + Send + Sync + 'static {
    /// The protocol whose line it is.
    fn protocol(&self) -> Protocol;
}

/// [`LineOf`] as the object a [`Link`] holds.
trait AnyLine: fmt::Debug + fmt::Display + Send + Sync {
    fn protocol(&self) -> Protocol;
    fn as_any(&self) -> &dyn Any;
    fn same(&self, other: &dyn AnyLine) -> bool;
}

impl<T: LineOf> AnyLine for T {
    fn protocol(&self) -> Protocol {
        LineOf::protocol(self)
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    fn same(&self, other: &dyn AnyLine) -> bool {
        other.as_any().downcast_ref::<T>() == Some(self)
    }
}

/// How a bus reaches its devices: its protocol's line.
#[derive(Clone)]
pub struct Link(Arc<dyn AnyLine>);

impl Link {
    /// A bus's link over `line`.
    pub fn new(line: impl LineOf) -> Link {
        Link(Arc::new(line))
    }

    /// The protocol of the link.
    pub fn protocol(&self) -> Protocol {
        self.0.protocol()
    }

    /// The line as its protocol's type, if it is one of `T`.
    pub fn line<T: LineOf>(&self) -> Option<&T> {
        self.0.as_any().downcast_ref()
    }
}

impl PartialEq for Link {
    fn eq(&self, other: &Link) -> bool {
        self.0.same(&*other.0)
    }
}

impl fmt::Debug for Link {
    /// `modbus(Tcp { .. })`: with its protocol's name, as the config hash reads it (two
    /// protocols' lines may print alike).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}({:?})", self.protocol().name(), self.0)
    }
}

impl fmt::Display for Link {
    /// How logs, `check` and the status page name the link.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
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
