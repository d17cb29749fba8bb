//! The one list of protocols a bus may speak (`[buses.NAME] protocol`), and the types every
//! part of the gateway sees of them: a bus's [`Link`], a device's [`Address`] and the serving
//! outputs a protocol brings ([`Servers`]). Everything a protocol knows of its configuration
//! (its tables, checks, line and address) is in its own folder (`src/<protocol>/config/`);
//! this file only picks among them (and `config/buses.rs` picks a bus's checks and its words by
//! its protocol). A new protocol is a variant in each enum below, and the arms the compiler
//! then asks for.

use super::walk::{Errors, Table};
use crate::mbus::config as mbus;
use crate::modbus::config as modbus;

/// The protocol a bus speaks; one list, parsed with `FromStr`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    Modbus,
    Mbus,
}

impl Protocol {
    /// Every protocol, in the order an error lists them.
    pub const ALL: [Protocol; 2] = [Protocol::Modbus, Protocol::Mbus];

    /// The protocol of a bus that names none.
    pub const DEFAULT: Protocol = Protocol::Modbus;

    /// The name a config writes.
    pub fn name(self) -> &'static str {
        match self {
            Protocol::Modbus => modbus::NAME,
            Protocol::Mbus => mbus::NAME,
        }
    }

    /// The protocol as a person writes it.
    pub fn title(self) -> &'static str {
        match self {
            Protocol::Modbus => modbus::TITLE,
            Protocol::Mbus => mbus::TITLE,
        }
    }

    /// What a bus of this protocol reaches, for an error that points to it
    /// (`protocol = "NAME"` for …).
    pub fn devices(self) -> &'static str {
        match self {
            Protocol::Modbus => modbus::DEVICES,
            Protocol::Mbus => mbus::DEVICES,
        }
    }

    /// How the other protocols are asked for, for an error on a bus of this one:
    /// `` `protocol = "mbus"` for M-Bus meters ``.
    pub fn others(self) -> String {
        let others: Vec<String> = Protocol::ALL
            .into_iter()
            .filter(|p| *p != self)
            .map(|p| format!("`protocol = {:?}` for {}", p.name(), p.devices()))
            .collect();
        others.join(", or ")
    }
}

impl std::fmt::Display for Protocol {
    /// The name a config (and `--protocol`) writes.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
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

/// How a bus reaches its devices: one line type per protocol.
#[derive(Debug, Clone, PartialEq)]
pub enum Link {
    Modbus(modbus::Line),
    Mbus(mbus::Line),
}

impl Link {
    /// The protocol of the link.
    pub fn protocol(&self) -> Protocol {
        match self {
            Link::Modbus(_) => Protocol::Modbus,
            Link::Mbus(_) => Protocol::Mbus,
        }
    }
}

impl std::fmt::Display for Link {
    /// How logs, `check` and the status page name the link.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Link::Modbus(line) => line.fmt(f),
            Link::Mbus(line) => line.fmt(f),
        }
    }
}

/// Where a device answers on its bus, in its protocol's terms: written, keyed and told apart
/// here once.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Address {
    Modbus(modbus::Unit),
    Mbus(mbus::MeterAddress),
}

impl Address {
    /// The protocol the address belongs to.
    pub fn protocol(&self) -> Protocol {
        match self {
            Address::Modbus(_) => Protocol::Modbus,
            Address::Mbus(_) => Protocol::Mbus,
        }
    }

    /// The address as the state file keys it (`3`, `5`, `12345678`).
    pub fn key(&self) -> String {
        match self {
            Address::Modbus(u) => u.key(),
            Address::Mbus(m) => m.key(),
        }
    }

    /// The address as a name part, stable across renames (`u3`, `a5`, `id12345678`).
    pub fn tag(&self) -> String {
        match self {
            Address::Modbus(u) => u.tag(),
            Address::Mbus(m) => m.tag(),
        }
    }

    /// The address in a few words after the bus's name (`unit 3`, `address 5`,
    /// `id 12345678`): a device's serial number in Home Assistant.
    pub fn short(&self) -> String {
        match self {
            Address::Modbus(u) => u.to_string(),
            Address::Mbus(m) => m.short(),
        }
    }

    /// The M-Bus meter's address, for its driver and tools.
    pub fn as_mbus(&self) -> Option<&mbus::MeterAddress> {
        match self {
            Address::Modbus(_) => None,
            Address::Mbus(m) => Some(m),
        }
    }

    /// A number from 1 to 247 the device answers by on its bus, if it has one (a Modbus
    /// server output gives the device that unit id unless told otherwise).
    pub fn unit_id(&self) -> Option<u8> {
        match self {
            Address::Modbus(u) => Some(u.0),
            Address::Mbus(m) => m.unit_id(),
        }
    }

    /// Whether the device's channels are what it answers (an M-Bus meter's records, found
    /// when it answers) rather than its profile's list.
    pub fn channels_from_device(&self) -> bool {
        match self {
            Address::Modbus(_) => false,
            Address::Mbus(_) => true,
        }
    }

    /// Whether the device's counts can be cleared or preset (a Modbus module's can; an M-Bus
    /// meter's registers cannot, only its reading can be set).
    pub fn writable_counts(&self) -> bool {
        match self {
            Address::Modbus(_) => true,
            Address::Mbus(_) => false,
        }
    }
}

impl std::fmt::Display for Address {
    /// The address as a person says it (`unit 3`, `primary address 5`, `id 12345678`).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Address::Modbus(u) => u.fmt(f),
            Address::Mbus(m) => m.fmt(f),
        }
    }
}

/// The serving outputs the protocols bring, each a kind of `[outputs.NAME]` of its own (kind
/// `"modbus"`: a Modbus TCP server for PLCs), read by its protocol's folder; servers, not MQTT
/// connections.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Servers {
    /// The outputs of kind `modbus`.
    pub modbus: Vec<modbus::server::ModbusServer>,
}

impl Servers {
    /// Whether `kind` names a serving output.
    pub fn is_kind(kind: &str) -> bool {
        kind == modbus::server::KIND
    }

    /// The serving kinds as an error lists them: `"modbus" (a Modbus TCP server)`.
    pub fn kinds() -> String {
        format!("{:?} (a Modbus TCP server)", modbus::server::KIND)
    }

    /// Reads one `[outputs.NAME]` table of a serving kind (its name checked, its `kind` read).
    pub(crate) fn read(&mut self, name: &str, t: Table<'_>, errs: &mut Errors) {
        self.modbus.extend(modbus::server::read(name, t, errs));
    }

    /// A device's own keys for the serving outputs (`server_unit = N`: the unit id it answers
    /// as), read beside its bus's keys whatever protocol the bus speaks.
    pub(crate) fn device_keys(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<u8> {
        modbus::server::server_unit(t, path, errs)
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.modbus.is_empty()
    }

    /// Each serving output: its name, kind and where it listens.
    pub fn each(&self) -> impl Iterator<Item = (&str, &'static str, String)> {
        self.modbus
            .iter()
            .map(|s| (s.name.as_str(), modbus::server::KIND, s.listen.to_string()))
    }

    /// Whether one takes commands.
    pub fn take_commands(&self) -> bool {
        self.modbus.iter().any(|s| s.commands)
    }

    /// The first serving kind, for a note that none serves.
    pub fn kind() -> &'static str {
        modbus::server::KIND
    }
}

#[cfg(test)]
mod tests;
