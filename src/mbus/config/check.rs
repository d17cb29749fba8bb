//! `[buses.NAME] protocol = "mbus"`: an M-Bus bus (a serial level converter at `port`, or an
//! M-Bus-to-Ethernet converter at `host = "HOST:PORT"`) and its meters (`address = N` or
//! `id = "12345678"` with `manufacturer`, `version` and `medium` optional), checked into the
//! same typed [`Bus`](crate::config::model::Bus) and [`Device`] as a Modbus bus's.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use config::Value;

use super::{BAUDS, DEFAULT_METER_POLL, Line, MAX_PRIMARY, METER_MODEL, MeterAddress};
use crate::config::bus::{BusParts, Device, Link, Protocol};
use crate::config::channel::ChannelConfig;
use crate::config::parity::Parity;
use crate::config::protocols::address::Address;
use crate::config::walk::{Errors, Table, join};
use crate::profile::MAX_TIMEOUT;

/// An M-Bus bus's link and meters.
pub(crate) fn bus(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> BusParts {
    let link = link(t, path, errs).map(Link::new);
    let mut devices = Vec::new();
    let mut places: BTreeMap<String, String> = BTreeMap::new();
    let entries = t.entries("devices", errs);
    if entries.is_empty() {
        errs.push(&join(path, "devices"), t.origin(), "no device on this bus");
    }
    for (name, value) in entries {
        let Some(d) = meter(path, &name, value, errs) else {
            continue;
        };
        let Some(address) = d.address.of::<MeterAddress>() else {
            continue;
        };
        let (key, what) = match address {
            MeterAddress::Primary(a) => ("address", format!("primary address {a}")),
            MeterAddress::Secondary { id, .. } => ("id", format!("id {id}")),
        };
        if let Some(other) = places.insert(d.place(), d.name.clone()) {
            errs.push(
                &format!("{path}.devices.{name}.{key}"),
                value.origin(),
                format!("{what} is already used by meter {other} on this bus"),
            );
        }
        devices.push(d);
    }
    BusParts {
        link,
        guard: Duration::ZERO,
        slow_poll: Duration::from_secs(60),
        devices,
    }
}

/// `port` (a serial level converter: `baud`, default 2400, and `parity`, default even) or
/// `host = "HOST:PORT"` (raw frames on a socket).
fn link(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<Line> {
    if t.has("host") {
        let host = t.req::<String>("host", errs)?;
        for key in ["baud", "parity", "port"] {
            if t.has(key) {
                let _ = t.raw(key);
                let why = match key {
                    "port" => "give the TCP port in `host` (\"HOST:PORT\"), not as `port`",
                    _ => "serial setting on a TCP bus",
                };
                errs.push(&join(path, key), t.origin(), why);
            }
        }
        let parsed = host
            .rsplit_once(':')
            .and_then(|(h, p)| Some((h, p.parse::<u16>().ok().filter(|p| *p > 0)?)));
        let Some((h, port)) = parsed.filter(|(h, _)| !h.is_empty()) else {
            let why = format!("{host:?}: an M-Bus converter's address is \"HOST:PORT\"");
            errs.push(&join(path, "host"), t.origin(), why);
            return None;
        };
        return Some(Line::Tcp {
            host: h.trim_matches(['[', ']']).to_string(),
            port,
        });
    }
    if !t.has("port") {
        errs.push(
            path,
            t.origin(),
            "an M-Bus bus needs `port` (a serial level converter) or `host = \"HOST:PORT\"` \
             (an M-Bus-to-Ethernet converter)",
        );
        return None;
    }
    let baud = t.int::<u32>("baud", errs).unwrap_or(2400);
    if !BAUDS.contains(&baud) {
        errs.push(
            &join(path, "baud"),
            t.origin(),
            format!("{baud} is not an M-Bus baud rate ({BAUDS:?})"),
        );
    }
    let parity = t.opt::<Parity>("parity", errs).unwrap_or(Parity::Even);
    let port = t.opt::<PathBuf>("port", errs)?;
    if !port.is_absolute() {
        errs.push(
            &join(path, "port"),
            t.origin(),
            "must be an absolute path such as /dev/ttyUSB0",
        );
        return None;
    }
    Some(Line::Serial { port, baud, parity })
}

/// One meter.
fn meter(bus_path: &str, name: &str, value: &Value, errs: &mut Errors) -> Option<Device> {
    let path = format!("{bus_path}.devices.{name}");
    let mut t = Table::of(value, &path, errs)?;
    crate::config::names::device_name(&t, &path, name, errs);
    for key in ["unit", "model", "baud"] {
        if t.has(key) {
            let _ = t.raw(key);
            let why = format!(
                "an M-Bus meter is found by `address` (primary, 0-250) or `id` (its 8-digit \
                 secondary address), not by a {} unit, model or baud rate",
                Protocol::DEFAULT.title()
            );
            errs.push(&join(&path, key), t.origin(), why);
        }
    }
    let address = address(&mut t, &path, errs);
    let poll = t.duration("poll", errs).unwrap_or(DEFAULT_METER_POLL);
    let timeout = t.duration_within("timeout", Duration::from_millis(1), MAX_TIMEOUT, errs);
    let commands = t.opt::<bool>("commands", errs).unwrap_or(true);
    let enabled = t.opt::<bool>("enabled", errs).unwrap_or(true);
    let publish = crate::config::publish::policy(&mut t, errs);
    let payload = crate::config::publish::payload(&mut t, errs);
    let intervals = crate::config::metering::intervals(&mut t, errs);
    let server_unit = crate::config::outputs::device_keys(&mut t, &path, errs);
    let channels = channels(&mut t, &path, errs);
    t.finish(errs);
    let address = address?;
    Some(Device {
        name: name.to_string(),
        unit: address.wire(),
        model: METER_MODEL.to_string(),
        profile: Arc::new(super::meter_profile()),
        poll,
        timeout,
        commands,
        baud: None,
        channels,
        enabled,
        publish,
        payload,
        intervals,
        address: Address::new(address),
        server_unit,
    })
}

/// `address = N`, or `id = "12345678"` with `manufacturer`, `version` and `medium` optional.
fn address(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<MeterAddress> {
    match (t.has("address"), t.has("id")) {
        (true, true) => {
            let _ = (t.raw("address"), t.raw("id"));
            errs.push(
                path,
                t.origin(),
                "give `address` (primary) or `id` (secondary), not both",
            );
            None
        }
        (true, false) => {
            secondary_only(t, path, errs);
            let a = t.int::<i64>("address", errs)?;
            match u8::try_from(a).ok().filter(|a| *a <= MAX_PRIMARY) {
                Some(a) => Some(MeterAddress::Primary(a)),
                None => {
                    let why = format!(
                        "primary address {a} is outside 0..{MAX_PRIMARY} (use `id` for a meter \
                         by its secondary address)"
                    );
                    errs.push(&join(path, "address"), t.origin(), why);
                    None
                }
            }
        }
        (false, true) => secondary(t, path, errs),
        (false, false) => {
            errs.push(
                path,
                t.origin(),
                "needs `address` (primary, 0-250) or `id` (the meter's 8-digit identification \
                 number)",
            );
            None
        }
    }
}

/// `manufacturer`, `version` and `medium` narrow a secondary address only.
fn secondary_only(t: &mut Table<'_>, path: &str, errs: &mut Errors) {
    for key in ["manufacturer", "version", "medium"] {
        if t.has(key) {
            let _ = t.raw(key);
            errs.push(
                &join(path, key),
                t.origin(),
                "narrows a secondary address: only with `id`",
            );
        }
    }
}

fn secondary(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<MeterAddress> {
    let id = match t.raw("id").map(|v| v.kind.clone()) {
        Some(config::ValueKind::String(s)) => Some(s),
        Some(config::ValueKind::I64(n)) => Some(format!("{n:08}")),
        Some(config::ValueKind::U64(n)) => Some(format!("{n:08}")),
        _ => None,
    };
    let id = id.filter(|s| s.len() == 8 && s.bytes().all(|b| b.is_ascii_digit()));
    if id.is_none() {
        errs.push(
            &join(path, "id"),
            t.origin(),
            "must be the meter's identification number: 8 digits, such as \"12345678\"",
        );
    }
    let manufacturer = t.opt::<String>("manufacturer", errs).filter(|m| {
        let ok = m.len() == 3 && m.bytes().all(|b| b.is_ascii_uppercase());
        if !ok {
            errs.push(
                &join(path, "manufacturer"),
                t.origin(),
                format!("{m:?}: a manufacturer is three letters A-Z, such as \"KAM\""),
            );
        }
        ok
    });
    let version = t.int::<u8>("version", errs);
    let medium = t.int::<u8>("medium", errs);
    Some(MeterAddress::Secondary {
        id: id?,
        manufacturer,
        version,
        medium,
    })
}

/// `[….channels.NAME]` of a meter: `record = N` picks and names a record; a table without
/// `record` names a record by its default name. Also `enabled`, the publish policy,
/// `intervals` and `max_rate_hz` (a register's most steps a second).
fn channels(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> BTreeMap<String, ChannelConfig> {
    let mut out = BTreeMap::new();
    let mut records: BTreeMap<usize, String> = BTreeMap::new();
    for (cname, cvalue) in t.entries("channels", errs) {
        let cpath = format!("{path}.channels.{cname}");
        let Some(mut ct) = Table::of(cvalue, &cpath, errs) else {
            continue;
        };
        if !crate::topics::is_topic_safe(&cname) {
            errs.push(
                &cpath,
                ct.origin(),
                "channel name must be letters, digits, '-' or '_' (it is a topic level)",
            );
        }
        let record = ct.int::<usize>("record", errs);
        if let Some(r) = record
            && let Some(other) = records.insert(r, cname.clone())
        {
            errs.push(
                &join(&cpath, "record"),
                ct.origin(),
                format!("record {r} is already channel {other}"),
            );
        }
        let max_rate_hz = ct.opt::<f64>("max_rate_hz", errs);
        if max_rate_hz.is_some_and(|v| !(v > 0.0 && v.is_finite())) {
            errs.push(
                &join(&cpath, "max_rate_hz"),
                ct.origin(),
                "must be a number greater than zero",
            );
        }
        let c = ChannelConfig {
            record,
            register: ct.int::<u16>("register", errs),
            max_rate_hz,
            enabled: ct.opt::<bool>("enabled", errs).unwrap_or(true),
            publish: crate::config::publish::policy(&mut ct, errs),
            intervals: crate::config::metering::intervals(&mut ct, errs),
            ..ChannelConfig::default()
        };
        ct.finish(errs);
        out.insert(cname, c);
    }
    out
}
