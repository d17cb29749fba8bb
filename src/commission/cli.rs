//! The commissioning subcommands of `pulsegate` (clap): what a command says, whatever the
//! protocol; `mod.rs` runs each by its protocol.

use std::path::PathBuf;

use tokio_util::sync::CancellationToken;

use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::config::Protocol;

/// How to reach the modules.
#[derive(clap::Args, Debug, Clone)]
pub struct LineArgs {
    /// Serial port of the RS-485 adapter, e.g. /dev/ttyUSB0.
    #[arg(long)]
    pub(crate) port: Option<PathBuf>,
    /// Modbus TCP instead: HOST[:PORT] (port 502 unless given; the ZH-YX1600 uses 20108).
    #[arg(long, conflicts_with = "port")]
    pub(crate) host: Option<String>,
    /// Serial parity: none | even | odd (default: none for Modbus, even for M-Bus).
    #[arg(long)]
    pub(crate) parity: Option<String>,
    /// Answer timeout before line time is added (default: the models' 100 ms).
    #[arg(long)]
    pub(crate) timeout: Option<humantime::Duration>,
}

/// One unit on the line: where, at what speed, which id.
#[derive(clap::Args, Debug, Clone)]
pub struct UnitArgs {
    #[command(flatten)]
    pub(crate) line: LineArgs,
    /// Baud rate to talk at (default: 9600 for Modbus, 2400 for M-Bus).
    #[arg(long)]
    pub(crate) baud: Option<u32>,
    /// Unit id of the module (Modbus).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=247))]
    pub(crate) unit: Option<u8>,
}

impl UnitArgs {
    /// The Modbus unit, which every Modbus command needs.
    pub(crate) fn unit(&self) -> Result<u8, CommissionError> {
        self.unit
            .ok_or_else(|| CommissionError::BadInput("give --unit N (1-247) of the module".into()))
    }

    /// The Modbus baud rate.
    pub(crate) fn baud(&self) -> u32 {
        self.baud.unwrap_or(9600)
    }
}

/// One module on the line, of a known (or identified) model.
#[derive(clap::Args, Debug, Clone)]
pub struct ModuleArgs {
    #[command(flatten)]
    pub(crate) at: UnitArgs,
    /// Model name, or "auto" to identify it from its identification registers.
    #[arg(long, default_value = "auto")]
    pub(crate) model: String,
}

