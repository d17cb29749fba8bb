//! `[buses.NAME]` of a Modbus bus (the default protocol): its link (with the TCP port its
//! devices' datasheets give when none is written), the guard time, the slow poll and its
//! devices of known models, a unit used once.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use config::Value;

use super::{BAUDS, Line, TCP_PORT, Unit};
use crate::config::bus::{BusParts, Checking, Device, Link};
use crate::config::parity::Parity;
use crate::config::protocols::address::Address;
use crate::config::walk::{Errors, Table, join};
use crate::profile::{MAX_TIMEOUT, Profiles};

/// What only a Modbus bus has: its link (with the TCP port its devices' datasheets give when
/// none is written), the guard time, the slow poll and its devices of known models.
pub(crate) fn bus(
    t: &mut Table<'_>,
    path: &str,
    checking: &Checking<'_>,
    errs: &mut Errors,
) -> BusParts {
    let link = bus_link(t, path, checking, errs);
    let t_origin = t.origin().map(str::to_string);
    let guard = t
        .duration_within("guard", Duration::ZERO, Duration::from_secs(1), errs)
        .unwrap_or(Duration::ZERO);
    let slow_poll = t
        .duration("slow_poll", errs)
        .unwrap_or(Duration::from_secs(60));
    let devices = bus_devices(t, path, checking.profiles, errs);
    if matches!(link, Some(Line::Tcp { .. })) {
        for d in devices.iter().filter(|d| d.baud.is_some()) {
            errs.push(
                &format!("{path}.devices.{}.baud", d.name),
                t.origin(),
                "serial setting on a TCP bus",
            );
        }
    }
    let mut link = link;
    if let Some(Line::Tcp { port, .. }) = &mut link
        && *port == 0
    {
        *port = default_tcp_port(path, &devices, t_origin.as_deref(), errs);
    }
    BusParts {
        link: link.map(Link::new),
        guard,
        slow_poll,
        devices,
    }
}

/// The bus's link: `host` (Modbus TCP) or `port` (a serial device, Modbus RTU) and its settings.
fn bus_link(
    t: &mut Table<'_>,
    path: &str,
    checking: &Checking<'_>,
    errs: &mut Errors,
) -> Option<Line> {
    let has_port = t.has("port");
    let has_host = t.has("host");
    if has_host {
        let host = t.req::<String>("host", errs);
        let port = t.int::<u16>("port", errs).unwrap_or(0);
        if port == 0 && has_port {
            errs.push(&join(path, "port"), t.origin(), "TCP port must be 1..65535");
        }
        for key in ["baud", "parity", "stop_bits"] {
            if t.has(key) {
                let _ = t.opt::<toml::Value>(key, errs);
                errs.push(&join(path, key), t.origin(), "serial setting on a TCP bus");
            }
        }
        host.map(|host| Line::Tcp { host, port })
    } else if has_port {
        let baud = t.int::<u32>("baud", errs).unwrap_or(9600);
        if !BAUDS.contains(&baud) {
            errs.push(
                &join(path, "baud"),
                t.origin(),
                format!("{baud} is not a rate the modules support ({BAUDS:?})"),
            );
        }
        let parity = t.opt::<Parity>("parity", errs).unwrap_or(Parity::None);
        let stop_bits = t.int::<u8>("stop_bits", errs).unwrap_or(1);
        if !(1..=2).contains(&stop_bits) {
            errs.push(&join(path, "stop_bits"), t.origin(), "must be 1 or 2");
        }
        let port = t.opt::<PathBuf>("port", errs).filter(|p| {
            let ok = p.is_absolute();
            if !ok {
                errs.push(
                    &join(path, "port"),
                    t.origin(),
                    "must be an absolute path such as /dev/ttyUSB0",
                );
            }
            ok
        });
        port.map(|port| Line::Rtu {
            port,
            baud,
            parity,
            stop_bits,
        })
    } else {
        let why = format!(
            "needs `port` (a serial device, Modbus RTU) or `host` (Modbus TCP), or {}",
            checking.protocols.others(checking.protocol)
        );
        errs.push(path, t.origin(), why);
        None
    }
}

/// The devices of a bus; a unit used twice is an error.
fn bus_devices(
    t: &mut Table<'_>,
    path: &str,
    profiles: &Profiles,
    errs: &mut Errors,
) -> Vec<Device> {
    let mut devices = Vec::new();
    let mut units: BTreeMap<u8, String> = BTreeMap::new();
    let entries = t.entries("devices", errs);
    if entries.is_empty() {
        errs.push(&join(path, "devices"), t.origin(), "no device on this bus");
    }
    for (dname, dvalue) in entries {
        if let Some(d) = device(path, &dname, dvalue, profiles, errs) {
            if let Some(other) = units.insert(d.unit, d.name.clone()) {
                errs.push(
                    &format!("{path}.devices.{dname}.unit"),
                    dvalue.origin(),
                    format!(
                        "unit {} is already used by device {other} on this bus",
                        d.unit
                    ),
                );
            }
            devices.push(d);
        }
    }
    devices
}

