//! The protocols, registered in one place above the layers they implement. Each protocol is a
//! folder of its own (`modbus/`, `mbus/`, declared in `lib.rs`) with a part per layer, each at
//! that layer's floor (its config, driver, commissioning, simulator, and a serving output if it
//! brings one). [`STANDARD`] is the one list of the protocols a bus may speak: an [`Entry`] is a
//! protocol's config part (its [`Protocol`], which checks `[buses.NAME]` and gives the bus's
//! link and its devices' addresses as its own types) and its driver ([`Spawn`]); the config is
//! checked against this list ([`Registry::protocols`], handed down as output kinds are), so a
//! protocol left out of it can neither be parsed nor run. A new protocol is its folder and one
//! line here (and in `lib.rs`); a test adds a toy one with [`Registry::with`]
//! (`toy_protocol_tests.rs`). This file also runs a commissioning command, starts the serving
//! outputs (and names their metric families), reads sim.toml's tables and starts a simulated
//! plant's parts, for the protocols that have them, and checks a config against both
//! registries (`Config::load`). The config floor keeps what it must below this one
//! (`config/protocols/mod.rs`: the serving outputs' `Servers`; `config/buses.rs`: their
//! register map), as the config cannot call up.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
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
use crate::config::{Bus, Config, ConfigErrors, Known, Protocol, Protocols};
use crate::health::Heart;
use crate::mbus::commission::commands as on_mbus;
use crate::mbus::sim::config::SimSegmentConfig;
use crate::mbus::sim::plant as mbus_sim;
use crate::metrics::OutputMetrics;
use crate::modbus::commission::commands as on_modbus;
use crate::modbus::driver::QUIET_LIBRARY;
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

/// Runs `task` over a protocol's driver on `bus`'s line until `shutdown`; `None` when the bus's
/// link is not that protocol's.
pub type Spawn =
    fn(BusTask, &Bus, Receiver<ScanRequest>, CancellationToken) -> Option<JoinHandle<()>>;

/// One protocol: its part of the config and its driver.
#[derive(Clone, Copy)]
pub struct Entry {
    pub protocol: Protocol,
    pub spawn: Spawn,
}

/// The protocols a bus may speak, one line each; the first is the default
/// (`Protocol::DEFAULT`), and an error lists them in this order.
pub static STANDARD: &[Entry] = &[
    Entry {
        protocol: crate::modbus::config::protocol::PROTOCOL,
        spawn: crate::modbus::driver::spawn,
    },
    Entry {
        protocol: crate::mbus::config::protocol::PROTOCOL,
        spawn: crate::mbus::driver::master::spawn,
    },
];

/// A list of protocols: the gateway's ([`Registry::standard`]), or more (a test's own).
#[derive(Clone)]
pub struct Registry(Vec<Entry>);

impl Registry {
    /// The gateway's protocols.
    pub fn standard() -> Registry {
        Registry(STANDARD.to_vec())
    }

    /// These protocols and `entry`, whose name none of them has.
    pub fn with(mut self, entry: Entry) -> Registry {
        let name = entry.protocol.name();
        assert!(
            self.0.iter().all(|e| e.protocol != entry.protocol),
            "two protocols named {name:?}"
        );
        self.0.push(entry);
        self
    }

    /// What the config checks `protocol` against.
    pub fn protocols(&self) -> Protocols {
        Protocols::new(self.0.iter().map(|e| e.protocol).collect())
    }

    /// Runs `task` over the driver of `bus`'s protocol until `shutdown`.
    pub fn spawn(
        &self,
        task: BusTask,
        bus: &Bus,
        scans: Receiver<ScanRequest>,
        shutdown: CancellationToken,
    ) -> JoinHandle<()> {
        let protocol = bus.link.protocol();
        let entry = self.0.iter().find(|e| e.protocol == protocol);
        if let Some(running) = entry.and_then(|e| (e.spawn)(task, bus, scans, shutdown)) {
            return running;
        }
        let bus = bus.name.clone();
        tokio::spawn(async move {
            tracing::error!(%bus, %protocol, "no driver for the bus's protocol: it is not polled");
        })
    }
}

/// Runs `task` over the driver of `bus`'s link until `shutdown`, by the gateway's registry.
pub fn spawn(
    task: BusTask,
    bus: &Bus,
    scans: Receiver<ScanRequest>,
    shutdown: CancellationToken,
) -> JoinHandle<()> {
    Registry::standard().spawn(task, bus, scans, shutdown)
}

/// The config checked against the gateway's registries: its output kinds and its protocols.
impl Config {
    /// What the gateway's own config is checked against.
    pub fn known() -> Known {
        Known {
            kinds: crate::publish::formats::Registry::standard().kinds(),
            protocols: Registry::standard().protocols(),
        }
    }

    /// Reads and checks `path`, with `PULSEGATE__…` overrides from the process environment.
    pub fn load(path: &Path) -> Result<Config, ConfigErrors> {
        Self::load_with(path, None, &Self::known())
    }

    /// Like [`Config::load`], with the environment given (for tests).
    pub fn load_with_env(
        path: &Path,
        env: Option<HashMap<String, String>>,
    ) -> Result<Config, ConfigErrors> {
        Self::load_with(path, env, &Self::known())
    }

    /// Checks TOML text as if it had been read from `path`.
    pub fn from_toml(
        text: &str,
        path: &Path,
        env: Option<HashMap<String, String>>,
    ) -> Result<Config, ConfigErrors> {
        Self::from_toml_with(text, path, env, &Self::known())
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
            let protocol = commissioned(&protocol)?;
            scan(protocol, &line, secondary, (baud, units), how, &profiles).await
        }
        Commission::Read {
            module,
            protocol,
            address,
            id,
            json,
            watch,
        } => match commissioned(&protocol)? {
            Commissioned::Mbus => {
                on_mbus::read_meter(&module.at, address, id.as_deref(), json).await
            }
            Commissioned::Modbus => on_modbus::read(&module, json, watch, &profiles).await,
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

/// The protocols that have commissioning commands.
enum Commissioned {
    Modbus,
    Mbus,
}

/// The protocol `--protocol` names, if it has commissioning commands.
fn commissioned(name: &str) -> Result<Commissioned, CommissionError> {
    let protocol = Registry::standard().protocols().find(name);
    match protocol.map_err(CommissionError::BadInput)? {
        p if p == crate::modbus::config::protocol::PROTOCOL => Ok(Commissioned::Modbus),
        p if p == crate::mbus::config::protocol::PROTOCOL => Ok(Commissioned::Mbus),
        p => Err(CommissionError::BadInput(format!(
            "{} has no commissioning commands",
            p.title()
        ))),
    }
}

/// `scan` by its protocol: a Modbus line's units, or an M-Bus segment's meters.
async fn scan(
    protocol: Commissioned,
    line: &LineArgs,
    secondary: bool,
    (baud, units): (Option<String>, Option<String>),
    how: ScanHow,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let mbus = crate::mbus::config::protocol::PROTOCOL;
    match protocol {
        Commissioned::Mbus => on_mbus::scan_meters(line, baud, units, secondary, how).await,
        Commissioned::Modbus if secondary => Err(CommissionError::BadInput(format!(
            "--secondary is {}'s search: give --protocol {mbus}",
            mbus.title(),
        ))),
        Commissioned::Modbus => {
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
