//! A Modbus bus's configuration: its line (RTU on a serial port, or TCP), a device's unit, the
//! baud rates the modules support, and the checks of `[buses.NAME]` (`check.rs`).

pub(crate) mod check;
pub mod plan;
pub mod protocol;
pub(crate) mod report;
pub mod server;

use std::path::PathBuf;
use std::time::Duration;

use crate::config::parity::Parity;

/// Baud rates the seed modules can be set to (their baud-code tables).
pub const BAUDS: [u32; 7] = [2400, 4800, 9600, 19200, 38400, 57600, 115200];

/// The TCP port of a Modbus TCP bus whose devices' datasheets give none.
pub const TCP_PORT: u16 = 502;

/// How a Modbus bus reaches its devices.
#[derive(Debug, Clone, PartialEq)]
pub enum Line {
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

impl Line {
    /// Character timing of an RTU line with `guard` after the silent interval: start bit,
    /// 8 data bits, parity if any, stop bits. `None` for Modbus TCP.
    pub fn timing(&self, guard: Duration) -> Option<plan::LineTiming> {
        match self {
            Line::Rtu {
                baud,
                parity,
                stop_bits,
                ..
            } => Some(plan::LineTiming {
                baud: *baud,
                bits_per_char: plan::bits_per_char(*parity != Parity::None, *stop_bits),
                guard,
            }),
            Line::Tcp { .. } => None,
        }
    }
}

impl std::fmt::Display for Line {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Line::Rtu { port, baud, .. } => write!(f, "RTU {} at {baud} baud", port.display()),
            Line::Tcp { host, port } => write!(f, "TCP {host}:{port}"),
        }
    }
}

/// A Modbus device's unit id (1..=247).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Unit(pub u8);

impl Unit {
    /// As the state file keys it: `3`.
    pub fn key(self) -> String {
        self.0.to_string()
    }

    /// As a name part: `u3`.
    pub fn tag(self) -> String {
        format!("u{}", self.0)
    }
}

impl std::fmt::Display for Unit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "unit {}", self.0)
    }
}
