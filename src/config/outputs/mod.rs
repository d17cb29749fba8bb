//! `[outputs.NAME]`: where readings go. Each output is a northbound of its own (its own MQTT
//! connection, will, store and hold); its `kind` is one of the output registry's
//! (`publish/formats.rs`), handed in as [`Kinds`]: each kind's file here holds its part
//! ([`kind::Kind`]: its name, its own table and the file that reads it, the topics it reserves).
//! The keys of `[mqtt]` written in an output's table override `[mqtt]` for that output.
//!
//! `mqtt.format` (one kind or a list) with `[homeassistant] discovery` still works: it is read
//! here into the same outputs, on the `[mqtt]` broker.
//!
//! The gateway's own voice (its status and will, its boot marker, command and scan results, the
//! command topics) belongs to no output kind: it rides on the first output that publishes the
//! gateway's JSON topics on the `[mqtt]` broker under `mqtt.topic_root`, or, when none does,
//! on a connection of its own ([`VoiceHome`]).

use std::sync::Arc;

pub mod homeassistant;
pub mod json;
pub mod kind;
pub mod sparkplug;

use config::ValueKind;

use super::connection::Mqtt;
use super::protocols::Servers;
use super::walk::{Errors, Table, join};
use homeassistant::HomeAssistant;
pub use kind::{Kind, Kinds, OutputKind, Settings};

/// A device's own keys for the outputs (`server_unit = N`: the unit id it answers as on a
/// server output), read beside its bus's keys whatever protocol the bus speaks.
pub(crate) fn device_keys(t: &mut Table<'_>, path: &str, errs: &mut Errors) -> Option<u8> {
    Servers::device_keys(t, path, errs)
}

impl Outputs {
    /// Whether an output serves the devices' registers (and so needs a register map).
    pub fn serve_registers(&self) -> bool {
        !self.servers.is_empty()
    }

    /// Each server output: its name, kind and where it listens.
    pub fn servers(&self) -> impl Iterator<Item = (&str, &'static str, String)> {
        self.servers.each()
    }

    /// What `check --register-map` says when no output would serve the map it prints.
    pub fn register_map_note(&self) -> Option<String> {
        self.servers.is_empty().then(|| {
            format!(
                "warning: no output of kind {:?}: the map is what one would serve",
                Servers::kind()
            )
        })
    }

    /// Whether a server output takes commands (its map then has their registers).
    pub fn serve_commands(&self) -> bool {
        self.servers.take_commands()
    }
}

/// A name that is not an output kind: the kinds listed are the registry's.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown output format {0:?}: one of {1}, or {servers}", servers = Servers::kinds())]
pub struct UnknownKind(pub String, pub String);

/// The kind named `name` among `kinds`.
pub fn parse_kind(kinds: &Kinds, name: &str) -> Result<OutputKind, UnknownKind> {
    kinds
        .find(name)
        .ok_or_else(|| UnknownKind(name.to_string(), kinds.list()))
}

/// One output, checked: its kind and its connection (`[mqtt]` with its own keys over it).
#[derive(Debug, Clone, PartialEq)]
pub struct OutputConfig {
    /// The table's name: in logs, metrics (`output` label), the client id and the spool's folder.
    pub name: String,
    pub kind: OutputKind,
    pub mqtt: Mqtt,
}

/// Where the gateway's own voice is said.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum VoiceHome {
    /// On the output at this index of [`Outputs::list`].
    Output(usize),
    /// On a connection of its own to the `[mqtt]` broker, as `mqtt.client_id`.
    Own,
}