fn device(
    bus_path: &str,
    name: &str,
    value: &Value,
    profiles: &Profiles,
    errs: &mut Errors,
) -> Option<Device> {
    let path = format!("{bus_path}.devices.{name}");
    let mut t = Table::of(value, &path, errs)?;
    crate::config::names::device_name(&t, &path, name, errs);
    let unit = unit(&mut t, &path, errs);
    let model = t.req::<String>("model", errs);
    let profile = model
        .as_ref()
        .and_then(|m| device_profile(&t, &path, m, profiles, errs));
    let poll = t.duration("poll", errs).unwrap_or(Duration::from_secs(1));
    let timeout = t.duration_within("timeout", Duration::from_millis(1), MAX_TIMEOUT, errs);
    let commands = t.opt::<bool>("commands", errs).unwrap_or(true);
    let enabled = t.opt::<bool>("enabled", errs).unwrap_or(true);
    let baud = t.int::<u32>("baud", errs);
    if let (Some(b), Some(p)) = (baud, &profile)
        && !p.bauds.contains(&b)
    {
        errs.push(
            &join(&path, "baud"),
            t.origin(),
            format!(
                "model {} does not support {b} baud ({:?})",
                p.model, p.bauds
            ),
        );
    }
    let publish = crate::config::publish::policy(&mut t, errs);
    let payload = crate::config::publish::payload(&mut t, errs);
    let intervals = crate::config::metering::intervals(&mut t, errs);
    let server_unit = crate::config::outputs::device_keys(&mut t, &path, errs);
    let channels = channels(&mut t, &path, profile.as_deref(), errs);
    t.finish(errs);
    Some(Device {
        name: name.to_string(),
        unit: unit?,
        model: model?,
        profile: profile?,
        poll,
        timeout,
        commands,
        baud,
        channels,
        enabled,
        publish,
        payload,
        intervals,
        address: Address::new(Unit(unit?)),
        server_unit,
    })
}

/// A device's `unit`: required, 1..247.
fn unit(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<u8> {
    if !t.has("unit") {
        errs.push(&join(path, "unit"), t.origin(), "missing");
    }
    let u = t.int::<i64>("unit", errs)?;
    if (1..=247).contains(&u) {
        Some(u as u8)
    } else {
        let why = format!("unit {u} is outside 1..247");
        errs.push(&join(path, "unit"), t.origin(), why);
        None
    }
}

/// A device's `[….channels.NAME]` tables.
fn channels(
    t: &mut Table<'_>,
    path: &str,
    profile: Option<&crate::profile::Profile>,
    errs: &mut Errors,
) -> BTreeMap<String, crate::config::channel::ChannelConfig> {
    let mut channels = BTreeMap::new();
    for (cname, cvalue) in t.entries("channels", errs) {
        let cpath = format!("{path}.channels.{cname}");
        let Some(ct) = Table::of(cvalue, &cpath, errs) else {
            continue;
        };
        let c = crate::config::channel::channel(ct, &cname, profile, errs);
        channels.insert(cname, c);
    }
    channels
}

/// The profile of `model`; an unknown model is an error naming the known ones.
fn device_profile(
    t: &Table<'_>,
    path: &str,
    model: &str,
    profiles: &Profiles,
    errs: &mut Errors,
) -> Option<std::sync::Arc<crate::profile::Profile>> {
    let p = profiles.get(model);
    if p.is_none() {
        let known = profiles.names().join(", ");
        let why = format!("unknown model {model:?}; known: {known}");
        errs.push(&join(path, "model"), t.origin(), why);
    }
    p
}

/// The port of a TCP bus written without one: the one the devices' datasheets give (ZH-YX1600:
/// 20108), or Modbus's 502 when none gives one. Devices whose datasheets disagree need `port`.
fn default_tcp_port(
    path: &str,
    devices: &[Device],
    origin: Option<&str>,
    errs: &mut Errors,
) -> u16 {
    let given: std::collections::BTreeSet<(u16, &str)> = devices
        .iter()
        .map(|d| {
            (
                d.profile.tcp_port.unwrap_or(TCP_PORT),
                d.profile.model.as_str(),
            )
        })
        .collect();
    let ports: std::collections::BTreeSet<u16> = given.iter().map(|(p, _)| *p).collect();
    match ports.len() {
        0 => TCP_PORT,
        1 => *ports.first().expect("one"),
        _ => {
            let list: Vec<String> = given
                .iter()
                .map(|(p, m)| format!("{m} listens on {p}"))
                .collect();
            errs.push(
                &join(path, "port"),
                origin,
                format!("missing, and the datasheets disagree: {}", list.join(", ")),
            );
            TCP_PORT
        }
    }
}
