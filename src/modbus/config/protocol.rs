//! Modbus at the config floor, as the registry (`crate::protocols`) sees it: its names, its
//! checks of `[buses.NAME]`, its bus in words, and its line and unit as a bus's link and a
//! device's address.

use super::{Line, Unit};
use crate::config::bus::{Bus, BusParts, BusProtocol, Checking, LineOf, Protocol};
use crate::config::protocols::address::AddressOf;
use crate::config::walk::{Errors, Table};

/// The protocol (`protocol = "modbus"`, the default).
pub const PROTOCOL: Protocol = Protocol::of(&Modbus);

/// Modbus RTU and TCP.
struct Modbus;

impl BusProtocol for Modbus {
    fn name(&self) -> &'static str {
        "modbus"
    }

    fn title(&self) -> &'static str {
        "Modbus"
    }

    fn devices(&self) -> &'static str {
        "Modbus modules"
    }

    fn bus(
        &self,
        t: &mut Table<'_>,
        path: &str,
        checking: &Checking<'_>,
        errs: &mut Errors,
    ) -> BusParts {
        super::check::bus(t, path, checking, errs)
    }

    fn in_words(&self, bus: &Bus) -> String {
        match bus.link.line::<Line>() {
            Some(line) => super::report::bus(bus, line),
            None => String::new(),
        }
    }
}

impl LineOf for Line {
    fn protocol(&self) -> Protocol {
        PROTOCOL
    }
}

impl AddressOf for Unit {
    fn key(&self) -> String {
        Unit::key(*self)
    }

    fn tag(&self) -> String {
        Unit::tag(*self)
    }

    fn unit_id(&self) -> Option<u8> {
        Some(self.0)
    }

    fn channels_from_device(&self) -> bool {
        false
    }

    fn writable_counts(&self) -> bool {
        true
    }
}
