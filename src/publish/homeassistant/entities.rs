//! Home Assistant MQTT discovery payloads. Pure: config in, retained config messages out.
//!
//! One HA device per module, linked `via_device` to one device for the gateway. Entities are
//! named after the module's place on the wire (bus and unit), not its display name, so renaming
//! a device in the config keeps its entities and their history: unique ids and config topics
//! are `<bus>_u<unit>_<channel>_<entity>` under the gateway id.

use std::collections::BTreeSet;

use serde_json::json;

pub use super::entity::Shape;
use super::entity::{Entity, Module, Site, State, common, merge, origin, sensor};
use crate::config::Config;
use crate::config::units::ChannelUnits;
use crate::config::units::rate_device_class;
use crate::profile::ChannelKind;

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
            "model": "Pulse counter and meter gateway",
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

/// The device-wide clear button, where commands are enabled and counts can be written.
pub fn device_entities(site: &Site, m: Module<'_>) -> Vec<Entity> {
    if !m.device.commands || !m.device.writable_counts() {
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

/// The total (or an encoder's position) with its units, class and attributes.
fn total(site: &Site, m: Module<'_>, spec: &Shape, units: &ChannelUnits) -> Entity {
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
fn rate(site: &Site, m: Module<'_>, spec: &Shape, units: &ChannelUnits) -> Entity {
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
/// them, and a clear button where commands are enabled and counts can be written; a gauge's
/// one sensor. None for a channel with `enabled = false` (not published, so its configs are
/// cleared).
pub fn channel_entities(site: &Site, m: Module<'_>, spec: &Shape) -> Vec<Entity> {
    let ch = &spec.name;
    let config = m.device.channels.get(ch);
    if config.is_some_and(|c| !c.enabled) {
        return Vec::new();
    }
    let units = config
        .map(|c| c.units.clone())
        .filter(|u| u.scale.is_some())
        .or_else(|| spec.declared.clone())
        .unwrap_or_default();
    if let Some(numeric) = spec.gauge {
        return vec![gauge(site, m, spec, &units, numeric)];
    }
    let state = State::of(site, m, ch);
    let mut out = vec![total(site, m, spec, &units), rate(site, m, spec, &units)];
    out.extend(super::meter_entities::entities(site, m, spec, &units));
    out.extend(super::account_entities::entities(site, m, spec, &units));
    if spec.freq {
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
    if spec.rpm {
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
    if m.device.commands && m.device.writable_counts() {
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
pub fn channel_spec(m: Module<'_>, name: &str, kind: ChannelKind) -> Option<Shape> {
    m.device
        .profile
        .all_channels()
        .into_iter()
        .find(|c| c.name == name && c.kind == kind)
        .map(|c| Shape::of_spec(&c))
}

/// A gauge's sensor: its value in its unit, a measurement (text, such as a date, has no state
/// class), with Home Assistant's class where its unit has one.
fn gauge(site: &Site, m: Module<'_>, spec: &Shape, units: &ChannelUnits, numeric: bool) -> Entity {
    let ch = &spec.name;
    let state = State::of(site, m, ch);
    let mut more = json!({
        "state_topic": state.topic,
        "value_template": state.template("value"),
    });
    if numeric {
        more["state_class"] = "measurement".into();
        if let Some(u) = &units.unit {
            more["unit_of_measurement"] = u.clone().into();
            if let Some(class) = gauge_class(u) {
                more["device_class"] = class.into();
            }
        }
    }
    sensor(site, m, ch.clone(), ch.replace('_', " "), more)
}

/// Home Assistant's sensor class of a measured value in `unit`, where one takes that unit as
/// a measurement (energy and volume take no `measurement`: a stored register is no class).
fn gauge_class(unit: &str) -> Option<&'static str> {
    Some(match unit {
        "W" | "kW" | "MW" => "power",
        "°C" | "K" | "°F" => "temperature",
        "m³/h" | "m³/min" | "m³/s" => "volume_flow_rate",
        "bar" => "pressure",
        "V" => "voltage",
        "A" => "current",
        "Hz" => "frequency",
        "s" | "min" | "h" | "d" => "duration",
        _ => return None,
    })
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
            channel_entities(site, m, &Shape::of_spec(&spec))
                .iter()
                .map(|e| e.topic(site)),
        );
    }
    out
}
