//! The merged configuration tree → typed [`Config`], collecting every error on the way.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Duration;

use config::Value;

use super::model::{Bus, Config, ConfigErrors, Device, Gateway, Link, Parity, Protocol};
use super::walk::{Errors, Table, join};
use crate::profile::Profiles;

use crate::profile::MAX_TIMEOUT;

/// Baud rates the seed modules can be set to (their baud-code tables).
pub const BAUDS: [u32; 7] = [2400, 4800, 9600, 19200, 38400, 57600, 115200];

/// Checks a merged configuration tree that was read from `path`.
pub fn from_tree(tree: &Value, path: &Path) -> Result<Config, ConfigErrors> {
    let mut errs = Errors {
        default_origin: path.display().to_string(),
        ..Errors::default()
    };
    let config = check(tree, path, &mut errs);
    match config {
        Some(c) if errs.list.is_empty() => Ok(c),
        _ => Err(ConfigErrors(errs.list)),
    }
}

fn check(tree: &Value, path: &Path, errs: &mut Errors) -> Option<Config> {
    let mut root = Table::of(tree, "", errs)?;
    let config_dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();

    let mut gateway = gateway(root.table("gateway", errs), &config_dir, errs);
    (gateway.tariffs, gateway.billing) = super::tariffs::read(&mut root, errs);
    let (mqtt, legacy) = match root.table("mqtt", errs) {
        Some(mut t) => {
            let mqtt = super::mqtt::mqtt(&mut t, &gateway.id, errs);
            let legacy = super::outputs::formats(&mut t, errs);
            t.finish(errs);
            (mqtt, legacy)
        }
        None => (super::mqtt::mqtt_default(&gateway.id), None),
    };
    let metrics = super::metrics::check(root.table("metrics", errs), errs);

    let profiles = match Profiles::with_dir(&gateway.profile_dir) {
        Ok(p) => p,
        Err(list) => {
            for e in list {
                errs.push("gateway.profile_dir", None, e.to_string());
            }
            Profiles::builtin()
        }
    };

    let buses = buses(&mut root, &profiles, errs);
    let outputs = super::outputs::read(&mut root, legacy, &mqtt, &gateway.id, errs);
    let remote = super::remote::read(root.table("remote", errs), errs);
    root.finish(errs);

    unique_device_names(&buses, errs);
    super::tariffs::check_grid(&gateway, &buses, errs);

    // A Modbus server output's map is a contract: unit ids and blocks that collide are errors.
    if !outputs.modbus.is_empty() {
        super::outputs::modbus::map::RegisterMap::build(&buses, errs);
    }

    Some(Config {
        source: path.to_path_buf(),
        gateway,
        mqtt,
        metrics,
        buses,
        outputs,
        remote,
    })
}

/// Every `[buses.NAME]`; none is an error.
fn buses(root: &mut Table<'_>, profiles: &Profiles, errs: &mut Errors) -> Vec<Bus> {
    let entries = root.entries("buses", errs);
    if entries.is_empty() {
        errs.push("buses", root.origin(), "no bus configured");
    }
    entries
        .into_iter()
        .filter_map(|(name, value)| bus(&name, value, profiles, errs))
        .collect()
}

/// Device names become topic levels, so they are unique across the gateway.
fn unique_device_names(buses: &[Bus], errs: &mut Errors) {
    let mut seen: HashMap<&str, &str> = HashMap::new();
    for bus in buses {
        for d in &bus.devices {
            if let Some(other) = seen.insert(&d.name, &bus.name) {
                errs.push(
                    &format!("buses.{}.devices.{}", bus.name, d.name),
                    None,
                    format!("device name is already used on bus {other}"),
                );
            }
        }
    }
}