/// The outputs of a gateway, and the settings of the kinds they use.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs {
    /// Sorted by name.
    pub list: Vec<OutputConfig>,
    pub voice: VoiceHome,
    /// Each kind's settings from its own table (`[sparkplug]`, `[homeassistant]`), by kind name;
    /// found by their type with [`Outputs::settings`].
    pub settings: Vec<(&'static str, Arc<dyn Settings>)>,
    /// Topic prefixes the kinds reserve, and why ([`Outputs::reserved_prefixes`]).
    pub reserved: Vec<(String, &'static str)>,
    /// The serving outputs (servers for PLCs, not MQTT connections), by their protocol.
    pub servers: Servers,
}

/// The name the gateway's own connection takes (no output may take it).
pub const VOICE_NAME: &str = "gateway";

/// The longest output name (it goes into client ids, file names and metric labels).
const MAX_NAME: usize = 32;

impl Outputs {
    /// Whether some output is of `kind`.
    pub fn has(&self, kind: &Kind) -> bool {
        self.list.iter().any(|o| o.kind.is(kind))
    }

    /// A kind's settings of type `T`, when its table was read.
    pub fn settings<T: Settings>(&self) -> Option<&T> {
        self.settings
            .iter()
            .find_map(|(_, s)| (**s).as_any().downcast_ref::<T>())
    }

    /// Topic prefixes no command may point a response topic into, besides the gateway's own
    /// root: the kinds' namespaces on the brokers the gateway writes to.
    pub fn reserved_prefixes(&self) -> Vec<(String, &'static str)> {
        self.reserved.clone()
    }
}

/// Each kind's own table, read by its own file: whether it was there, and what it said.
struct OwnTables(Vec<Own>);

/// A kind's own table, read.
struct Own {
    kind: &'static Kind,
    present: bool,
    settings: Option<Arc<dyn Settings>>,
}

impl OwnTables {
    fn read(root: &mut Table<'_>, kinds: &Kinds, gateway_id: &str, errs: &mut Errors) -> Self {
        let cx = kind::Context { gateway_id };
        let mut out = Vec::new();
        for &kind in &kinds.0 {
            let Some(own) = &kind.table else {
                continue;
            };
            let table = root.table(own.name, errs);
            let present = table.is_some();
            let settings = (own.read)(table, &cx, errs);
            out.push(Own {
                kind,
                present,
                settings,
            });
        }
        OwnTables(out)
    }

    /// A table a kind needs that no output asked for, or the other way round.
    fn check_needed(&self, list: &[OutputConfig], origin: Option<&str>, errs: &mut Errors) {
        for Own { kind, present, .. } in &self.0 {
            let Some(own) = &kind.table else { continue };
            let Some(what) = own.needed else { continue };
            let (name, table) = (kind.name, own.name);
            let used = list.iter().any(|o| o.kind.is(kind));
            if used && !present {
                let why = format!("an output of kind {name:?} needs [{table}] {what}");
                errs.push(table, origin, why);
            } else if *present && !used {
                let why = format!("[{table}] is set but no output is of kind {name:?}");
                errs.push(table, origin, why);
            }
        }
    }

    fn settings_of(&self, kind: &Kind) -> Option<&dyn Settings> {
        self.0
            .iter()
            .find(|own| own.kind.name == kind.name)
            .and_then(|own| own.settings.as_deref())
    }
}

/// Reads `[outputs]` (or the older `mqtt.format`) and each kind's own table against the
/// checked `[mqtt]`.
pub(crate) fn read(
    root: &mut Table<'_>,
    (legacy, kinds): (Option<Vec<OutputKind>>, &Kinds),
    base: &Mqtt,
    gateway_id: &str,
    errs: &mut Errors,
) -> Outputs {
    let tables = OwnTables::read(root, kinds, gateway_id, errs);
    let discovery = tables
        .settings_of(&homeassistant::KIND)
        .and_then(|s| s.as_any().downcast_ref::<HomeAssistant>())
        .and_then(|h| h.discovery);
    let entries = root.entries("outputs", errs);
    let origin = root.origin().map(str::to_string);
    let mut servers_read = Servers::default();
    let list = if entries.is_empty() {
        from_format(legacy.as_deref(), discovery, base, errs)
    } else {
        if legacy.is_some() {
            let why = "set either mqtt.format or [outputs.NAME] tables, not both";
            errs.push("mqtt.format", origin.as_deref(), why);
        }
        if discovery == Some(true) {
            let why = "with [outputs], Home Assistant discovery is an output of kind \"homeassistant\"; remove discovery";
            errs.push("homeassistant.discovery", origin.as_deref(), why);
        }
        let (servers, connections): (Vec<_>, Vec<_>) = entries
            .into_iter()
            .partition(|(_, value)| kind_of(value).is_some_and(|k| Servers::is_kind(&k)));
        for (name, value) in servers {
            server(&name, value, &mut servers_read, errs);
        }
        connections
            .into_iter()
            .filter_map(|(name, value)| output(&name, value, (base, kinds), errs))
            .collect()
    };
    tables.check_needed(&list, origin.as_deref(), errs);
    clashes(&list, base, errs);
    let reserved = kinds
        .0
        .iter()
        .filter_map(|k| (k.reserved)(tables.settings_of(k)))
        .collect();
    let settings = tables.0.into_iter();
    let settings = settings.filter_map(|own| Some((own.kind.name, own.settings?)));
    Outputs {
        voice: voice_home(&list, base),
        list,
        settings: settings.collect(),
        reserved,
        servers: servers_read,
    }
}

/// `mqtt.format` as outputs on the `[mqtt]` broker: the JSON one (with discovery when asked)
/// keeps `mqtt.client_id`, so a broker's rules for the gateway's client still hold; the
/// others take `<client_id>-<kind>`.
fn from_format(
    kinds: Option<&[OutputKind]>,
    discovery: Option<bool>,
    base: &Mqtt,
    errs: &mut Errors,
) -> Vec<OutputConfig> {
    let json = OutputKind::of(&json::KIND);
    let kinds = kinds.unwrap_or(std::slice::from_ref(&json));
    let discovery = discovery.unwrap_or(false);
    if discovery && !kinds.contains(&json) {
        let why = "Home Assistant discovery describes the JSON topics: add \"json\" to mqtt.format";
        errs.push("homeassistant.discovery", None, why);
    }
    let mut list: Vec<OutputConfig> = kinds
        .iter()
        .map(|&kind| {
            let mut mqtt = base.clone();
            if kind != json {
                mqtt.client_id = format!("{}-{}", base.client_id, kind.name());
            }
            let kind = match kind {
                k if k == json && discovery => OutputKind::of(&homeassistant::KIND),
                k => k,
            };
            let name = if kind.is(&homeassistant::KIND) {
                "json"
            } else {
                kind.name()
            };
            OutputConfig {
                name: name.to_string(),
                kind,
                mqtt,
            }
        })
        .collect();
    list.sort_by(|a, b| a.name.cmp(&b.name));
    list
}

/// The `kind` an `[outputs.NAME]` table names, if it names one as text.
fn kind_of(value: &config::Value) -> Option<String> {
    match &value.kind {
        ValueKind::Table(t) => match &t.get("kind")?.kind {
            ValueKind::String(k) => Some(k.clone()),
            _ => None,
        },
        _ => None,
    }
}

/// One `[outputs.NAME]` table of a serving kind, read into `servers`.
fn server(name: &str, value: &config::Value, servers: &mut Servers, errs: &mut Errors) {
    let path = format!("outputs.{name}");
    let Some(mut t) = Table::of(value, &path, errs) else {
        return;
    };
    if !is_output_name(name) {
        let why = format!(
            "{name:?} is not an output name: 1..{MAX_NAME} of a-z, 0-9, '_' and '-', not {VOICE_NAME:?}"
        );
        errs.push(&path, t.origin(), why);
    }
    let _ = t.raw("kind");
    servers.read(name, t, errs);
}

/// One `[outputs.NAME]` table.
fn output(
    name: &str,
    value: &config::Value,
    (base, kinds): (&Mqtt, &Kinds),
    errs: &mut Errors,
) -> Option<OutputConfig> {
    let path = format!("outputs.{name}");
    let mut t = Table::of(value, &path, errs)?;
    if !is_output_name(name) {
        let why = format!(
            "{name:?} is not an output name: 1..{MAX_NAME} of a-z, 0-9, '_' and '-', not {VOICE_NAME:?}"
        );
        errs.push(&path, t.origin(), why);
    }
    let kind = match t.req::<String>("kind", errs).map(|k| parse_kind(kinds, &k)) {
        Some(Ok(kind)) => Some(kind),
        Some(Err(e)) => {
            errs.push(&join(&path, "kind"), t.origin(), e.to_string());
            None
        }
        None => None,
    };
    let mut mqtt = base.clone();
    mqtt.client_id = format!("{}-{name}", base.client_id);
    super::mqtt::overlay(&mut t, &mut mqtt, errs);
    if mqtt.socket.is_some() && mqtt.tls.is_some() {
        let why = "a local socket with TLS: TLS is not used over a Unix socket; set tls or socket for this output, not both";
        errs.push(&path, t.origin(), why);
    }
    t.finish(errs);
    Some(OutputConfig {
        name: name.to_string(),
        kind: kind?,
        mqtt,
    })
}

/// An output name: it becomes a file name, part of a client id and a metric label.
fn is_output_name(name: &str) -> bool {
    (1..=MAX_NAME).contains(&name.len())
        && name != VOICE_NAME
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-')
}

/// Two outputs that would fight on one broker: the same client id (each takes the other's
/// session), or the gateway's JSON topics twice (every reading published twice).
fn clashes(list: &[OutputConfig], base: &Mqtt, errs: &mut Errors) {
    for (i, a) in list.iter().enumerate() {
        let others = list[..i].iter();
        for b in others {
            if a.mqtt.broker() != b.mqtt.broker() {
                continue;
            }
            if a.mqtt.client_id == b.mqtt.client_id {
                let why = format!(
                    "same client id {:?} on the same broker as output {:?}: each would take the other's session",
                    a.mqtt.client_id, b.name
                );
                errs.push(&format!("outputs.{}.client_id", a.name), None, why);
            }
            let both_json = a.kind.carries_gateway_topics() && b.kind.carries_gateway_topics();
            if both_json && a.mqtt.topic_root == b.mqtt.topic_root {
                let why = format!(
                    "publishes the same JSON topics on the same broker as output {:?}: give one another topic_root or broker",
                    b.name
                );
                errs.push(&format!("outputs.{}", a.name), None, why);
            }
        }
        let own_voice = voice_home(list, base) == VoiceHome::Own;
        if own_voice && a.mqtt.broker() == base.broker() && a.mqtt.client_id == base.client_id {
            let why = format!(
                "the gateway's own connection uses {:?} on this broker (mqtt.client_id)",
                base.client_id
            );
            errs.push(&format!("outputs.{}.client_id", a.name), None, why);
        }
    }
}

/// The first output that says the gateway's JSON topics where `[mqtt]` points, else its own.
fn voice_home(list: &[OutputConfig], base: &Mqtt) -> VoiceHome {
    list.iter()
        .position(|o| {
            o.kind.carries_gateway_topics()
                && o.mqtt.broker() == base.broker()
                && o.mqtt.topic_root == base.topic_root
        })
        .map_or(VoiceHome::Own, VoiceHome::Output)
}

/// Reads `mqtt.format`: one kind or a list of kinds, none twice; `None` when absent (or broken:
/// the error is in `errs`).
pub(crate) fn formats(
    t: &mut Table<'_>,
    known: &Kinds,
    errs: &mut Errors,
) -> Option<Vec<OutputKind>> {
    let path = join(&t.path, "format");
    let value = t.raw("format")?;
    let list: Option<Vec<String>> = match &value.kind {
        ValueKind::String(name) => Some(vec![name.clone()]),
        ValueKind::Array(items) => items
            .iter()
            .map(|v| match &v.kind {
                ValueKind::String(name) => Some(name.clone()),
                _ => None,
            })
            .collect(),
        _ => None,
    };
    let Some(list) = list else {
        let why = "expected a format name or a list of names (\"json\", [\"json\", \"sparkplug\"])";
        errs.push(&path, value.origin(), why);
        return None;
    };
    if list.is_empty() {
        errs.push(&path, t.origin(), "an empty list: name at least one format");
        return None;
    }
    let mut kinds = Vec::new();
    for name in &list {
        match parse_kind(known, name) {
            Err(e) => errs.push(&path, t.origin(), e.to_string()),
            Ok(k) if k.is(&homeassistant::KIND) => {
                let why = "homeassistant is not a payload format: set [homeassistant] discovery = true, or use [outputs]";
                errs.push(&path, t.origin(), why);
            }
            Ok(k) if kinds.contains(&k) => {
                errs.push(&path, t.origin(), format!("{name:?} is named twice"));
            }
            Ok(k) => kinds.push(k),
        }
    }
    (kinds.len() == list.len()).then_some(kinds)
}
