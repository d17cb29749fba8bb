//! Home Assistant MQTT discovery payloads. Pure: config in, retained config messages out.
//!
//! One HA device per module, linked `via_device` to one device for the gateway. Entities are
//! named after the module's place on the wire (bus and unit), not its display name, so renaming
//! a device in the config keeps its entities and their history: unique ids and config topics
//! are `<bus>_u<unit>_<channel>_<entity>` under the gateway id.

use std::collections::BTreeSet;

use serde_json::{Value, json};

use crate::config::policy::PayloadMode;
use crate::config::units::ChannelUnits;
use crate::config::units::rate_device_class;
use crate::config::{Config, Device};
use crate::profile::{ChannelKind, ChannelSpec};
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
}

impl Site {
    pub fn of(config: &Config) -> Site {
        Site {
            prefix: config.homeassistant.prefix.clone(),
            gateway: config.gateway.id.clone(),
            topics: Topics::new(&config.mqtt.topic_root),
            payload: config.gateway.payload,
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

    fn gateway_identifier(&self) -> String {
        format!("pulsegate_{}", self.gateway)
    }
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
    fn key(&self) -> String {
        format!("{}_u{}", self.bus, self.device.unit)
    }

    fn payload(&self, site: &Site) -> PayloadMode {
        self.device.payload.unwrap_or(site.payload)
    }
}

fn origin() -> Value {
    json!({ "name": "pulsegate", "sw_version": env!("CARGO_PKG_VERSION") })
}

/// Available only while the gateway and the module both say exactly `online` (a module's
/// `offline`, `wrong_model` or anything else makes its entities unavailable).
fn availability(site: &Site, device: &str) -> Value {
    let only_online = "{{ 'online' if value == 'online' else 'offline' }}";
    json!([
        { "topic": site.topics.gateway_status(), "value_template": only_online,
          "payload_available": "online", "payload_not_available": "offline" },
        { "topic": site.topics.device_status(device), "value_template": only_online,
          "payload_available": "online", "payload_not_available": "offline" },
    ])
}

fn module_device(site: &Site, m: Module<'_>) -> Value {
    let profile = &m.device.profile;
    let mut device = json!({
        "identifiers": [format!("{}_{}", site.gateway_identifier(), m.key())],
        "name": m.device.name,
        "model": profile.title,
        "model_id": profile.model,
        "serial_number": format!("{} unit {}", m.bus, m.device.unit),
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
fn common(site: &Site, m: Module<'_>, component: &str, object: &str, name: &str) -> Value {
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

fn merge(mut base: Value, more: Value) -> Value {
    if let (Some(b), Value::Object(m)) = (base.as_object_mut(), more) {
        b.extend(m);
    }
    base
}

/// The gateway's own device, with its status as a diagnostic sensor so `via_device` resolves.
pub fn gateway_entities(site: &Site) -> Vec<Entity> {
    let config = json!({
        "name": "Status",
        "unique_id": format!("{}_status", site.gateway_identifier()),
        "default_entity_id": format!("sensor.{}_status", site.gateway),
        "state_topic": site.topics.gateway_status(),
        "entity_category": "diagnostic",
        "device": {
            "identifiers": [site.gateway_identifier()],
            "name": format!("pulsegate {}", site.gateway),
            "manufacturer": "pulsegate",
            "model": "Modbus pulse gateway",
            "sw_version": env!("CARGO_PKG_VERSION"),
        },
        "origin": origin(),
    });
    vec![Entity {
        component: "sensor",
        object_id: "gateway_status".into(),
        config,
    }]
}

/// The device-wide clear button, where commands are enabled.
pub fn device_entities(site: &Site, m: Module<'_>) -> Vec<Entity> {
    if !m.device.commands {
        return Vec::new();
    }
    let object = "clear_all";
    let config = merge(
        common(site, m, "button", object, "Clear all"),
        json!({
            "command_topic": site.topics.device_command(&m.device.name),
            "payload_press": r#"{"op":"clear_all"}"#,
            "qos": 1,
            "retain": false,
            "entity_category": "config",
        }),
    );
    vec![Entity {
        component: "button",
        object_id: format!("{}_{object}", m.key()),
        config,
    }]
}

/// Where a channel's readings arrive and how a template reaches one of its keys.
struct State {
    topic: String,
    channel: Option<String>,
}

impl State {
    fn of(site: &Site, m: Module<'_>, channel: &str) -> State {
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
    fn template(&self, key: &str) -> String {
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

    /// The attributes template: count, event and seq of the last reading.
    fn attributes(&self) -> String {
        let r = match &self.channel {
            None => "value_json".to_string(),
            Some(c) => format!("value_json.get('{c}', {{}})"),
        };
        format!(
            "{{{{ {{'count': {r}.get('count'), 'event': {r}.get('event'), 'seq': {r}.get('seq')}} | tojson }}}}"
        )
    }
}

fn sensor(site: &Site, m: Module<'_>, object: String, name: String, more: Value) -> Entity {
    let config = merge(common(site, m, "sensor", &object, &name), more);
    Entity {
        component: "sensor",
        object_id: format!("{}_{object}", m.key()),
        config,
    }
}

/// The total (or an encoder's position) with its units, class and attributes.
fn total(site: &Site, m: Module<'_>, spec: &ChannelSpec, units: &ChannelUnits) -> Entity {
    let ch = &spec.name;
    let state = State::of(site, m, ch);
    let encoder = spec.kind == ChannelKind::Encoder;
    // Only a count that never goes down is a meter total; an encoder moves both ways.
    let state_class = if encoder {
        "measurement"
    } else {
        "total_increasing"
    };
    let (key, unit, precision) = match units.scale {
        Some(s) => ("value", units.unit.clone(), s.places()),
        None => ("total", Some("pulses".to_string()), 0),
    };
    let mut more = json!({
        "state_topic": state.topic,
        "value_template": state.template(key),
        "state_class": state_class,
        "suggested_display_precision": precision,
        "json_attributes_topic": state.topic,
        "json_attributes_template": state.attributes(),
    });
    if let Some(u) = unit {
        more["unit_of_measurement"] = u.into();
    }
    if let (Some(class), Some(_)) = (&units.device_class, units.scale) {
        more["device_class"] = class.clone().into();
    }
    let (object, name) = if encoder {
        (format!("{ch}_position"), format!("{ch} position"))
    } else {
        (format!("{ch}_total"), format!("{ch} total"))
    };
    sensor(site, m, object, name, more)
}

/// The rate: scaled per the channel's time base, or pulses per second.
fn rate(site: &Site, m: Module<'_>, spec: &ChannelSpec, units: &ChannelUnits) -> Entity {
    let ch = &spec.name;
    let state = State::of(site, m, ch);
    let per = match units.rate_per.seconds() {
        1 => "s",
        60 => "min",
        _ => "h",
    };
    let (key, unit) = match (&units.scale, &units.rate_unit, &units.unit) {
        (Some(_), Some(r), _) => ("rate", r.clone()),
        (Some(_), None, Some(u)) => ("rate", format!("{u}/{per}")),
        (Some(_), None, None) => ("rate", format!("1/{per}")),
        (None, ..) => ("rate_hz", "pulses/s".to_string()),
    };
    let mut more = json!({
        "state_topic": state.topic,
        "value_template": state.template(key),
        "state_class": "measurement",
        "unit_of_measurement": unit,
    });
    if let Some(class) = units.scale.and(rate_device_class(units)) {
        more["device_class"] = class.into();
    }
    sensor(site, m, format!("{ch}_rate"), format!("{ch} rate"), more)
}

/// Every entity of one channel of a module: total, rate, frequency and rpm where the model has
/// them, and a clear button where commands are enabled. None for a channel with
/// `enabled = false` (not published, so its configs are cleared).
pub fn channel_entities(site: &Site, m: Module<'_>, spec: &ChannelSpec) -> Vec<Entity> {
    let ch = &spec.name;
    if m.device.channels.get(ch).is_some_and(|c| !c.enabled) {
        return Vec::new();
    }
    let units = m
        .device
        .channels
        .get(ch)
        .map(|c| c.units.clone())
        .unwrap_or_default();
    let state = State::of(site, m, ch);
    let mut out = vec![total(site, m, spec, &units), rate(site, m, spec, &units)];
    if spec.freq.is_some() {
        let more = json!({
            "state_topic": state.topic,
            "value_template": state.template("freq_hz"),
            "state_class": "measurement",
            "device_class": "frequency",
            "unit_of_measurement": "Hz",
        });
        out.push(sensor(
            site,
            m,
            format!("{ch}_frequency"),
            format!("{ch} frequency"),
            more,
        ));
    }
    if spec.rpm.is_some() {
        // rpm has no device class: Home Assistant's frequency class refuses the unit.
        let more = json!({
            "state_topic": state.topic,
            "value_template": state.template("rpm"),
            "state_class": "measurement",
            "unit_of_measurement": "rpm",
        });
        out.push(sensor(
            site,
            m,
            format!("{ch}_rpm"),
            format!("{ch} speed"),
            more,
        ));
    }
    if m.device.commands {
        let object = format!("{ch}_clear");
        let config = merge(
            common(site, m, "button", &object, &format!("{ch} clear")),
            json!({
                "command_topic": site.topics.channel_command(&m.device.name, ch),
                "payload_press": r#"{"op":"clear"}"#,
                "qos": 1,
                "retain": false,
                "entity_category": "config",
            }),
        );
        out.push(Entity {
            component: "button",
            object_id: format!("{}_{object}", m.key()),
            config,
        });
    }
    out
}

/// The channel of `m`'s profile called `name` that counts as `kind` (the work mode decides:
/// a ZH-YX1600 `di1` is an input counter or an encoder).
pub fn channel_spec(m: Module<'_>, name: &str, kind: ChannelKind) -> Option<ChannelSpec> {
    m.device
        .profile
        .all_channels()
        .into_iter()
        .find(|c| c.name == name && c.kind == kind)
}

/// Every config topic `config` may have: the gateway's, each module's, and each channel of
/// any work mode. A retained config outside this set belongs to a removed device or channel.
pub fn possible_topics(site: &Site, config: &Config) -> BTreeSet<String> {
    let mut out: BTreeSet<String> = gateway_entities(site)
        .iter()
        .map(|e| e.topic(site))
        .collect();
    for (bus, device) in config.enabled_devices() {
        let m = Module {
            bus: &bus.name,
            device,
        };
        out.extend(module_topics(site, m));
    }
    out
}

/// Every config topic module `m` may have, in any work mode.
pub fn module_topics(site: &Site, m: Module<'_>) -> BTreeSet<String> {
    let mut out: BTreeSet<String> = device_entities(site, m)
        .iter()
        .map(|e| e.topic(site))
        .collect();
    for spec in m.device.profile.all_channels() {
        out.extend(
            channel_entities(site, m, &spec)
                .iter()
                .map(|e| e.topic(site)),
        );
    }
    out
}
