//! An M-Bus bus's configuration: its line (a serial level converter, or raw frames on a TCP
//! socket), a meter's address, and the checks of `[buses.NAME] protocol = "mbus"` (`check.rs`).

pub(crate) mod check;
pub mod protocol;
pub(crate) mod report;

use std::path::PathBuf;
use std::time::Duration;

use crate::config::parity::Parity;

/// The `model` of every M-Bus meter in the state file's keys.
pub const METER_MODEL: &str = "mbus";

/// The baud rates of wired M-Bus (EN 13757-2): 300 to 38400.
pub const BAUDS: [u32; 8] = [300, 600, 1200, 2400, 4800, 9600, 19200, 38400];

/// A meter's primary addresses: 0 (unconfigured, as many ship) to 250.
pub const MAX_PRIMARY: u8 = 250;

/// How often a meter is read unless its config says: meters move slowly, and a 2400-baud
/// segment of many meters needs the time.
pub const DEFAULT_METER_POLL: Duration = Duration::from_secs(60);

/// What a meter has in the place of a profile: no registers and no channels (its channels are
/// its answer's records, found when it answers), the M-Bus baud rates, and the answer timeout
/// of an M-Bus-to-Ethernet converter (a serial line's comes from its baud rate, by the
/// standard).
pub fn meter_profile() -> crate::profile::Profile {
    crate::profile::Profile::answered(
        METER_MODEL,
        "M-Bus meter",
        &BAUDS,
        Duration::from_millis(500),
    )
}

/// How an M-Bus bus reaches its meters.
#[derive(Debug, Clone, PartialEq)]
pub enum Line {
    /// A serial M-Bus level converter (the master): 8 data bits, `parity`, 1 stop bit.
    Serial {
        port: PathBuf,
        baud: u32,
        parity: Parity,
    },
    /// An M-Bus-to-Ethernet converter passing raw frames on a TCP socket.
    Tcp { host: String, port: u16 },
}

impl std::fmt::Display for Line {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Line::Serial { port, baud, parity } => {
                write!(
                    f,
                    "M-Bus {} at {baud} baud, parity {parity:?}",
                    port.display()
                )
            }
            Line::Tcp { host, port } => write!(f, "M-Bus over TCP {host}:{port}"),
        }
    }
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
    /// As the state file keys it: `5` for primary address 5, the 8-digit id for a secondary
    /// address.
    pub fn key(&self) -> String {
        match self {
            MeterAddress::Primary(a) => a.to_string(),
            MeterAddress::Secondary { id, .. } => id.clone(),
        }
    }

    /// As a name part: `a5`, `id12345678`.
    pub fn tag(&self) -> String {
        match self {
            MeterAddress::Primary(a) => format!("a{a}"),
            MeterAddress::Secondary { id, .. } => format!("id{id}"),
        }
    }

    /// In a few words after the bus's name: `address 5`, `id 12345678`.
    pub fn short(&self) -> String {
        match self {
            MeterAddress::Primary(a) => format!("address {a}"),
            MeterAddress::Secondary { id, .. } => format!("id {id}"),
        }
    }

    /// The primary address where it could be a Modbus unit id (1..=247).
    pub fn unit_id(&self) -> Option<u8> {
        match self {
            MeterAddress::Primary(a) if (1..=247).contains(a) => Some(*a),
            _ => None,
        }
    }

    /// The address byte of the meter's frames: its primary address, or 0xFD (the network
    /// layer's, once the meter is selected by its secondary address).
    pub fn wire(&self) -> u8 {
        match self {
            MeterAddress::Primary(a) => *a,
            MeterAddress::Secondary { .. } => 0xFD,
        }
    }
}

impl std::fmt::Display for MeterAddress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MeterAddress::Primary(a) => write!(f, "primary address {a}"),
            MeterAddress::Secondary { id, .. } => write!(f, "id {id}"),
        }
    }
}
