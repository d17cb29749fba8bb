//! The M-Bus buses of the gateway's config for a running plant (beside
//! [`GatewayToml::render`]'s Modbus buses): each segment its converter, each meter its address.

use super::plant::SegmentTables;
use crate::sim::gateway::GatewayToml;
use crate::sim::{Endpoint, Plant, SimConfig};

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

impl SimConfig {
    /// Every meter of a plant's config, each read every `poll`, by its own name.
    pub fn every_meter<'a>(&'a self, poll: &'a str) -> Vec<MeterLine<'a>> {
        every_meter(self, poll)
    }
}

/// Every meter of a plant's config, each read every `poll`, by its own name.
pub fn every_meter<'a>(sim: &'a SimConfig, poll: &'a str) -> Vec<MeterLine<'a>> {
    sim.part::<SegmentTables>()
        .into_iter()
        .flatten()
        .flat_map(|(seg, s)| {
            s.meters
                .keys()
                .map(move |m| (seg.as_str(), m.as_str(), m.as_str(), poll))
        })
        .collect()
}