/// The machine's hostname as the kernel has it.
pub fn host_name_raw() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// The gateway id derived from a hostname: characters a topic level cannot hold (the dots of an
/// FQDN) become '-'. `None` when nothing usable is left: then the id must be configured, never
/// silently replaced by a shared default (two gateways with one id take each other's commands).
pub fn id_from_host(host: &str) -> Option<String> {
    let id: String = host
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '-'
            }
        })
        .collect();
    let id = id.trim_matches('-').to_string();
    crate::topics::is_topic_safe(&id).then_some(id)
}

fn gateway(table: Option<Table<'_>>, config_dir: &Path, errs: &mut Errors) -> Gateway {
    let host = host_name_raw();
    let mut g = Gateway {
        id: id_from_host(&host).unwrap_or_default(),
        id_from_hostname: Some(host),
        state_dir: PathBuf::from("/var/lib/pulsegate"),
        state_flush: Duration::from_secs(5),
        stats_interval: Duration::from_secs(60),
        profile_dir: config_dir.join("profiles"),
        publish: Default::default(),
        payload: Default::default(),
        clock: Default::default(),
        intervals: None,
        tariffs: None,
        billing: None,
    };
    let Some(mut t) = table else {
        refuse_unusable_host(&g, errs);
        return g;
    };
    if let Some(id) = t.opt::<String>("id", errs) {
        g.id_from_hostname = None;
        if crate::topics::is_topic_safe(&id) {
            g.id = id;
        } else {
            errs.push(
                &join(&t.path, "id"),
                t.origin(),
                "must be letters, digits, '-' or '_' (it is a topic level)",
            );
        }
    }
    if let Some(dir) = t.opt::<PathBuf>("state_dir", errs) {
        g.state_dir = dir;
    }
    if let Some(d) = t.duration("state_flush", errs) {
        g.state_flush = d;
    }
    if let Some(d) = t.duration("stats_interval", errs) {
        g.stats_interval = d;
    }
    if let Some(dir) = t.opt::<PathBuf>("profile_dir", errs) {
        g.profile_dir = if dir.is_absolute() {
            dir
        } else {
            config_dir.join(dir)
        };
    }
    g.publish = super::publish::policy(&mut t, errs);
    g.payload = super::publish::payload(&mut t, errs).unwrap_or_default();
    g.clock = super::metering::timezone(&mut t, errs);
    g.intervals = super::metering::intervals(&mut t, errs);
    t.finish(errs);
    refuse_unusable_host(&g, errs);
    g
}

fn refuse_unusable_host(g: &Gateway, errs: &mut Errors) {
    if let Some(host) = &g.id_from_hostname
        && g.id.is_empty()
    {
        errs.push(
            "gateway.id",
            None,
            format!(
                "not set, and the hostname {host:?} cannot be made a topic level: set gateway.id"
            ),
        );
    }
}

fn bus(name: &str, value: &Value, profiles: &Profiles, errs: &mut Errors) -> Option<Bus> {
    let path = format!("buses.{name}");
    let mut t = Table::of(value, &path, errs)?;
    if !crate::topics::is_topic_safe(name) {
        errs.push(
            &path,
            t.origin(),
            "bus name must be letters, digits, '-' or '_'",
        );
    }
    let protocol = match t.opt::<String>("protocol", errs) {
        None => Protocol::Modbus,
        Some(p) => match p.parse::<Protocol>() {
            Ok(p) => p,
            Err(why) => {
                errs.push(&join(&path, "protocol"), t.origin(), why);
                return None;
            }
        },
    };
    let (link, guard, slow_poll, devices) = match protocol {
        Protocol::Modbus => modbus_bus(&mut t, &path, profiles, errs),
        Protocol::Mbus => {
            let (link, devices) = super::meter::bus(&mut t, &path, errs);
            (link, Duration::ZERO, Duration::from_secs(60), devices)
        }
    };
    let timeout = t.duration_within("timeout", Duration::from_millis(1), MAX_TIMEOUT, errs);
    let offline_after = t.int::<u32>("offline_after", errs).unwrap_or(3);
    if offline_after == 0 {
        errs.push(
            &join(&path, "offline_after"),
            t.origin(),
            "must be at least 1",
        );
    }
    let backoff_min = t
        .duration("backoff_min", errs)
        .unwrap_or(Duration::from_secs(1));
    let backoff_max = t
        .duration("backoff_max", errs)
        .unwrap_or(Duration::from_secs(60));
    if backoff_max < backoff_min {
        errs.push(
            &join(&path, "backoff_max"),
            t.origin(),
            "must not be below backoff_min",
        );
    }
    let enabled = t.opt::<bool>("enabled", errs).unwrap_or(true);
    t.finish(errs);
    Some(Bus {
        name: name.to_string(),
        link: link?,
        timeout,
        guard,
        offline_after,
        backoff_min,
        backoff_max,
        slow_poll,
        enabled,
        devices,
    })
}

