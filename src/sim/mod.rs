//! The simulated plant: modules of every supported model behind real Modbus servers
//! (tokio-modbus server side) on pseudo-terminals and TCP ports.
//!
//! Tests and the demo hold a [`Plant`] and steer it (rates, counts, power cycles, silence) while
//! the gateway talks to it over the wire like to real modules.

mod config;
pub mod model;
mod server;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use tokio_util::sync::CancellationToken;

pub use config::{SimBusConfig, SimConfig, SimDeviceConfig};
pub use model::SimModule;

/// The modules of one simulated bus, by unit id.
pub type Modules = Arc<Mutex<BTreeMap<u8, SimModule>>>;

/// Where a simulated bus can be reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A pseudo-terminal: open this path as a serial port.
    Serial(PathBuf),
    Tcp(SocketAddr),
}

/// A simulated bus.
pub struct PlantBus {
    pub name: String,
    pub endpoint: Endpoint,
    pub modules: Modules,
}

/// A running simulated plant.
pub struct Plant {
    pub buses: Vec<PlantBus>,
    start: Instant,
    cancel: CancellationToken,
    /// Pseudo-terminal slave ends kept open so the line stays up between gateway runs.
    _keep: Vec<tokio_serial::SerialStream>,
}

/// The plant could not be started.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("simulator config: {0}")]
    Config(String),
    #[error("bus {bus}: {message}")]
    Bus { bus: String, message: String },
}

impl Plant {
    /// Builds the modules of `config` and starts serving them.
    pub async fn start(config: &SimConfig) -> Result<Plant, SimError> {
        let profiles = crate::profile::Profiles::builtin();
        let start = Instant::now();
        let cancel = CancellationToken::new();
        let mut buses = Vec::new();
        let mut keep = Vec::new();
        for (name, bus) in &config.buses {
            let bus_err = |message: String| SimError::Bus {
                bus: name.clone(),
                message,
            };
            let mut modules = BTreeMap::new();
            for (dname, d) in &bus.devices {
                let profile = profiles
                    .get(&d.model)
                    .ok_or_else(|| bus_err(format!("device {dname}: unknown model {}", d.model)))?;
                let mut m = SimModule::new(profile, &d.modes)
                    .map_err(|e| bus_err(format!("device {dname}: {e}")))?;
                for (cname, c) in &d.channels {
                    if m.channel(cname).is_none() {
                        return Err(bus_err(format!(
                            "device {dname}: no channel {cname} in this mode"
                        )));
                    }
                    m.set_count(0.0, cname, c.count);
                    m.set_rate(0.0, cname, c.rate);
                    if let Some(ppr) = c.ppr {
                        m.set_ppr(cname, ppr);
                    }
                }
                m.silent = d.silent;
                if modules.insert(d.unit, m).is_some() {
                    return Err(bus_err(format!("unit {} used twice", d.unit)));
                }
            }
            let modules: Modules = Arc::new(Mutex::new(modules));
            let service = server::SimService::new(modules.clone(), start);
            let endpoint = match (&bus.listen, &bus.link) {
                (Some(addr), None) => {
                    let addr = server::serve_tcp(*addr, service, cancel.clone())
                        .await
                        .map_err(|e| bus_err(format!("cannot listen on {addr}: {e}")))?;
                    Endpoint::Tcp(addr)
                }
                (None, link) => {
                    let (path, slave) = server::serve_pty(service, cancel.clone())
                        .map_err(|e| bus_err(format!("cannot create a pseudo-terminal: {e}")))?;
                    keep.push(slave);
                    let path = match link {
                        Some(link) => {
                            let _ = std::fs::remove_file(link);
                            if let Some(dir) = link.parent() {
                                let _ = std::fs::create_dir_all(dir);
                            }
                            std::os::unix::fs::symlink(&path, link).map_err(|e| {
                                bus_err(format!("cannot link {}: {e}", link.display()))
                            })?;
                            link.clone()
                        }
                        None => path,
                    };
                    Endpoint::Serial(path)
                }
                (Some(_), Some(_)) => {
                    return Err(bus_err(
                        "give either `link` (serial) or `listen` (TCP), not both".into(),
                    ));
                }
            };
            buses.push(PlantBus {
                name: name.clone(),
                endpoint,
                modules,
            });
        }
        Ok(Plant {
            buses,
            start,
            cancel,
            _keep: keep,
        })
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