/// Commissioning commands: survey and set up a line before a config exists.
#[derive(clap::Subcommand, Debug)]
pub enum Commission {
    /// Find the units that answer on a line, their models and baud rates (M-Bus: the meters,
    /// their ids, manufacturers, versions, media and primary addresses).
    Scan {
        #[command(flatten)]
        line: LineArgs,
        /// modbus | mbus.
        #[arg(long, default_value_t = Protocol::DEFAULT.name().to_string())]
        protocol: String,
        /// M-Bus: the wildcard search by secondary address (finds meters that share a primary
        /// address, 0 as shipped), instead of asking primary addresses.
        #[arg(long)]
        secondary: bool,
        /// A baud rate, or "all": every rate the profiles support, fastest first (default 9600;
        /// M-Bus: 2400).
        #[arg(long)]
        baud: Option<String>,
        /// Unit ids to ask: "1-247", "5", "1,3,10-20" (M-Bus: primary addresses, default
        /// "0-250").
        #[arg(long)]
        units: Option<String>,
        /// Print a gateway config for what was found (the table goes to stderr).
        #[arg(long, conflicts_with = "json")]
        toml: bool,
        /// Print what was found as JSON.
        #[arg(long)]
        json: bool,
        /// Ask every identification register even when a unit is silent on the first (for
        /// modules that stay silent on registers they lack; doubles the time per empty unit).
        #[arg(long)]
        every_probe: bool,
    },
    /// Read one module's channels, decoded as the gateway publishes them (M-Bus: one meter's
    /// answer, every record with its value in its unit).
    Read {
        #[command(flatten)]
        module: ModuleArgs,
        /// modbus | mbus.
        #[arg(long, default_value_t = Protocol::DEFAULT.name().to_string())]
        protocol: String,
        /// M-Bus: the meter's primary address (0-250).
        #[arg(long, conflicts_with = "id")]
        address: Option<u8>,
        /// M-Bus: the meter's 8-digit id (its secondary address; F for any digit).
        #[arg(long)]
        id: Option<String>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Read again at this interval, in place, with deltas (until Ctrl-C).
        #[arg(long)]
        watch: Option<humantime::Duration>,
    },
    /// Clear one channel's count (written and read back as the MQTT command does).
    Clear {
        #[command(flatten)]
        module: ModuleArgs,
        #[arg(long)]
        channel: String,
    },
    /// Preset one channel's count (written and read back as the MQTT command does).
    Preset {
        #[command(flatten)]
        module: ModuleArgs,
        #[arg(long)]
        channel: String,
        #[arg(long, allow_negative_numbers = true)]
        value: i64,
    },
    /// Change settings the module's datasheet documents; confirmed, written, read back.
    Setup {
        #[command(flatten)]
        module: ModuleArgs,
        /// New unit id.
        #[arg(long)]
        new_unit: Option<String>,
        /// New baud rate.
        #[arg(long)]
        new_baud: Option<String>,
        /// ZH-YX1600: state of every counter after power-up: up | down | stopped.
        #[arg(long)]
        power_on: Option<String>,
        /// Pulses per revolution of a channel: CHANNEL=N (repeatable).
        #[arg(long, value_name = "CHANNEL=N")]
        ppr: Vec<String>,
        /// Any other documented setting: NAME=VALUE, e.g. parity=even (repeatable).
        #[arg(long, value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Write without asking.
        #[arg(long)]
        yes: bool,
    },
    /// Read or write raw holding registers (model unknown).
    Raw {
        #[command(flatten)]
        at: UnitArgs,
        #[command(subcommand)]
        op: RawOp,
    },
}

/// A raw register operation.
#[derive(clap::Subcommand, Debug)]
pub enum RawOp {
    /// Read COUNT registers from START (FC03).
    Read {
        #[arg(value_parser = parse_u16)]
        start: u16,
        #[arg(value_parser = parse_u16, default_value = "1")]
        count: u16,
    },
    /// Write VALUES from ADDRESS (one: FC06, more: FC16).
    Write {
        #[arg(value_parser = parse_u16)]
        address: u16,
        #[arg(value_parser = parse_u16, required = true)]
        values: Vec<u16>,
        /// Write without asking.
        #[arg(long)]
        yes: bool,
    },
}

/// A register number or value: decimal, or hex with `0x`.
pub fn parse_u16(text: &str) -> Result<u16, String> {
    let t = text.trim();
    let parsed = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(hex) => u16::from_str_radix(hex, 16),
        None => t.parse::<u16>(),
    };
    parsed.map_err(|_| {
        format!("{text:?} is not a register number or value (0..=65535 or 0x0000..=0xFFFF)")
    })
}

pub(crate) fn target(line: &LineArgs) -> Result<Target, CommissionError> {
    let parity = line.parity.as_deref().unwrap_or("none");
    Target::parse(line.port.clone(), line.host.clone(), parity)
}

/// Cancelled at Ctrl-C.
pub(crate) fn ctrl_c() -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            t.cancel();
        }
    });
    token
}

/// Output and probing choices of a scan.
pub(crate) struct ScanHow {
    pub(crate) toml: bool,
    pub(crate) json: bool,
    pub(crate) every_probe: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registers_are_decimal_or_hex() {
        assert_eq!(parse_u16("67"), Ok(67));
        assert_eq!(parse_u16("0x1160"), Ok(0x1160));
        assert!(
            parse_u16("65536").is_err() && parse_u16("-1").is_err() && parse_u16("0xG").is_err()
        );
    }
}
