//! `[buses.NAME]` of `sim.toml`: a Modbus bus and its modules.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;

use serde::Deserialize;

/// One bus: a pseudo-terminal (optionally linked at `link`) or a TCP listener.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusConfig {
    /// Symlink to create to the pseudo-terminal (serial bus).
    pub link: Option<PathBuf>,
    /// Address to serve Modbus TCP on, e.g. "127.0.0.1:20108".
    pub listen: Option<SocketAddr>,
    /// Put a line emulator (baud-rate timing, turnaround, byte faults) in front of the bus.
    pub line: Option<super::line::LineSpec>,
    pub devices: BTreeMap<String, SimDeviceConfig>,
}

/// One simulated module.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimDeviceConfig {
    pub unit: u8,
    pub model: String,
    /// The module's baud rate (default 9600, the datasheets' factory setting).
    pub baud: Option<u32>,
    /// Stay silent on reads of registers the module lacks (default: exception 02).
    #[serde(default)]
    pub silent_on_unknown: bool,
    /// Raw values of the mode registers (profile order); default: each group's first mode.
    #[serde(default)]
    pub modes: Vec<u16>,
    /// Start silent (never answering).
    #[serde(default)]
    pub silent: bool,
    /// Answer nonsense in well-formed frames.
    #[serde(default)]
    pub nonsense: bool,
    /// Answer this late, e.g. "150ms".
    #[serde(default, with = "humantime_serde")]
    pub answer_delay: Option<std::time::Duration>,
    #[serde(default)]
    pub channels: BTreeMap<String, SimChannelConfig>,
}

/// A channel's starting count and pulse rate.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimChannelConfig {
    #[serde(default)]
    pub count: i64,
    /// Pulses per second; negative turns an encoder backwards.
    #[serde(default)]
    pub rate: f64,
    pub ppr: Option<u16>,
}
