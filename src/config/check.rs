//! The merged configuration tree → typed [`Config`], collecting every error on the way.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Duration;

use config::Value;

use super::walk::{Errors, Table, join};
use super::{Bus, Config, ConfigErrors, Device, Gateway, Link, Mqtt, Parity};
use crate::profile::Profiles;

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

    let gateway = gateway(root.table("gateway", errs), &config_dir, errs);
    let mqtt = mqtt(root.table("mqtt", errs), &gateway.id, errs);

    let profiles = match Profiles::with_dir(&gateway.profile_dir) {
        Ok(p) => p,
        Err(list) => {
            for e in list {
                errs.push("gateway.profile_dir", None, e.to_string());
            }
            Profiles::builtin()
        }
    };

    let mut buses = Vec::new();
    let bus_entries = root.entries("buses", errs);
    if bus_entries.is_empty() {
        errs.push("buses", root.origin(), "no bus configured");
    }
    for (name, value) in bus_entries {
        if let Some(bus) = bus(&name, value, &profiles, errs) {
            buses.push(bus);
        }
    }
    root.finish(errs);

    // Device names become topic levels, so they are unique across the gateway.
    let mut seen: HashMap<&str, &str> = HashMap::new();
    for bus in &buses {
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

    Some(Config {
        source: path.to_path_buf(),
        gateway,
        mqtt,
        buses,
    })
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| super::is_topic_safe(s))
        .unwrap_or_else(|| "pulsegate".to_string())
}

