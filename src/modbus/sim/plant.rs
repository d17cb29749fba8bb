//! The plant's Modbus buses: modules of every supported model behind real Modbus servers
//! (tokio-modbus server side) on pseudo-terminals and TCP ports, started from sim.toml's
//! `[buses.NAME]` tables ([`Buses`], a part of the [`Plant`]), and what tests ask of them
//! (a bus, a module, a power cycle, an adapter pulled and plugged back).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use tokio_util::sync::CancellationToken;

use super::comm;
use super::config::{BusConfig, SimDeviceConfig};
use super::line;
use super::model::SimModule;
use super::server;
use super::server::Modules;
use crate::sim::gateway::DeviceLine;
use crate::sim::{Endpoint, Part, Plant, SimConfig, SimError, relink};

/// sim.toml's Modbus buses (`[buses.NAME]`), the plant's config part.
pub type BusTables = BTreeMap<String, BusConfig>;

/// A simulated bus.
pub struct PlantBus {
    pub name: String,
    pub endpoint: Endpoint,
    pub modules: Modules,
    /// The line emulator between gateway and modules, where the bus has one.
    pub line: Option<line::Line>,
    wire: Mutex<Option<Wire>>,
    service: server::SimService,
    link: Option<PathBuf>,
}

/// The serving end of a pseudo-terminal bus: dropping it unplugs the adapter.
struct Wire {
    cancel: CancellationToken,
    _keep: Option<serialport::TTYPort>,
}

impl Drop for Wire {
    fn drop(&mut self) {
        self.cancel.cancel();
    }
}

/// The plant's Modbus buses, one of its parts.
pub struct Buses(pub Vec<PlantBus>);

impl Part for Buses {
    fn endpoints(&self) -> Vec<String> {
        self.0
            .iter()
            .map(|bus| format!("bus {}: {:?}", bus.name, bus.endpoint))
            .collect()
    }
}

/// One simulated module of a device's config, in its datasheet factory state plus what the
/// config sets.
fn build_module(
    profiles: &crate::profile::Profiles,
    dname: &str,
    d: &SimDeviceConfig,
) -> Result<SimModule, String> {
    let profile = profiles
        .get(&d.model)
        .ok_or_else(|| format!("device {dname}: unknown model {}", d.model))?;
    let mut m = SimModule::new(profile, &d.modes).map_err(|e| format!("device {dname}: {e}"))?;
    for (cname, c) in &d.channels {
        if m.channel(cname).is_none() {
            return Err(format!("device {dname}: no channel {cname} in this mode"));
        }
        m.set_count(0.0, cname, c.count);
        m.set_rate(0.0, cname, c.rate);
        if let Some(ppr) = c.ppr {
            m.set_ppr(cname, ppr);
        }
    }
    m.silent = d.silent;
    m.nonsense = d.nonsense;
    m.answer_delay = d.answer_delay.unwrap_or_default();
    comm::install(&mut m, d.unit, d.baud.unwrap_or(9600))
        .map_err(|e| format!("device {dname}: {e}"))?;
    m.baud = d.baud;
    m.silent_on_unknown = d.silent_on_unknown;
    Ok(m)
}

/// Serves a bus's modules over TCP, a line emulator or a bare pseudo-terminal.
async fn serve(
    bus: &BusConfig,
    service: &server::SimService,
    cancel: &CancellationToken,
    seed: u64,
) -> Result<(Endpoint, Option<line::Line>, Option<Wire>), String> {
    match (&bus.listen, &bus.link) {
        (Some(addr), None) => {
            let addr = server::serve_tcp(*addr, service.clone(), cancel.clone())
                .await
                .map_err(|e| format!("cannot listen on {addr}: {e}"))?;
            Ok((Endpoint::Tcp(addr), None, None))
        }
        (None, link) => {
            let (path, line, wire) = serial(bus, service, cancel, seed)?;
            let endpoint = match link {
                Some(link) => {
                    relink(&path, link)
                        .map_err(|e| format!("cannot link {}: {e}", link.display()))?;
                    Endpoint::Serial(link.clone())
                }
                None => Endpoint::Serial(path),
            };
            Ok((endpoint, line, Some(wire)))
        }
        (Some(_), Some(_)) => Err("give either `link` (serial) or `listen` (TCP), not both".into()),
    }
}

/// The serial side: the path the gateway opens, the line emulator if the bus has one.
fn serial(
    bus: &BusConfig,
    service: &server::SimService,
    cancel: &CancellationToken,
    seed: u64,
) -> Result<(PathBuf, Option<line::Line>, Wire), String> {
    let c = cancel.child_token();
    match bus.line {
        Some(spec) => {
            let (l, module_path) = line::Line::start(spec, seed)
                .map_err(|e| format!("cannot start the line emulator: {e}"))?;
            let port = serialport::new(module_path.display().to_string(), spec.baud)
                .open_native()
                .map(server::private)
                .map_err(|e| format!("cannot open {}: {e}", module_path.display()))?;
            server::serve_port(port, service.clone(), c.clone());
            let wire = Wire {
                cancel: c,
                _keep: None,
            };
            Ok((l.gateway_path.clone(), Some(l), wire))
        }
        None => {
            let (path, slave) = server::serve_pty(service.clone(), c.clone())
                .map_err(|e| format!("cannot create a pseudo-terminal: {e}"))?;
            let wire = Wire {
                cancel: c,
                _keep: Some(slave),
            };
            Ok((path, None, wire))
        }
    }
}

