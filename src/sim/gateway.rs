//! The gateway's config for a running plant: the one generator behind the demo, the
//! integration tests and the benchmark. Each bus gets its endpoint (the pseudo-terminal or the
//! TCP address the plant serves it on) and each device its unit, model and poll interval; what
//! differs between the callers (ids, timeouts, extra keys) is given, not rewritten.

use std::path::Path;

use super::{Endpoint, Plant};

/// A device the gateway polls: bus, device name, unit, model, poll interval.
pub type DeviceLine<'a> = (&'a str, &'a str, u8, &'a str, &'a str);

/// What the caller decides about the gateway's config.
#[derive(Debug, Clone, Copy)]
pub struct GatewayToml<'a> {
    pub id: &'a str,
    pub state_dir: &'a Path,
    /// Extra `[gateway]` keys, one per line.
    pub gateway: &'a str,
    pub mqtt_host: &'a str,
    pub mqtt_port: Option<u16>,
    /// Extra `[mqtt]` keys.
    pub mqtt: &'a str,
    /// Extra keys of every serial bus (baud, timeouts).
    pub serial: &'a str,
    /// Extra keys of every TCP bus.
    pub tcp: &'a str,
}

impl GatewayToml<'_> {
    /// The config text for `devices` of `plant`, buses in name order.
    pub fn render(&self, plant: &Plant, devices: &[DeviceLine<'_>]) -> String {
        let mut t = format!(
            "[gateway]\nid = {:?}\nstate_dir = {:?}\n{}\n[mqtt]\nhost = {:?}\n",
            self.id, self.state_dir, self.gateway, self.mqtt_host
        );
        if let Some(port) = self.mqtt_port {
            t += &format!("port = {port}\n");
        }
        t += self.mqtt;
        t += "\n";
        let mut buses: Vec<&str> = devices.iter().map(|d| d.0).collect();
        buses.sort_unstable();
        buses.dedup();
        for bus in buses {
            let endpoint = &plant.bus(bus).expect("bus in plant").endpoint;
            t += &match endpoint {
                Endpoint::Serial(p) => format!("[buses.{bus}]\nport = {p:?}\n{}", self.serial),
                Endpoint::Tcp(a) => format!(
                    "[buses.{bus}]\nhost = \"{}\"\nport = {}\n{}",
                    a.ip(),
                    a.port(),
                    self.tcp
                ),
            };
            for (_, name, unit, model, poll) in devices.iter().filter(|d| d.0 == bus) {
                t += &format!(
                    "[buses.{bus}.devices.{name}]\nunit = {unit}\nmodel = {model:?}\npoll = {poll:?}\n"
                );
            }
            t += "\n";
        }
        t
    }
}
