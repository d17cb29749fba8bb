//! The gateway's config for a running plant: the one generator behind the demo, the
//! integration tests and the benchmark. Each bus gets its endpoint (the pseudo-terminal or the
//! TCP address the plant serves it on) and each device its unit, model and poll interval; what
//! differs between the callers (ids, timeouts, extra keys) is given, not rewritten.

use std::path::Path;

use super::{Endpoint, Plant, SimConfig};

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

/// An M-Bus meter the gateway reads: segment, device name, meter name in the plant, poll
/// interval.
pub type MeterLine<'a> = (&'a str, &'a str, &'a str, &'a str);

impl GatewayToml<'_> {
    /// The M-Bus buses of `meters` of `plant` (to add to [`GatewayToml::render`]'s text), in
    /// segment order: each segment its converter (the TCP address, or the pseudo-terminal at
    /// its baud rate, even parity), each meter its primary address, or its id where another
    /// meter of the segment shares that address. `extra`: keys added to every M-Bus bus.
    pub fn meters(&self, plant: &Plant, meters: &[MeterLine<'_>], extra: &str) -> String {
        let mut t = String::new();
        let mut segments: Vec<&str> = meters.iter().map(|m| m.0).collect();
        segments.sort_unstable();
        segments.dedup();
        for name in segments {
            let seg = plant.segment(name).expect("segment in plant");
            t += &format!("[buses.{name}]\nprotocol = \"mbus\"\n");
            t += &match (&seg.endpoint, seg.baud) {
                (Endpoint::Serial(p), baud) => {
                    format!(
                        "port = {p:?}\nbaud = {}\nparity = \"even\"\n",
                        baud.unwrap_or(2400)
                    )
                }
                (Endpoint::Tcp(a), _) => format!("host = \"{a}\"\n"),
            };
            t += extra;
            t += "\n";
            for (_, device, meter, poll) in meters.iter().filter(|m| m.0 == name) {
                t += &format!("[buses.{name}.devices.{device}]\npoll = {poll:?}\n");
                t += &match seg.primary_of(meter) {
                    Some(a) => format!("address = {a}\n"),
                    None => format!("id = \"{:08}\"\n", seg.id_of(meter).expect("meter")),
                };
            }
            t += "\n";
        }
        t
    }
}

/// Every meter of a plant's config, each read every `poll`, by its own name.
pub fn every_meter<'a>(sim: &'a SimConfig, poll: &'a str) -> Vec<MeterLine<'a>> {
    sim.mbus
        .iter()
        .flat_map(|(seg, s)| {
            s.meters
                .keys()
                .map(move |m| (seg.as_str(), m.as_str(), m.as_str(), poll))
        })
        .collect()
}

/// Every device of a plant's config, each polled every `poll`.
pub fn every_device<'a>(sim: &'a SimConfig, poll: &'a str) -> Vec<DeviceLine<'a>> {
    sim.buses
        .iter()
        .flat_map(|(bus, b)| {
            b.devices
                .iter()
                .map(move |(name, d)| (bus.as_str(), name.as_str(), d.unit, d.model.as_str(), poll))
        })
        .collect()
}
