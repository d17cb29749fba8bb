//! `[mqtt]`: the broker connection of the gateway's own voice and the defaults of every output's
//! connection. The same keys in `[outputs.NAME]` override these for that output
//! ([`overlay`]), so one reader checks both.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::connection::{Mqtt, MqttProtocol, Secret, Tls};
use super::walk::{Errors, Table, join};

/// The connection settings before any key is read.
pub(crate) fn defaults(gateway_id: &str) -> Mqtt {
    Mqtt {
        host: "127.0.0.1".into(),
        port: 1883,
        socket: None,
        client_id: format!("pulsegate-{gateway_id}"),
        username: None,
        password: None,
        tls: None,
        keep_alive: Duration::from_secs(30),
        qos: 1,
        retain: false,
        topic_root: format!("pulsegate/{gateway_id}"),
        spool_bytes: 64 << 20,
        commands: true,
        protocol: MqttProtocol::Auto,
        failover: Vec::new(),
        failover_after: DEFAULT_FAILOVER_AFTER,
        batch: DEFAULT_BATCH,
    }
}

/// Reads `[mqtt]` over the defaults; `mqtt.format` is left for [`super::outputs`].
pub(crate) fn mqtt(t: &mut Table<'_>, gateway_id: &str, errs: &mut Errors) -> Mqtt {
    let mut m = defaults(gateway_id);
    overlay(t, &mut m, errs);
    mqtt_or_credential(m)
}

/// The settings of a config without `[mqtt]`.
pub(crate) fn mqtt_default(gateway_id: &str) -> Mqtt {
    mqtt_or_credential(defaults(gateway_id))
}

fn mqtt_or_credential(mut m: Mqtt) -> Mqtt {
    if m.password.is_none() {
        m.password = systemd_credential();
    }
    m
}

/// Applies the connection keys `t` has to `m`; keys it lacks keep `m`'s values. A table that
/// names another broker (`host`, `port`) drops `m`'s socket unless it sets its own, and one that
/// names another user drops `m`'s password unless it gives one: a password belongs to its user.
pub(crate) fn overlay(t: &mut Table<'_>, m: &mut Mqtt, errs: &mut Errors) {
    if let Some(v) = t.opt::<String>("protocol", errs) {
        match v.as_str() {
            "auto" => m.protocol = MqttProtocol::Auto,
            "5" => m.protocol = MqttProtocol::V5,
            "3.1.1" => m.protocol = MqttProtocol::V311,
            _ => errs.push(
                &join(&t.path, "protocol"),
                t.origin(),
                format!("unknown MQTT protocol {v:?}: \"auto\", \"5\" or \"3.1.1\""),
            ),
        }
    }
    let mut moved = false;
    if let Some(v) = t.opt("host", errs) {
        m.host = v;
        moved = true;
    }
    if let Some(v) = t.int::<u16>("port", errs) {
        if v == 0 {
            errs.push(&join(&t.path, "port"), t.origin(), "must be 1..65535");
        }
        m.port = v;
        moved = true;
    }
    if let Some(list) = hosts(t, errs) {
        if moved {
            let why = "set hosts, or host and port, not both";
            errs.push(&join(&t.path, "hosts"), t.origin(), why);
        }
        let mut list = list.into_iter();
        if let Some((host, port)) = list.next() {
            (m.host, m.port) = (host, port);
        }
        m.failover = list.collect();
        moved = true;
    }
    if let Some(v) = t.duration_within(
        "failover_after",
        Duration::from_secs(1),
        MAX_FAILOVER_AFTER,
        errs,
    ) {
        m.failover_after = v;
    }
    if let Some(v) = t.opt("client_id", errs) {
        m.client_id = v;
    }
    if let Some(user) = t.opt("username", errs) {
        m.username = Some(user);
        m.password = None;
    }
    if let Some(p) = password(t, errs) {
        m.password = Some(p);
    }
    if let Some(tls) = tls(t, errs) {
        m.tls = Some(tls);
    }
    match super::socket::mqtt_socket(t, errs) {
        Some(path) => m.socket = Some(path),
        None if moved => m.socket = None,
        None => {}
    }
    delivery(t, m, errs);
}

/// How long a connection fails before the next of `hosts` is tried.
pub const DEFAULT_FAILOVER_AFTER: Duration = Duration::from_secs(30);
const MAX_FAILOVER_AFTER: Duration = Duration::from_secs(3600);
/// The most brokers one connection moves between.
const MAX_HOSTS: usize = 16;

