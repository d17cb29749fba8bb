//! The parts every Home Assistant discovery entity is made of: where discovery goes (`Site`),
//! the module an entity belongs to, the entity itself, the state topic a template reads, and
//! the common keys (origin, availability, device). `entities.rs` builds the gateway's,
//! devices' and channels' entities from them, `meter_entities.rs` the meter's. Pure.

use serde_json::{Value, json};

use crate::config::outputs::homeassistant::HomeAssistant;
use crate::config::policy::PayloadMode;
use crate::config::units::ChannelUnits;
use crate::config::{Config, Device};
use crate::profile::{ChannelKind, ChannelSpec};
use crate::reading::{Measure, Reading};
use crate::topics::Topics;

/// Where discovery goes and what it points at.
#[derive(Debug, Clone)]
pub struct Site {
    /// Discovery prefix (`homeassistant`).
    pub prefix: String,
    /// Gateway id: the node id of every config topic.
    pub gateway: String,
    /// Our own topics (state, status, commands).
    pub topics: Topics,
    /// The gateway's default payload shape.
    pub payload: PayloadMode,
    /// `gateway.intervals`: interval periods of channels that do not say otherwise.
    pub intervals: Option<Vec<crate::metering::Period>>,
    /// `[tariffs]`: the tariffs, each a register of every metered channel.
    pub tariffs: Vec<String>,
    /// `[billing]`: metered channels close billing periods.
    pub billing: Option<BillingSite>,
}

impl Site {
    pub fn of(config: &Config) -> Site {
        Site {
            prefix: config
                .outputs
                .settings::<HomeAssistant>()
                .cloned()
                .unwrap_or_default()
                .prefix,
            gateway: config.gateway.id.clone(),
            topics: Topics::new(&config.mqtt.topic_root),
            payload: config.gateway.payload,
            intervals: config.gateway.intervals.clone(),
            tariffs: config
                .gateway
                .tariffs
                .as_ref()
                .map(|c| c.names().to_vec())
                .unwrap_or_default(),
            billing: config.gateway.billing.as_ref().map(|b| BillingSite {
                demand: b.demand.is_some(),
            }),
        }
    }

    /// `<prefix>/status`, where Home Assistant says `online` after it starts.
    pub fn ha_status(&self) -> String {
        format!("{}/status", self.prefix)
    }

    /// Filter of every config topic of this gateway.
    pub fn config_filter(&self) -> String {
        format!("{}/+/{}/+/config", self.prefix, self.gateway)
    }

    pub(super) fn gateway_identifier(&self) -> String {
        format!("pulsegate_{}", self.gateway)
    }
}

/// Where billing goes, as discovery needs it.
#[derive(Debug, Clone, Copy)]
pub struct BillingSite {
    /// `[billing] demand` is set: billing records carry a demand.
    pub demand: bool,
}

/// One discovered entity: its component (`sensor`, `button`), object id and config payload.
#[derive(Debug, Clone, PartialEq)]
pub struct Entity {
    pub component: &'static str,
    pub object_id: String,
    pub config: Value,
}

impl Entity {
    /// `<prefix>/<component>/<gateway>/<object_id>/config`.
    pub fn topic(&self, site: &Site) -> String {
        format!(
            "{}/{}/{}/{}/config",
            site.prefix, self.component, site.gateway, self.object_id
        )
    }
}

/// A module: a device of the config and the bus it is on.
#[derive(Debug, Clone, Copy)]
pub struct Module<'a> {
    pub bus: &'a str,
    pub device: &'a Device,
}

impl Module<'_> {
    /// The module's place on the wire, stable across renames.
    pub(super) fn key(&self) -> String {
        format!("{}_{}", self.bus, self.device.place_tag())
    }

    pub(super) fn payload(&self, site: &Site) -> PayloadMode {
        self.device.payload.unwrap_or(site.payload)
    }
}

pub(super) fn origin() -> Value {
    json!({ "name": "pulsegate", "sw_version": env!("CARGO_PKG_VERSION") })
}

/// Available only while the gateway and the module both say exactly `online` (a module's
/// `offline`, `wrong_model` or anything else makes its entities unavailable).
pub(super) fn availability(site: &Site, device: &str) -> Value {
    let only_online = "{{ 'online' if value == 'online' else 'offline' }}";
    json!([
        { "topic": site.topics.gateway_status(), "value_template": only_online,
          "payload_available": "online", "payload_not_available": "offline" },
        { "topic": site.topics.device_status(device), "value_template": only_online,
          "payload_available": "online", "payload_not_available": "offline" },
    ])
}

/// Where the module is, for its device's `serial_number`: `line1 unit 3`, `mbus1 address 5`,
/// `mbus1 id 12345678`.
fn serial(m: Module<'_>) -> String {
    format!("{} {}", m.bus, m.device.address.short())
}

pub(super) fn module_device(site: &Site, m: Module<'_>) -> Value {
    let profile = &m.device.profile;
    let mut device = json!({
        "identifiers": [format!("{}_{}", site.gateway_identifier(), m.key())],
        "name": m.device.name,
        "model": profile.title,
        "model_id": profile.model,
        "serial_number": serial(m),
        "via_device": site.gateway_identifier(),
    });
    // The profile's maker is that of its own model; an alias (IBF67 on the YL67 map) may be
    // another maker's, so it gets none.
    if let Some(maker) = profile
        .manufacturer
        .as_ref()
        .filter(|_| m.device.model == profile.model)
    {
        device["manufacturer"] = maker.clone().into();
    }
    device
}

