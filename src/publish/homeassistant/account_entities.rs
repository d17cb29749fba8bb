//! Home Assistant entities of a metered channel's account (`[tariffs]`, `[billing]`): a
//! `total_increasing` sensor per tariff register, so the Energy dashboard can take each tariff
//! as its own consumption; the billing period's maximum demand as a `measurement` (power for
//! energy); and the last billing record, its fields as attributes. Pure.
//!
//! The gateway switches tariffs itself: unlike Home Assistant's `utility_meter`, nothing here
//! waits for an automation, and a restart of Home Assistant loses no boundary (every register
//! is retained and equals the sum of its records).

use serde_json::json;

use super::entity::{Entity, Module, Shape, Site, sensor, with_units};
use crate::config::units::ChannelUnits;
use crate::profile::ChannelKind;

/// The register, demand and billing sensors of channel `spec` of `m`: none for an encoder
/// (its position is not a meter) or a channel without intervals (it has no account).
pub fn entities(site: &Site, m: Module<'_>, spec: &Shape, units: &ChannelUnits) -> Vec<Entity> {
    let metered = !m
        .device
        .intervals_of(site.intervals.as_deref(), &spec.name)
        .is_empty();
    if spec.kind == ChannelKind::Encoder || !metered {
        return Vec::new();
    }
    let mut out: Vec<Entity> = site
        .tariffs
        .iter()
        .map(|t| register(site, m, &spec.name, t, units))
        .collect();
    if let Some(billing) = &site.billing {
        out.push(period(site, m, &spec.name, units));
        if billing.demand {
            out.push(demand(site, m, &spec.name, units));
        }
    }
    out
}

/// The value a template reads from a register or billing record: in the unit with a scale,
/// else in pulses.
fn amount(units: &ChannelUnits, pulses: &str) -> String {
    let key = if units.scale.is_some() {
        "value"
    } else {
        pulses
    };
    format!("{{{{ value_json.{key} }}}}")
}

/// A tariff's register: it only grows, and equals the sum of the tariff's records.
fn register(site: &Site, m: Module<'_>, ch: &str, tariff: &str, units: &ChannelUnits) -> Entity {
    let topic = site.topics.tariff(&m.device.name, ch, tariff);
    let more = with_units(
        json!({
            "state_topic": topic,
            "value_template": amount(units, "total"),
            "state_class": "total_increasing",
            "json_attributes_topic": topic,
            "json_attributes_template":
                "{{ {'total': value_json.total, 'seq': value_json.seq, 'obis': value_json.get('obis')} | tojson }}",
        }),
        units,
    );
    sensor(
        site,
        m,
        format!("{ch}_tariff_{tariff}"),
        format!("{ch} {tariff}"),
        more,
    )
}

/// The last billing period's consumption (`last_reset` at its start, so statistics book each
/// period once), every field of the record as an attribute.
fn period(site: &Site, m: Module<'_>, ch: &str, units: &ChannelUnits) -> Entity {
    let topic = site.topics.billing(&m.device.name, ch);
    let more = with_units(
        json!({
            "state_topic": topic,
            "value_template": amount(units, "delta"),
            "state_class": "total",
            "last_reset_value_template": "{{ value_json.start }}",
            "json_attributes_topic": topic,
        }),
        units,
    );
    sensor(
        site,
        m,
        format!("{ch}_billing"),
        format!("{ch} billing period"),
        more,
    )
}

/// The last period's maximum demand: the largest mean rate of a demand record, in the rate of
/// the channel's unit (kW from kWh). A period without a complete record has none: `None`
/// is Home Assistant's "unknown".
fn demand(site: &Site, m: Module<'_>, ch: &str, units: &ChannelUnits) -> Entity {
    let topic = site.topics.billing(&m.device.name, ch);
    let unit = units.scale.and(units.unit.as_deref());
    let mut more = json!({
        "state_topic": topic,
        "value_template": "{{ value_json.demand.value if value_json.demand is defined else None }}",
        "state_class": "measurement",
        "unit_of_measurement": crate::metering::demand::rate_unit(unit),
        "json_attributes_topic": topic,
        "json_attributes_template":
            "{{ {'start': value_json.demand.start, 'obis': value_json.demand.get('obis')} | tojson if value_json.demand is defined else '{}' }}",
    });
    if let Some(class) = demand_class(unit) {
        more["device_class"] = class.into();
    }
    sensor(
        site,
        m,
        format!("{ch}_demand"),
        format!("{ch} maximum demand"),
        more,
    )
}

/// Home Assistant's class of a demand counted in `unit`: power from energy, a flow from a
/// volume; none where Home Assistant has no class for the rate.
fn demand_class(unit: Option<&str>) -> Option<&'static str> {
    match unit? {
        "Wh" | "kWh" | "MWh" => Some("power"),
        "m³" => Some("volume_flow_rate"),
        _ => None,
    }
}