/// `hosts = ["a:8883", "b:8883"]`: each `HOST:PORT` (an IPv6 address in brackets), at least
/// one, none twice.
fn hosts(t: &mut Table<'_>, errs: &mut Errors) -> Option<Vec<(String, u16)>> {
    let path = join(&t.path, "hosts");
    let list = t.opt::<Vec<String>>("hosts", errs)?;
    let mut out = Vec::new();
    if list.is_empty() || list.len() > MAX_HOSTS {
        errs.push(
            &path,
            t.origin(),
            format!("1 to {MAX_HOSTS} brokers, as \"HOST:PORT\""),
        );
        return None;
    }
    for entry in &list {
        let parsed = entry
            .rsplit_once(':')
            .and_then(|(h, p)| {
                Some((
                    h.trim_start_matches('[').trim_end_matches(']'),
                    p.parse::<u16>().ok()?,
                ))
            })
            .filter(|(h, p)| !h.is_empty() && *p > 0);
        match parsed {
            Some((h, p)) if !out.contains(&(h.to_string(), p)) => out.push((h.to_string(), p)),
            Some(_) => errs.push(&path, t.origin(), format!("{entry:?} is named twice")),
            None => errs.push(&path, t.origin(), format!("{entry:?} is not \"HOST:PORT\"")),
        }
    }
    (out.len() == list.len()).then_some(out)
}

/// A password read from a file: the line ending is not part of it.
fn secret(text: String) -> Secret {
    Secret(text.trim_end_matches(['\n', '\r']).to_string())
}

/// systemd's `LoadCredential=mqtt-password:…` puts it here for this service only.
fn systemd_credential() -> Option<Secret> {
    let dir = std::env::var_os("CREDENTIALS_DIRECTORY")?;
    std::fs::read_to_string(Path::new(&dir).join("mqtt-password"))
        .ok()
        .map(secret)
}

/// `password` or `password_file`, when the table has one.
fn password(t: &mut Table<'_>, errs: &mut Errors) -> Option<Secret> {
    let mut password = t.opt::<String>("password", errs).map(Secret);
    if let Some(file) = t.opt::<PathBuf>("password_file", errs) {
        match std::fs::read_to_string(&file) {
            Ok(p) => password = Some(secret(p)),
            Err(e) => errs.push(
                &join(&t.path, "password_file"),
                t.origin(),
                format!("cannot read {}: {e}", file.display()),
            ),
        }
    }
    password
}

/// `[mqtt.tls]`, built as `run` builds it.
fn tls(t: &mut Table<'_>, errs: &mut Errors) -> Option<Tls> {
    let mut tt = t.table("tls", errs)?;
    let tt_path = tt.path.clone();
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
    let tls = ca_file.map(|ca_file| Tls {
        ca_file,
        cert_file,
        key_file,
    });
    // Built here exactly as `run` builds it, so `check` (run as the service user) reports
    // a file the service could not read, and the gateway never starts without TLS.
    let files_exist = errs.list.iter().all(|e| !e.path.starts_with(&tt_path));
    if let Some(tls) = &tls
        && files_exist
        && let Err(e) = crate::config::tls::client_config(tls)
    {
        errs.push(&tt_path, t.origin(), format!("TLS cannot be set up: {e}"));
    }
    tls
}

/// Largest spool (1 TiB): beyond any edge PC's disk, and far from overflowing the byte count.
pub const MAX_SPOOL_MB: u64 = 1 << 20;

/// Readings wait this long at most to share a write to the broker with the next polls'.
pub const DEFAULT_BATCH: Duration = Duration::from_millis(250);

/// A dashboard a reading reaches later than this is not live any more.
const MAX_BATCH: Duration = Duration::from_secs(5);

/// Keep-alive, batch, QoS, retain, commands, spool size and topic root.
fn delivery(t: &mut Table<'_>, m: &mut Mqtt, errs: &mut Errors) {
    // MQTT carries it in 16 bits of seconds.
    let keep_alive_max = Duration::from_secs(u64::from(u16::MAX));
    if let Some(v) = t.duration_within("keep_alive", Duration::from_secs(5), keep_alive_max, errs) {
        m.keep_alive = v;
    }
    if let Some(v) = t.duration_within("batch", Duration::ZERO, MAX_BATCH, errs) {
        m.batch = v;
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
    if let Some(v) = t.opt("commands", errs) {
        m.commands = v;
    }
    if let Some(mb) = t.int::<u64>("spool_mb", errs) {
        if !(1..=MAX_SPOOL_MB).contains(&mb) {
            errs.push(
                &join(&t.path, "spool_mb"),
                t.origin(),
                format!("must be 1..{MAX_SPOOL_MB}"),
            );
        }
        m.spool_bytes = mb.min(MAX_SPOOL_MB) << 20;
    }
    if let Some(v) = t.opt::<String>("topic_root", errs) {
        if crate::topics::is_topic_prefix(&v) {
            m.topic_root = v;
        } else {
            errs.push(
                &join(&t.path, "topic_root"),
                t.origin(),
                "must be a topic without wildcards, empty levels or a leading/trailing '/'",
            );
        }
    }
}
