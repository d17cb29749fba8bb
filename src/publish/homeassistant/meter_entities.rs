//! Home Assistant entities of a metered channel (one with a `scale`): its meter reading and one
//! consumption sensor per interval period. Pure.
//!
//! The channel's total stays the `total_increasing` consumption sensor (it never jumps). The
//! meter reading may jump when `set_reading` matches it to the meter's display, so it is
//! `state_class: total` with `last_reset` at the time it was set: Home Assistant's statistics
//! start again from there instead of booking the jump. An interval sensor holds the last
//! record's consumption with `last_reset` at the record's start, so every record is added once
//! to the long-term statistics (the Energy dashboard takes both).

use serde_json::json;

use super::entity::{Entity, Module, Shape, Site, State, sensor, with_units};
use crate::config::units::ChannelUnits;
use crate::profile::ChannelKind;

/// The meter-reading and interval sensors of channel `spec` of `m` (none for an encoder, whose
/// position is not a meter, and no reading without a scale).
pub fn entities(site: &Site, m: Module<'_>, spec: &Shape, units: &ChannelUnits) -> Vec<Entity> {
    if spec.kind == ChannelKind::Encoder {
        return Vec::new();
    }
    let ch = &spec.name;
    let mut out = Vec::new();
    if units.scale.is_some() {
        let state = State::of(site, m, ch);
        let more = with_units(
            json!({
                "state_topic": state.topic,
                "value_template": state.template("reading"),
                "state_class": "total",
                "last_reset_value_template": state.optional("reading_since"),
            }),
            units,
        );
        out.push(sensor(
            site,
            m,
            format!("{ch}_reading"),
            format!("{ch} meter reading"),
            more,
        ));
    }
    let periods = m.device.intervals_of(site.intervals.as_deref(), ch);
    for p in periods {
        let key = if units.scale.is_some() {
            "value"
        } else {
            "delta"
        };
        let more = with_units(
            json!({
                "state_topic": site.topics.interval(&m.device.name, ch, p.text()),
                "value_template": format!("{{{{ value_json.{key} }}}}"),
                "state_class": "total",
                "last_reset_value_template": "{{ value_json.start }}",
                "json_attributes_topic": site.topics.interval(&m.device.name, ch, p.text()),
                "json_attributes_template":
                    "{{ {'end': value_json.end, 'status': value_json.status, 'seq': value_json.seq, 'events': value_json.get('events', [])} | tojson }}",
            }),
            units,
        );
        out.push(sensor(
            site,
            m,
            format!("{ch}_interval_{}", p.text()),
            format!("{ch} consumption per {}", p.text()),
            more,
        ));
    }
    out
}
