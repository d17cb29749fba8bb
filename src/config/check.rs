//! The merged configuration tree → typed [`Config`], collecting every error on the way.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use config::Value;

use super::model::BusParts;
use super::model::{Bus, Config, ConfigErrors, Gateway};
use super::outputs::Kinds;
use super::protocols::{Checking, Protocol, Protocols};
use super::walk::{Errors, Table, join};
use crate::profile::Profiles;

use crate::profile::MAX_TIMEOUT;

/// What a config is checked against: the registries' output kinds (`publish/formats.rs`) and
/// protocols (`crate::protocols`), handed in from above, so that one left out of its registry
/// can neither be parsed nor run.
#[derive(Clone)]
pub struct Known {
    pub kinds: Kinds,
    pub protocols: Protocols,
}

/// Checks a merged configuration tree that was read from `path`, against the registries' output
/// kinds and protocols.
pub fn from_tree(tree: &Value, path: &Path, known: &Known) -> Result<Config, ConfigErrors> {
    let mut errs = Errors {
        default_origin: path.display().to_string(),
        ..Errors::default()
    };
    let config = check(tree, (path, known), &mut errs);
    match config {
        Some(c) if errs.list.is_empty() => Ok(c),
        _ => Err(ConfigErrors(errs.list)),
    }
}

fn check(tree: &Value, (path, known): (&Path, &Known), errs: &mut Errors) -> Option<Config> {
    let kinds = &known.kinds;
    let mut root = Table::of(tree, "", errs)?;
    let config_dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();

    let mut gateway = gateway(root.table("gateway", errs), &config_dir, errs);
    (gateway.tariffs, gateway.billing) = super::tariffs::read(&mut root, errs);
    let (mqtt, legacy) = match root.table("mqtt", errs) {
        Some(mut t) => {
            let mqtt = super::mqtt::mqtt(&mut t, &gateway.id, errs);
            let legacy = super::outputs::formats(&mut t, kinds, errs);
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

    let checking = Checking {
        protocol: Protocol::DEFAULT,
        profiles: &profiles,
        protocols: &known.protocols,
    };
    let buses = buses(&mut root, &checking, errs);
    let outputs = super::outputs::read(&mut root, (legacy, kinds), &mqtt, &gateway.id, errs);
    let remote = super::remote::read(root.table("remote", errs), errs);
    root.finish(errs);

    unique_device_names(&buses, errs);
    super::tariffs::check_grid(&gateway, &buses, errs);

    if outputs.serve_registers() {
        super::buses::RegisterMap::build(&buses, errs);
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
fn buses(root: &mut Table<'_>, checking: &Checking<'_>, errs: &mut Errors) -> Vec<Bus> {
    let entries = root.entries("buses", errs);
    if entries.is_empty() {
        errs.push("buses", root.origin(), "no bus configured");
    }
    entries
        .into_iter()
        .filter_map(|(name, value)| bus(&name, value, checking, errs))
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

/// `protocol`: one of the registry's, or the default.
fn protocol(
    t: &mut Table<'_>,
    path: &str,
    protocols: &Protocols,
    errs: &mut Errors,
) -> Option<Protocol> {
    let Some(name) = t.opt::<String>("protocol", errs) else {
        return Some(Protocol::DEFAULT);
    };
    protocols
        .find(&name)
        .map_err(|why| errs.push(&join(path, "protocol"), t.origin(), why))
        .ok()
}

fn bus(name: &str, value: &Value, checking: &Checking<'_>, errs: &mut Errors) -> Option<Bus> {
    let path = format!("buses.{name}");
    let mut t = Table::of(value, &path, errs)?;
    if !crate::topics::is_topic_safe(name) {
        errs.push(
            &path,
            t.origin(),
            "bus name must be letters, digits, '-' or '_'",
        );
    }
    let protocol = protocol(&mut t, &path, checking.protocols, errs)?;
    let BusParts {
        link,
        guard,
        slow_poll,
        devices,
    } = protocol.bus(
        &mut t,
        &path,
        &Checking {
            protocol,
            ..*checking
        },
        errs,
    );
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