/// The keys every entity of a module shares.
pub(super) fn common(
    site: &Site,
    m: Module<'_>,
    component: &str,
    object: &str,
    name: &str,
) -> Value {
    json!({
        "name": name,
        "unique_id": format!("{}_{}_{object}", site.gateway_identifier(), m.key()),
        "default_entity_id": format!("{component}.{}_{}_{object}", site.gateway, m.device.name),
        "device": module_device(site, m),
        "availability": availability(site, &m.device.name),
        "availability_mode": "all",
        "origin": origin(),
    })
}

pub(super) fn merge(mut base: Value, more: Value) -> Value {
    if let (Some(b), Value::Object(m)) = (base.as_object_mut(), more) {
        b.extend(m);
    }
    base
}

/// Where a channel's readings arrive and how a template reaches one of its keys.
pub struct State {
    pub topic: String,
    channel: Option<String>,
}

impl State {
    pub(super) fn of(site: &Site, m: Module<'_>, channel: &str) -> State {
        match m.payload(site) {
            PayloadMode::Channel => State {
                topic: site.topics.reading(&m.device.name, channel),
                channel: None,
            },
            PayloadMode::Device => State {
                topic: site.topics.device(&m.device.name),
                channel: Some(channel.to_string()),
            },
        }
    }

    /// A template of `key`; a message without it (or, per device, without the channel)
    /// keeps the entity's state.
    pub(super) fn template(&self, key: &str) -> String {
        match &self.channel {
            None => {
                format!("{{{{ value_json['{key}'] if '{key}' in value_json else this.state }}}}")
            }
            Some(c) => format!(
                "{{{{ value_json['{c}']['{key}'] if '{c}' in value_json and '{key}' in \
                 value_json['{c}'] else this.state }}}}"
            ),
        }
    }

    /// A template of `key` that renders empty when the message lacks it (Home Assistant
    /// ignores an empty `last_reset`).
    pub(super) fn optional(&self, key: &str) -> String {
        match &self.channel {
            None => format!("{{{{ value_json.get('{key}', '') }}}}"),
            Some(c) => format!("{{{{ value_json.get('{c}', {{}}).get('{key}', '') }}}}"),
        }
    }

    /// The attributes template: count, event, seq and OBIS name of the last reading.
    pub(super) fn attributes(&self) -> String {
        let r = match &self.channel {
            None => "value_json".to_string(),
            Some(c) => format!("value_json.get('{c}', {{}})"),
        };
        format!(
            "{{{{ {{'count': {r}.get('count'), 'event': {r}.get('event'), 'seq': {r}.get('seq'), 'obis': {r}.get('obis')}} | tojson }}}}"
        )
    }
}

pub fn sensor(site: &Site, m: Module<'_>, object: String, name: String, more: Value) -> Entity {
    let config = merge(common(site, m, "sensor", &object, &name), more);
    Entity {
        component: "sensor",
        object_id: format!("{}_{object}", m.key()),
        config,
    }
}

/// What a channel's entities are made of: its name and kind, whether the module measures its
/// frequency and speed (from the profile); for a channel its device declares (an M-Bus
/// meter's record), the units it declared and whether it is a gauge (a value, not a count).
#[derive(Debug, Clone, PartialEq)]
pub struct Shape {
    pub name: String,
    pub kind: ChannelKind,
    pub freq: bool,
    pub rpm: bool,
    /// `Some(numeric)` for a gauge (text, such as a date, is not numeric).
    pub gauge: Option<bool>,
    /// The units the device declared (a `scale` in the config wins).
    pub declared: Option<ChannelUnits>,
}

impl Shape {
    /// A profile's channel.
    pub fn of_spec(spec: &ChannelSpec) -> Shape {
        Shape {
            name: spec.name.clone(),
            kind: spec.kind,
            freq: spec.freq.is_some(),
            rpm: spec.rpm.is_some(),
            gauge: None,
            declared: None,
        }
    }

    /// A channel its device declared, as its reading shows it.
    pub fn of_reading(r: &Reading) -> Shape {
        Shape {
            name: r.channel.to_string(),
            kind: r.kind,
            freq: r.freq_hz.is_some(),
            rpm: r.rpm.is_some(),
            gauge: r.measured.as_ref().map(|m| !matches!(m, Measure::Text(_))),
            declared: r.units.as_deref().cloned(),
        }
    }
}

/// The channel's unit, class and precision (pulses without a scale).
pub(super) fn with_units(mut more: Value, units: &ChannelUnits) -> Value {
    match units.scale {
        Some(s) => {
            if let Some(u) = &units.unit {
                more["unit_of_measurement"] = u.clone().into();
            }
            if let Some(class) = &units.device_class {
                more["device_class"] = class.clone().into();
            }
            more["suggested_display_precision"] = s.places().into();
        }
        None => more["unit_of_measurement"] = "pulses".into(),
    }
    more
}
