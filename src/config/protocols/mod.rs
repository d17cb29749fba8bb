//! What the config floor knows of the protocols a bus may speak (`[buses.NAME] protocol`): a
//! device's [`Address`] (`address.rs`), and the serving outputs a protocol brings
//! ([`Servers`]). A protocol's part of the config ([`BusProtocol`]: its names, its checks of
//! `[buses.NAME]`, its words, its line as a bus's [`Link`]) is in `config/bus.rs` beside the
//! bus it makes, implemented in the protocol's folder (`src/<protocol>/config/`); the list a
//! config is checked against ([`Protocols`]) is handed in by the protocol registry
//! (`crate::protocols`), as output kinds are. A new protocol implements the traits in its folder
//! and is one line in `crate::protocols`; nothing here changes.

pub mod address;

pub(crate) use super::bus::Checking;
pub use super::bus::{LineOf, Link, Protocol, Protocols};
pub use address::{Address, AddressOf};

use super::walk::{Errors, Table};
use crate::modbus::config as modbus;

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