/// Builds the modules of sim.toml's Modbus buses and starts serving them, on the plant's clock
/// (`start`) until `cancel`.
pub async fn start(
    tables: &BusTables,
    start: Instant,
    cancel: &CancellationToken,
) -> Result<Buses, SimError> {
    let profiles = crate::profile::Profiles::builtin();
    let mut buses = Vec::new();
    for (name, bus) in tables {
        let bus_err = |message: String| SimError::Bus {
            bus: name.clone(),
            message,
        };
        let mut modules = BTreeMap::new();
        for (dname, d) in &bus.devices {
            let m = build_module(&profiles, dname, d).map_err(bus_err)?;
            if modules.insert(d.unit, m).is_some() {
                return Err(bus_err(format!("unit {} used twice", d.unit)));
            }
        }
        let modules: Modules = Arc::new(Mutex::new(modules));
        let service = server::SimService::new(modules.clone(), start);
        let seed = 0x5EED ^ buses.len() as u64;
        let (endpoint, line, wire) = serve(bus, &service, cancel, seed).await.map_err(bus_err)?;
        buses.push(PlantBus {
            name: name.clone(),
            endpoint,
            modules,
            line,
            wire: Mutex::new(wire),
            service,
            link: bus.link.clone(),
        });
    }
    Ok(Buses(buses))
}

impl Plant {
    /// A Modbus bus by name.
    pub fn bus(&self, name: &str) -> Option<&PlantBus> {
        self.part::<Buses>()?.0.iter().find(|b| b.name == name)
    }

    /// Every Modbus bus.
    pub fn buses(&self) -> &[PlantBus] {
        self.part::<Buses>().map_or(&[], |b| &b.0)
    }

    /// Runs `f` on a module with the plant's current time.
    pub fn with_module<R>(
        &self,
        bus: &str,
        unit: u8,
        f: impl FnOnce(&mut SimModule, f64) -> R,
    ) -> Option<R> {
        let now = self.now();
        let b = self.bus(bus)?;
        let mut modules = b.modules.lock().unwrap_or_else(|e| e.into_inner());
        modules.get_mut(&unit).map(|m| f(m, now))
    }

    /// Pulls the bus's USB adapter: its pseudo-terminal disappears, and so does its link.
    pub fn unplug(&self, bus: &str) {
        if let Some(b) = self.bus(bus) {
            b.wire.lock().unwrap_or_else(|e| e.into_inner()).take();
            if let Some(link) = &b.link {
                let _ = std::fs::remove_file(link);
            }
        }
    }

    /// Plugs the adapter back: a new pseudo-terminal behind the same link.
    pub fn plug(&self, bus: &str) -> Result<(), SimError> {
        let b = self
            .bus(bus)
            .ok_or_else(|| SimError::Config(format!("no bus {bus}")))?;
        let err = |message: String| SimError::Bus {
            bus: bus.into(),
            message,
        };
        let link = b
            .link
            .as_ref()
            .ok_or_else(|| err("only a bus with a `link` can be plugged back".into()))?;
        let c = self.cancel().child_token();
        let (path, slave) =
            server::serve_pty(b.service.clone(), c.clone()).map_err(|e| err(e.to_string()))?;
        relink(&path, link).map_err(|e| err(e.to_string()))?;
        *b.wire.lock().unwrap_or_else(|e| e.into_inner()) = Some(Wire {
            cancel: c,
            _keep: Some(slave),
        });
        Ok(())
    }
}

impl Plant {
    /// Power loss and return of one module: counts it does not keep go, and it comes back with
    /// the address and baud rate in its registers (and a ZH-YX1600's counters in the run state
    /// of their pAuto bits: `SimModule::power_cycle`). Returns the unit it answers at afterwards.
    pub fn power_cycle(&self, bus: &str, unit: u8) -> Result<u8, SimError> {
        let now = self.now();
        let b = self
            .bus(bus)
            .ok_or_else(|| SimError::Config(format!("no bus {bus}")))?;
        let mut modules = b.modules.lock().unwrap_or_else(|e| e.into_inner());
        let m = modules.get_mut(&unit).ok_or_else(|| SimError::Bus {
            bus: bus.into(),
            message: format!("no module at unit {unit}"),
        })?;
        m.power_cycle(now);
        if let Some(regs) = comm::registers(&m.profile.model) {
            if let Some(baud) = m.stored(regs.baud).and_then(|c| regs.baud_of(c)) {
                m.baud = Some(baud);
            }
        }
        Ok(comm::move_to_stored_unit(&mut modules, unit).unwrap_or(unit))
    }
}

impl SimConfig {
    /// Every device of the plant's Modbus buses, each polled every `poll`.
    pub fn every_device<'a>(&'a self, poll: &'a str) -> Vec<DeviceLine<'a>> {
        every_device(self, poll)
    }

    /// The plant's Modbus buses (`[buses.NAME]`), to change before it starts.
    pub fn buses_mut(&mut self) -> Option<&mut BusTables> {
        self.part_mut::<BusTables>()
    }
}

/// Every device of a plant's config, each polled every `poll`.
pub fn every_device<'a>(sim: &'a SimConfig, poll: &'a str) -> Vec<DeviceLine<'a>> {
    sim.part::<BusTables>()
        .into_iter()
        .flatten()
        .flat_map(|(bus, b)| {
            b.devices
                .iter()
                .map(move |(name, d)| (bus.as_str(), name.as_str(), d.unit, d.model.as_str(), poll))
        })
        .collect()
}
