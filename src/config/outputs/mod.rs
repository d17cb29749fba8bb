//! `[outputs.NAME]`: where readings go. Each output is a northbound of its own (its own MQTT
//! connection, will, store and hold); its `kind` names its format, once, in [`OutputKind`]. The
//! keys of `[mqtt]` written in an output's table override `[mqtt]` for that output.
//!
//! `mqtt.format` (one kind or a list) with `[homeassistant] discovery` still works: it is read
//! here into the same outputs, on the `[mqtt]` broker.
//!
//! The gateway's own voice (its status and will, its boot marker, command and scan results, the
//! command topics) belongs to no output kind: it rides on the first output that publishes the
//! gateway's JSON topics on the `[mqtt]` broker under `mqtt.topic_root`, or, when none does,
//! on a connection of its own ([`VoiceHome`]).

use std::fmt;
use std::str::FromStr;

pub mod homeassistant;
pub mod sparkplug;

use config::ValueKind;

use super::connection::Mqtt;
use super::protocols::Servers;
use super::walk::{Errors, Table, join};
use homeassistant::HomeAssistant;
use sparkplug::Sparkplug;

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

/// What an output publishes: the one list of formats the config checks against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum OutputKind {
    /// The gateway's JSON topics (`<root>/<device>/<channel>`, statuses, intervals).
    Json,
    /// A Sparkplug B edge node (`[sparkplug]`).
    Sparkplug,
    /// The JSON topics with Home Assistant discovery configs (`[homeassistant]`).
    HomeAssistant,
}

impl OutputKind {
    /// Every kind, in the order the config's error message lists them.
    pub const ALL: [OutputKind; 3] = [
        OutputKind::Json,
        OutputKind::Sparkplug,
        OutputKind::HomeAssistant,
    ];

    /// The name the config writes.
    pub fn name(self) -> &'static str {
        match self {
            OutputKind::Json => "json",
            OutputKind::Sparkplug => "sparkplug",
            OutputKind::HomeAssistant => "homeassistant",
        }
    }

    /// Whether it publishes the gateway's JSON topics under its topic root (and so says the
    /// gateway's status there, with that status as its will).
    pub fn carries_gateway_topics(self) -> bool {
        matches!(self, OutputKind::Json | OutputKind::HomeAssistant)
    }

    /// The kinds as the error message lists them: `"json", "sparkplug", "homeassistant"`.
    pub fn list() -> String {
        let names: Vec<String> = Self::ALL
            .iter()
            .map(|k| format!("{:?}", k.name()))
            .collect();
        names.join(", ")
    }
}

impl fmt::Display for OutputKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not an output kind.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown output format {0:?}: one of {list}, or {servers}", list = OutputKind::list(), servers = Servers::kinds())]
pub struct UnknownKind(pub String);

impl FromStr for OutputKind {
    type Err = UnknownKind;
    fn from_str(s: &str) -> Result<OutputKind, UnknownKind> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| UnknownKind(s.to_string()))
    }
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

/// The outputs of a gateway, and the settings of the formats they use.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs {
    /// Sorted by name.
    pub list: Vec<OutputConfig>,
    pub voice: VoiceHome,
    /// `[sparkplug]`: present exactly when an output is of kind `sparkplug`.
    pub sparkplug: Option<Sparkplug>,
    /// `[homeassistant]`: its prefix, for the outputs of kind `homeassistant`.
    pub homeassistant: HomeAssistant,
    /// The serving outputs (servers for PLCs, not MQTT connections), by their protocol.
    pub servers: Servers,
}

/// The name the gateway's own connection takes (no output may take it).
pub const VOICE_NAME: &str = "gateway";

/// The longest output name (it goes into client ids, file names and metric labels).
const MAX_NAME: usize = 32;

impl Outputs {
    /// Whether some output is of `kind`.
    pub fn has(&self, kind: OutputKind) -> bool {
        self.list.iter().any(|o| o.kind == kind)
    }

    /// Topic prefixes no command may point a response topic into, besides the gateway's own
    /// root: the formats' namespaces on the brokers the gateway writes to.
    pub fn reserved_prefixes(&self) -> Vec<(String, &'static str)> {
        vec![
            (
                self.homeassistant.prefix.clone(),
                "it is under the Home Assistant discovery prefix",
            ),
            (
                sparkplug::NAMESPACE.to_string(),
                "it is in the Sparkplug B namespace (births, data and deaths of nodes)",
            ),
        ]
    }
}

/// Reads `[outputs]` (or the older `mqtt.format`), `[sparkplug]` and `[homeassistant]` against
/// the checked `[mqtt]`.
pub(crate) fn read(
    root: &mut Table<'_>,
    legacy: Option<Vec<OutputKind>>,
    base: &Mqtt,
    gateway_id: &str,
    errs: &mut Errors,
) -> Outputs {
    let ha_table = root.table("homeassistant", errs);
    let (homeassistant, discovery) = homeassistant::read(ha_table, errs);
    let sp_table = root.table("sparkplug", errs);
    let sparkplug_set = sp_table.is_some();
    let sparkplug = sparkplug::sparkplug(sp_table, gateway_id, errs);
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
            .filter_map(|(name, value)| output(&name, value, base, errs))
            .collect()
    };
    let has_sparkplug = list
        .iter()
        .any(|o: &OutputConfig| o.kind == OutputKind::Sparkplug);
    if has_sparkplug && !sparkplug_set {
        let why = "an output of kind \"sparkplug\" needs [sparkplug] with its group_id";
        errs.push("sparkplug", origin.as_deref(), why);
    } else if sparkplug_set && !has_sparkplug {
        let why = "[sparkplug] is set but no output is of kind \"sparkplug\"";
        errs.push("sparkplug", origin.as_deref(), why);
    }
    clashes(&list, base, errs);
    Outputs {
        voice: voice_home(&list, base),
        list,
        sparkplug,
        servers: servers_read,
        homeassistant,
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
    let kinds = kinds.unwrap_or(&[OutputKind::Json]);
    let discovery = discovery.unwrap_or(false);
    if discovery && !kinds.contains(&OutputKind::Json) {
        let why = "Home Assistant discovery describes the JSON topics: add \"json\" to mqtt.format";
        errs.push("homeassistant.discovery", None, why);
    }
    let mut list: Vec<OutputConfig> = kinds
        .iter()
        .map(|&kind| {
            let mut mqtt = base.clone();
            if kind != OutputKind::Json {
                mqtt.client_id = format!("{}-{}", base.client_id, kind.name());
            }
            let kind = match kind {
                OutputKind::Json if discovery => OutputKind::HomeAssistant,
                k => k,
            };
            let name = if kind == OutputKind::HomeAssistant {
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
    base: &Mqtt,
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
    let kind = match t
        .req::<String>("kind", errs)
        .map(|k| k.parse::<OutputKind>())
    {
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
pub(crate) fn formats(t: &mut Table<'_>, errs: &mut Errors) -> Option<Vec<OutputKind>> {
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
        match name.parse::<OutputKind>() {
            Err(e) => errs.push(&path, t.origin(), e.to_string()),
            Ok(OutputKind::HomeAssistant) => {
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
