//! Wired M-Bus at the config floor, as the registry (`crate::protocols`) sees it: its names,
//! its checks of `[buses.NAME]`, its bus in words, and its line and a meter's address as a
//! bus's link and a device's address.

use super::{Line, MeterAddress};
use crate::config::bus::{Bus, BusParts, BusProtocol, Checking, LineOf, Protocol};
use crate::config::protocols::address::AddressOf;
use crate::config::walk::{Errors, Table};

/// The protocol (`protocol = "mbus"`).
pub const PROTOCOL: Protocol = Protocol::of(&Mbus);

/// Wired M-Bus (EN 13757-2/-3).
struct Mbus;

impl BusProtocol for Mbus {
    fn name(&self) -> &'static str {
        "mbus"
    }

    fn title(&self) -> &'static str {
        "M-Bus"
    }

    fn devices(&self) -> &'static str {
        "M-Bus meters"
    }

    fn bus(&self, t: &mut Table<'_>, path: &str, _: &Checking<'_>, errs: &mut Errors) -> BusParts {
        super::check::bus(t, path, errs)
    }

    fn in_words(&self, bus: &Bus) -> String {
        super::report::meters(&bus.name, &bus.link, &bus.devices) + "\n"
    }
}

impl LineOf for Line {
    fn protocol(&self) -> Protocol {
        PROTOCOL
    }
}

impl AddressOf for MeterAddress {
    fn key(&self) -> String {
        MeterAddress::key(self)
    }

    fn tag(&self) -> String {
        MeterAddress::tag(self)
    }

    fn short(&self) -> String {
        MeterAddress::short(self)
    }

    fn unit_id(&self) -> Option<u8> {
        MeterAddress::unit_id(self)
    }

    /// A meter's channels are its answer's records.
    fn channels_from_device(&self) -> bool {
        true
    }

    /// A meter's registers cannot be cleared or preset; only its reading can be set.
    fn writable_counts(&self) -> bool {
        false
    }
}
