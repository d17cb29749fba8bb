//! The simulated plant: modules of every supported model behind real Modbus servers
//! (tokio-modbus server side) on pseudo-terminals and TCP ports.
//!
//! Tests and the demo hold a [`Plant`] and steer it (rates, counts, power cycles, silence) while
//! the gateway talks to it over the wire like to real modules.

pub(crate) mod endpoint;
mod error;
pub mod gateway;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::Deserialize;
use tokio_util::sync::CancellationToken;

use crate::mbus::sim as mbus;
use crate::modbus::sim as modbus;

pub use endpoint::Endpoint;
use endpoint::relink;
pub use error::SimError;
pub use mbus::config::{SimMeterConfig, SimSegmentConfig};
pub use mbus::gateway::{MeterLine, every_meter};
pub use mbus::plant::PlantSegment;
pub use modbus::config::{BusConfig as SimBusConfig, SimDeviceConfig};
pub use modbus::model::SimModule;

pub use modbus::server::Modules;
use modbus::{comm, line, server};

/// The whole plant.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    #[serde(default)]
    pub buses: BTreeMap<String, modbus::config::BusConfig>,
    /// M-Bus segments (`[mbus.NAME]`).
    #[serde(default)]
    pub mbus: BTreeMap<String, mbus::config::SimSegmentConfig>,
}

impl SimConfig {
    /// Parses a simulator config.
    pub fn from_toml(text: &str) -> Result<SimConfig, error::SimError> {
        toml::from_str(text).map_err(|e| error::SimError::Config(e.to_string()))
    }
}

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

/// A running simulated plant.
pub struct Plant {
    pub buses: Vec<PlantBus>,
    /// M-Bus segments.
    pub segments: Vec<PlantSegment>,
    start: Instant,
    cancel: CancellationToken,
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
    bus: &SimBusConfig,
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
    bus: &SimBusConfig,
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

impl Plant {
    /// Builds the modules of `config` and starts serving them.
    pub async fn start(config: &SimConfig) -> Result<Plant, SimError> {
        let profiles = crate::profile::Profiles::builtin();
        let start = Instant::now();
        let cancel = CancellationToken::new();
        let mut buses = Vec::new();
        for (name, bus) in &config.buses {
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
            let (endpoint, line, wire) =
                serve(bus, &service, &cancel, seed).await.map_err(bus_err)?;
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
        let mut segments = Vec::new();
        for (name, c) in &config.mbus {
            let segment = mbus::plant::serve(name, c, start, &cancel)
                .await
                .map_err(|message| SimError::Bus {
                    bus: name.clone(),
                    message,
                })?;
            segments.push(segment);
        }
        Ok(Plant {
            buses,
            segments,
            start,
            cancel,
        })
    }

    /// An M-Bus segment by name.
    pub fn segment(&self, name: &str) -> Option<&PlantSegment> {
        self.segments.iter().find(|s| s.name == name)
    }

    /// Seconds since the plant started (the modules' clock).
    pub fn now(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// A bus by name.
    pub fn bus(&self, name: &str) -> Option<&PlantBus> {
        self.buses.iter().find(|b| b.name == name)
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
        let c = self.cancel.child_token();
        let (path, slave) =
            server::serve_pty(b.service.clone(), c.clone()).map_err(|e| err(e.to_string()))?;
        relink(&path, link).map_err(|e| err(e.to_string()))?;
        *b.wire.lock().unwrap_or_else(|e| e.into_inner()) = Some(Wire {
            cancel: c,
            _keep: Some(slave),
        });
        Ok(())
    }

    /// Stops serving.
    pub fn stop(&self) {
        self.cancel.cancel();
    }
}

impl Drop for Plant {
    fn drop(&mut self) {
        self.cancel.cancel();
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