fn gateway(table: Option<Table<'_>>, config_dir: &Path, errs: &mut Errors) -> Gateway {
    let mut g = Gateway {
        id: host_name(),
        state_dir: PathBuf::from("/var/lib/pulsegate"),
        state_flush: Duration::from_secs(5),
        stats_interval: Duration::from_secs(60),
        profile_dir: config_dir.join("profiles"),
    };
    let Some(mut t) = table else { return g };
    if let Some(id) = t.opt::<String>("id", errs) {
        if super::is_topic_safe(&id) {
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
    t.finish(errs);
    g
}

/// A password read from a file: the line ending is not part of it.
fn secret(text: String) -> super::Secret {
    super::Secret(text.trim_end_matches(['\n', '\r']).to_string())
}

fn mqtt(table: Option<Table<'_>>, gateway_id: &str, errs: &mut Errors) -> Mqtt {
    let mut m = Mqtt {
        host: "127.0.0.1".into(),
        port: 1883,
        client_id: format!("pulsegate-{gateway_id}"),
        username: None,
        password: None,
        tls: None,
        keep_alive: Duration::from_secs(30),
        qos: 1,
        retain: false,
        topic_root: format!("pulsegate/{gateway_id}"),
        spool_bytes: 64 << 20,
    };
    let Some(mut t) = table else { return m };
    if let Some(v) = t.opt("host", errs) {
        m.host = v;
    }
    if let Some(v) = t.int::<u16>("port", errs) {
        if v == 0 {
            errs.push(&join(&t.path, "port"), t.origin(), "must be 1..65535");
        }
        m.port = v;
    }
    if let Some(v) = t.opt("client_id", errs) {
        m.client_id = v;
    }
    m.username = t.opt("username", errs);
    m.password = t.opt::<String>("password", errs).map(super::Secret);
    if let Some(file) = t.opt::<PathBuf>("password_file", errs) {
        match std::fs::read_to_string(&file) {
            Ok(p) => m.password = Some(secret(p)),
            Err(e) => errs.push(
                &join(&t.path, "password_file"),
                t.origin(),
                format!("cannot read {}: {e}", file.display()),
            ),
        }
    }
    if m.password.is_none() {
        // systemd's LoadCredential=mqtt-password:… puts it here for this service only.
        if let Some(dir) = std::env::var_os("CREDENTIALS_DIRECTORY") {
            if let Ok(p) = std::fs::read_to_string(Path::new(&dir).join("mqtt-password")) {
                m.password = Some(secret(p));
            }
        }
    }
    if let Some(mut tt) = t.table("tls", errs) {
        let ca_file = tt.req::<PathBuf>("ca_file", errs);
        let cert_file = tt.opt::<PathBuf>("cert_file", errs);
        let key_file = tt.opt::<PathBuf>("key_file", errs);
        if cert_file.is_some() != key_file.is_some() {
            errs.push(
                &tt.path.clone(),
                tt.origin(),
                "cert_file and key_file go together",
            );
        }
        for (key, file) in [
            ("ca_file", &ca_file),
            ("cert_file", &cert_file),
            ("key_file", &key_file),
        ] {
            if let Some(f) = file
                && !f.is_file()
            {
                errs.push(
                    &join(&tt.path, key),
                    tt.origin(),
                    format!("no such file {}", f.display()),
                );
            }
        }
        tt.finish(errs);
        m.tls = ca_file.map(|ca_file| super::Tls {
            ca_file,
            cert_file,
            key_file,
        });
    }
    if let Some(v) = t.duration("keep_alive", errs) {
        if v < Duration::from_secs(5) {
            errs.push(
                &join(&t.path, "keep_alive"),
                t.origin(),
                "must be at least 5s",
            );
        }
        m.keep_alive = v;
    }
    if let Some(v) = t.int::<u8>("qos", errs) {
        if v > 2 {
            errs.push(&join(&t.path, "qos"), t.origin(), "must be 0, 1 or 2");
        }
        m.qos = v;
    }
    if let Some(v) = t.opt("retain", errs) {
        m.retain = v;
    }
    if let Some(mb) = t.int::<u64>("spool_mb", errs) {
        if mb == 0 {
            errs.push(&join(&t.path, "spool_mb"), t.origin(), "must be at least 1");
        }
        m.spool_bytes = mb << 20;
    }
    if let Some(v) = t.opt::<String>("topic_root", errs) {
        let ok = !v.is_empty()
            && !v.starts_with('/')
            && !v.ends_with('/')
            && !v.contains(['+', '#'])
            && v.split('/').all(|level| !level.is_empty());
        if ok {
            m.topic_root = v;
        } else {
            errs.push(
                &join(&t.path, "topic_root"),
                t.origin(),
                "must be a topic without wildcards, empty levels or a leading/trailing '/'",
            );
        }
    }
    t.finish(errs);
    m
}

fn bus(name: &str, value: &Value, profiles: &Profiles, errs: &mut Errors) -> Option<Bus> {
    let path = format!("buses.{name}");
    let mut t = Table::of(value, &path, errs)?;
    if !super::is_topic_safe(name) {
        errs.push(
            &path,
            t.origin(),
            "bus name must be letters, digits, '-' or '_'",
        );
    }
    let has_port = t.has("port");
    let has_host = t.has("host");
    let link = if has_host {
        let host = t.req::<String>("host", errs);
        let port = t.int::<u16>("port", errs).unwrap_or(0);
        if port == 0 && has_port {
            errs.push(
                &join(&path, "port"),
                t.origin(),
                "TCP port must be 1..65535",
            );
        }
        for key in ["baud", "parity", "stop_bits"] {
            if t.has(key) {
                let _ = t.opt::<toml::Value>(key, errs);
                errs.push(&join(&path, key), t.origin(), "serial setting on a TCP bus");
            }
        }
        host.map(|host| Link::Tcp { host, port })
    } else if has_port {
        let baud = t.int::<u32>("baud", errs).unwrap_or(9600);
        if !BAUDS.contains(&baud) {
            errs.push(
                &join(&path, "baud"),
                t.origin(),
                format!("{baud} is not a rate the modules support ({BAUDS:?})"),
            );
        }
        let parity = t.opt::<Parity>("parity", errs).unwrap_or(Parity::None);
        let stop_bits = t.int::<u8>("stop_bits", errs).unwrap_or(1);
        if !(1..=2).contains(&stop_bits) {
            errs.push(&join(&path, "stop_bits"), t.origin(), "must be 1 or 2");
        }
        let port = t.opt::<PathBuf>("port", errs).filter(|p| {
            let ok = p.is_absolute();
            if !ok {
                errs.push(
                    &join(&path, "port"),
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
            &path,
            t.origin(),
            "needs `port` (a serial device, Modbus RTU) or `host` (Modbus TCP)",
        );
        None
    };

    let t_origin = t.origin().map(str::to_string);
    let timeout = t.duration("timeout", errs);
    let guard = t.opt::<String>("guard", errs).map_or(Duration::ZERO, |s| {
        humantime::parse_duration(&s).unwrap_or_else(|e| {
            errs.push(
                &join(&path, "guard"),
                t.origin(),
                format!("bad duration {s:?}: {e}"),
            );
            Duration::ZERO
        })
    });
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
    let slow_poll = t
        .duration("slow_poll", errs)
        .unwrap_or(Duration::from_secs(60));
    let enabled = t.opt::<bool>("enabled", errs).unwrap_or(true);

    let mut devices = Vec::new();
    let mut units: BTreeMap<u8, String> = BTreeMap::new();
    let entries = t.entries("devices", errs);
    if entries.is_empty() {
        errs.push(&join(&path, "devices"), t.origin(), "no device on this bus");
    }
    for (dname, dvalue) in entries {
        if let Some(d) = device(&path, &dname, dvalue, profiles, errs) {
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
    t.finish(errs);
    let mut link = link?;
    if let Link::Tcp { port, .. } = &mut link
        && *port == 0
    {
        *port = default_tcp_port(&path, &devices, t_origin.as_deref(), errs);
    }
    Some(Bus {
        name: name.to_string(),
        link,
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

fn device(
    bus_path: &str,
    name: &str,
    value: &Value,
    profiles: &Profiles,
    errs: &mut Errors,
) -> Option<Device> {
    let path = format!("{bus_path}.devices.{name}");
    let mut t = Table::of(value, &path, errs)?;
    if !super::is_topic_safe(name) || matches!(name, "status" | "bus" | "cmd") {
        errs.push(
            &path,
            t.origin(),
            "device name must be letters, digits, '-' or '_' and not status, bus or cmd \
             (it is a topic level)",
        );
    }
    if !t.has("unit") {
        errs.push(&join(&path, "unit"), t.origin(), "missing");
    }
    let unit = t.int::<i64>("unit", errs).and_then(|u| {
        if (1..=247).contains(&u) {
            Some(u as u8)
        } else {
            errs.push(
                &join(&path, "unit"),
                t.origin(),
                format!("unit {u} is outside 1..247"),
            );
            None
        }
    });
    let model = t.req::<String>("model", errs);
    let profile = model.as_ref().and_then(|m| {
        let p = profiles.get(m);
        if p.is_none() {
            errs.push(
                &join(&path, "model"),
                t.origin(),
                format!(
                    "unknown model {m:?}; known: {}",
                    profiles.names().join(", ")
                ),
            );
        }
        p
    });
    let poll = t.duration("poll", errs).unwrap_or(Duration::from_secs(1));
    let timeout = t.duration("timeout", errs);
    let commands = t.opt::<bool>("commands", errs).unwrap_or(true);
    let enabled = t.opt::<bool>("enabled", errs).unwrap_or(true);
    let mut channels = BTreeMap::new();
    for (cname, cvalue) in t.entries("channels", errs) {
        let cpath = format!("{path}.channels.{cname}");
        let Some(ct) = Table::of(cvalue, &cpath, errs) else {
            continue;
        };
        let c = super::channel::channel(ct, &cname, profile.as_deref(), errs);
        channels.insert(cname, c);
    }
    t.finish(errs);
    Some(Device {
        name: name.to_string(),
        unit: unit?,
        model: model?,
        profile: profile?,
        poll,
        timeout,
        commands,
        channels,
        enabled,
    })
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
