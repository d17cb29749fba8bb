//! `[mbus.NAME]` of `sim.toml`: an M-Bus segment and its meters.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;

use serde::Deserialize;

/// One M-Bus segment: a TCP listener (an M-Bus-to-Ethernet converter) or a pseudo-terminal
/// at `baud` 8E1 (a level converter), with its meters.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSegmentConfig {
    /// Address to serve raw M-Bus frames on, e.g. "127.0.0.1:10001" (port 0: any free one).
    pub listen: Option<SocketAddr>,
    /// Symlink to create to the pseudo-terminal (a serial segment; the default without
    /// `listen`).
    pub link: Option<PathBuf>,
    /// The serial segment's baud rate (default 2400).
    pub baud: Option<u32>,
    pub meters: BTreeMap<String, SimMeterConfig>,
}

/// One simulated M-Bus meter.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimMeterConfig {
    /// The identification number (8 decimal digits).
    pub id: u32,
    /// Three letters A-Z (default "PGS").
    #[serde(default = "default_manufacturer")]
    pub manufacturer: String,
    #[serde(default = "one")]
    pub version: u8,
    /// The medium code (default 0x07, water).
    #[serde(default = "water")]
    pub medium: u8,
    /// The primary address (default 0, as many meters ship).
    #[serde(default)]
    pub address: u8,
    #[serde(default)]
    pub registers: Vec<SimRegisterConfig>,
    /// Gauges: `power_w`, `flow_litre_per_hour`, `flow_temperature_centi`,
    /// `return_temperature_centi`.
    #[serde(default)]
    pub gauges: BTreeMap<String, i32>,
    /// The most records a telegram holds; more follow in further telegrams (0: all in one).
    #[serde(default)]
    pub records_per_telegram: usize,
    /// Answers nothing.
    #[serde(default)]
    pub silent: bool,
    /// Answers bytes that are no frame.
    #[serde(default)]
    pub garbage: bool,
}

/// A counting register of a simulated meter.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimRegisterConfig {
    /// `energy_wh`, `energy_kwh` or `volume_litre`.
    pub quantity: String,
    /// `bcd8` (rolls over at 10^8) or `int32` (at 2^32).
    #[serde(default = "bcd8")]
    pub width: String,
    #[serde(default)]
    pub start: u64,
    /// Steps a second.
    #[serde(default)]
    pub rate: f64,
}

fn default_manufacturer() -> String {
    "PGS".into()
}

fn one() -> u8 {
    1
}

fn water() -> u8 {
    0x07
}

fn bcd8() -> String {
    "bcd8".into()
}
