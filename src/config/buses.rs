//! A bus by its protocol: the one place that picks a protocol's checks of `[buses.NAME]` and
//! its words for `check` and `plan` (each protocol's own are in its folder,
//! `src/<protocol>/config/`), and the serving outputs' register map and its guard. A new
//! protocol is an arm in each match below.

use super::model::{Bus, BusParts};
use super::protocols::{Link, Protocol};
use super::walk::{Errors, Table};
use crate::mbus::config as mbus;
use crate::modbus::config as modbus;
use crate::profile::Profiles;

/// The protocol's own keys of `[buses.NAME]`, checked: its link, devices and timing.
pub(crate) fn parts(
    protocol: Protocol,
    t: &mut Table<'_>,
    path: &str,
    profiles: &Profiles,
    errs: &mut Errors,
) -> BusParts {
    match protocol {
        Protocol::Modbus => modbus::check::bus(t, path, profiles, errs),
        Protocol::Mbus => mbus::check::bus(t, path, errs),
    }
}

/// The bus in its protocol's words, one line each: a Modbus bus's reads, registers and line
/// time per device and poll; an M-Bus bus's meters.
pub fn in_words(bus: &Bus) -> String {
    match &bus.link {
        Link::Modbus(line) => modbus::report::bus(bus, line),
        Link::Mbus(_) => mbus::report::meters(&bus.name, &bus.link, &bus.devices) + "\n",
    }
}

/// A server output's register map: a contract, so unit ids and blocks that collide are errors.
pub(crate) use crate::modbus::config::server::map::RegisterMap;

/// What of the server outputs an unsigned pushed config may not change, in words.
pub use crate::modbus::config::server::guard::changes as server_changes;