/// What only a Modbus bus has: its link (with the TCP port its devices' datasheets give when
/// none is written), the guard time, the slow poll and its devices of known models.
fn modbus_bus(
    t: &mut Table<'_>,
    path: &str,
    profiles: &Profiles,
    errs: &mut Errors,
) -> (Option<Link>, Duration, Duration, Vec<Device>) {
    let link = bus_link(t, path, errs);
    let t_origin = t.origin().map(str::to_string);
    let guard = t
        .duration_within("guard", Duration::ZERO, Duration::from_secs(1), errs)
        .unwrap_or(Duration::ZERO);
    let slow_poll = t
        .duration("slow_poll", errs)
        .unwrap_or(Duration::from_secs(60));
    let devices = bus_devices(t, path, profiles, errs);
    if matches!(link, Some(Link::Tcp { .. })) {
        for d in devices.iter().filter(|d| d.baud.is_some()) {
            errs.push(
                &format!("{path}.devices.{}.baud", d.name),
                t.origin(),
                "serial setting on a TCP bus",
            );
        }
    }
    let mut link = link;
    if let Some(Link::Tcp { port, .. }) = &mut link
        && *port == 0
    {
        *port = default_tcp_port(path, &devices, t_origin.as_deref(), errs);
    }
    (link, guard, slow_poll, devices)
}

/// The bus's link: `host` (Modbus TCP) or `port` (a serial device, Modbus RTU) and its settings.
fn bus_link(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<Link> {
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
        host.map(|host| Link::Tcp { host, port })
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
        port.map(|port| Link::Rtu {
            port,
            baud,
            parity,
            stop_bits,
        })
    } else {
        errs.push(
            path,
            t.origin(),
            "needs `port` (a serial device, Modbus RTU) or `host` (Modbus TCP), or `protocol = \"mbus\"` for M-Bus meters",
        );
        None
    }
}

/// The devices of a bus; a unit used twice is an error.
fn bus_devices(
    t: &mut Table<'_>,
    path: &str,
    profiles: &Profiles,
    errs: &mut Errors,
) -> Vec<super::model::Device> {
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
    super::names::device_name(&t, &path, name, errs);
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
    let publish = super::publish::policy(&mut t, errs);
    let payload = super::publish::payload(&mut t, errs);
    let intervals = super::metering::intervals(&mut t, errs);
    let server_unit = super::outputs::modbus::server_unit(&mut t, &path, errs);
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
        meter: None,
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
) -> BTreeMap<String, super::channel::ChannelConfig> {
    let mut channels = BTreeMap::new();
    for (cname, cvalue) in t.entries("channels", errs) {
        let cpath = format!("{path}.channels.{cname}");
        let Some(ct) = Table::of(cvalue, &cpath, errs) else {
            continue;
        };
        let c = super::channel::channel(ct, &cname, profile, errs);
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
        .map(|d| (d.profile.tcp_port.unwrap_or(502), d.profile.model.as_str()))
        .collect();
    let ports: std::collections::BTreeSet<u16> = given.iter().map(|(p, _)| *p).collect();
    match ports.len() {
        0 => 502,
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
            502
        }
    }
}
