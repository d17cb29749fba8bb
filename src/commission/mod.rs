//! Commissioning: survey a line before a config exists, one folder per protocol; `cli.rs` says
//! what a command asks, this file runs it by its protocol. Modbus (`modbus/`): find the units
//! that answer and their models (`scan`), read one module as the gateway would (`read`), clear
//! or preset a channel, change the settings its datasheet documents (`setup`), and read or
//! write raw registers. M-Bus segments (`mbus/`): find the meters (primary addresses, or the
//! wildcard search) and read one meter's answer.
//!
//! Everything here reuses the gateway's parts: the profiles (identification, settings,
//! channels), the link layer (timeouts, late answers, exclusive port) and the device poller
//! (decoding, clear and preset with read-back). Bad input is refused before anything is
//! written.

mod cli;
mod error;
mod holder;
pub mod mbus;
pub(crate) mod modbus;
pub(crate) mod target;

pub use cli::Commission;
pub use error::CommissionError;
pub use holder::{Holder, holders};

pub use modbus::scan::scan_bauds;
pub use modbus::snippet::config_snippet;

use std::process::ExitCode;

use crate::command::Op;
use crate::config::Protocol;
use crate::profile::Profiles;
use cli::ScanHow;

/// Runs a commissioning command; prints errors and returns the exit status.
pub async fn run(command: Commission) -> ExitCode {
    match run_inner(command).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

async fn run_inner(command: Commission) -> Result<(), CommissionError> {
    let profiles = Profiles::builtin();
    match command {
        Commission::Scan {
            line,
            protocol,
            secondary,
            baud,
            units,
            toml,
            json,
            every_probe,
        } => {
            let how = ScanHow {
                toml,
                json,
                every_probe,
            };
            scan(protocol, &line, secondary, (baud, units), how, &profiles).await
        }
        Commission::Read {
            module,
            protocol,
            address,
            id,
            json,
            watch,
        } => match protocol {
            Protocol::Mbus => {
                mbus::commands::read_meter(&module.at, address, id.as_deref(), json).await
            }
            Protocol::Modbus => modbus::commands::read(&module, json, watch, &profiles).await,
        },
        Commission::Clear { module, channel } => {
            modbus::commands::write_count(&module, &channel, Op::Clear, &profiles).await
        }
        Commission::Preset {
            module,
            channel,
            value,
        } => modbus::commands::write_count(&module, &channel, Op::Preset(value), &profiles).await,
        Commission::Setup {
            module,
            new_unit,
            new_baud,
            power_on,
            ppr,
            set,
            yes,
        } => {
            let wanted = modbus::commands::wanted(new_unit, new_baud, power_on, &ppr, &set)?;
            modbus::commands::setup(&module, &wanted, yes, &profiles).await
        }
        Commission::Raw { at, op } => {
            modbus::commands::raw(&at.line, at.baud(), at.unit()?, op, &profiles).await
        }
    }
}

/// `scan` by its protocol: a Modbus line's units, or an M-Bus segment's meters.
async fn scan(
    protocol: Protocol,
    line: &cli::LineArgs,
    secondary: bool,
    (baud, units): (Option<String>, Option<String>),
    how: ScanHow,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    match protocol {
        Protocol::Mbus => mbus::commands::scan_meters(line, baud, units, secondary, how).await,
        Protocol::Modbus if secondary => Err(CommissionError::BadInput(format!(
            "--secondary is {}'s search: give --protocol {}",
            Protocol::Mbus.title(),
            Protocol::Mbus
        ))),
        Protocol::Modbus => {
            let baud = baud.unwrap_or_else(|| "9600".into());
            let units = units.unwrap_or_else(|| "1-247".into());
            modbus::commands::scan(line, &baud, &units, how, profiles).await
        }
    }
}
