//! The protocols, registered in one place above the layers they implement. Each protocol is a
//! folder of its own (`modbus/`, `mbus/`, declared in `lib.rs`) with a part per layer, each at
//! that layer's floor (its config, driver, commissioning, simulator, and a serving output if it
//! brings one); this file is where the gateway picks a bus's driver, runs a commissioning
//! command, starts the serving outputs (and names their metric families), reads sim.toml's
//! tables and starts a simulated plant's parts, by protocol. The config floor keeps two
//! registries below this one (`config/protocols/mod.rs`: `Protocol`, a bus's `Link`, a device's
//! `Address`, the serving outputs' `Servers`; `config/buses.rs`: a bus's checks and words, the
//! register map), as the config cannot call up to the drivers. A new protocol is its folder, a
//! line in `lib.rs` and the arms the compiler asks for in the three registries.

use std::collections::BTreeMap;
use std::process::ExitCode;
use std::time::Instant;

use serde::Deserialize;
use tokio::sync::mpsc::Receiver;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use crate::bus::BusTask;
use crate::command::Op;
use crate::commission::cli::ScanHow;
use crate::commission::{Commission, CommissionError, LineArgs};
use crate::config::{Bus, Config, Link, Protocol};
use crate::health::Heart;
use crate::mbus::commission::commands as on_mbus;
use crate::mbus::driver::master::Mbus;
use crate::mbus::sim::config::SimSegmentConfig;
use crate::mbus::sim::plant as mbus_sim;
use crate::metrics::OutputMetrics;
use crate::modbus::commission::commands as on_modbus;
use crate::modbus::driver::{Modbus, QUIET_LIBRARY};
use crate::modbus::server::metrics::SERVER;
use crate::modbus::sim::config::BusConfig;
use crate::modbus::sim::plant as modbus_sim;
use crate::profile::Profiles;
use crate::publish::Server;
use crate::scan::ScanRequest;
use crate::sim::{Part, Plant, SimConfig, SimError};

/// The log filter that keeps the protocol libraries' own logs to their errors (a late or
/// garbled answer is the driver's to count and say, not the library's to log at each frame).
pub const QUIET_LIBRARIES: &str = QUIET_LIBRARY;

/// The metric families of the serving outputs (names and help texts), registered with the
/// others when the metrics start.
pub const SERVER_FAMILIES: [(&str, &str); 3] = SERVER;

/// Runs `task` over the driver of `bus`'s link until `shutdown`.
pub fn spawn(
    task: BusTask,
    bus: &Bus,
    scans: Receiver<ScanRequest>,
    shutdown: CancellationToken,
) -> JoinHandle<()> {
    match &bus.link {
        Link::Modbus(line) => {
            let driver = Modbus::for_bus(bus, line).with_scans(Some(scans));
            tokio::spawn(task.run(driver, shutdown))
        }
        Link::Mbus(line) => {
            let driver = Mbus::for_bus(bus, line).with_scans(Some(scans));
            tokio::spawn(task.run(driver, shutdown))
        }
    }
}

/// Every serving output of `config`, each with the heart and metrics `parts` gives its name.
pub fn servers(
    config: &Config,
    parts: impl Fn(&str) -> (Heart, OutputMetrics),
) -> Vec<Box<dyn Server>> {
    crate::modbus::server::servers(config, parts)
}

/// Runs a commissioning command; prints errors and returns the exit status.
pub async fn commission(command: Commission) -> ExitCode {
    match commission_inner(command).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

async fn commission_inner(command: Commission) -> Result<(), CommissionError> {
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
            Protocol::Mbus => on_mbus::read_meter(&module.at, address, id.as_deref(), json).await,
            Protocol::Modbus => on_modbus::read(&module, json, watch, &profiles).await,
        },
        Commission::Clear { module, channel } => {
            on_modbus::write_count(&module, &channel, Op::Clear, &profiles).await
        }
        Commission::Preset {
            module,
            channel,
            value,
        } => on_modbus::write_count(&module, &channel, Op::Preset(value), &profiles).await,
        Commission::Setup {
            module,
            new_unit,
            new_baud,
            power_on,
            ppr,
            set,
            yes,
        } => {
            let wanted = on_modbus::wanted(new_unit, new_baud, power_on, &ppr, &set)?;
            on_modbus::setup(&module, &wanted, yes, &profiles).await
        }
        Commission::Raw { at, op } => {
            on_modbus::raw(&at.line, at.baud(), at.unit()?, op, &profiles).await
        }
    }
}

/// `scan` by its protocol: a Modbus line's units, or an M-Bus segment's meters.
async fn scan(
    protocol: Protocol,
    line: &LineArgs,
    secondary: bool,
    (baud, units): (Option<String>, Option<String>),
    how: ScanHow,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    match protocol {
        Protocol::Mbus => on_mbus::scan_meters(line, baud, units, secondary, how).await,
        Protocol::Modbus if secondary => Err(CommissionError::BadInput(format!(
            "--secondary is {}'s search: give --protocol {}",
            Protocol::Mbus.title(),
            Protocol::Mbus
        ))),
        Protocol::Modbus => {
            let baud = baud.unwrap_or_else(|| "9600".into());
            let units = units.unwrap_or_else(|| "1-247".into());
            on_modbus::scan(line, &baud, &units, how, profiles).await
        }
    }
}

/// sim.toml: each protocol's tables (`[buses.NAME]` Modbus buses, the default; `[mbus.NAME]`
/// M-Bus segments).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SimTables {
    #[serde(default)]
    buses: BTreeMap<String, BusConfig>,
    #[serde(default)]
    mbus: BTreeMap<String, SimSegmentConfig>,
}

impl SimConfig {
    /// Parses a simulator config: each protocol's tables, for its folder to start.
    pub fn from_toml(text: &str) -> Result<SimConfig, SimError> {
        let t: SimTables = toml::from_str(text).map_err(|e| SimError::Config(e.to_string()))?;
        Ok(SimConfig::of(vec![Box::new(t.buses), Box::new(t.mbus)]))
    }
}

impl Plant {
    /// Builds each protocol's part of `config` and starts serving them.
    pub async fn start(config: &SimConfig) -> Result<Plant, SimError> {
        let start = Instant::now();
        let cancel = CancellationToken::new();
        let mut parts: Vec<Box<dyn Part>> = Vec::new();
        if let Some(tables) = config.part() {
            parts.push(Box::new(modbus_sim::start(tables, start, &cancel).await?));
        }
        if let Some(tables) = config.part() {
            parts.push(Box::new(mbus_sim::start(tables, start, &cancel).await?));
        }
        Ok(Plant::of(parts, start, cancel))
    }
}
