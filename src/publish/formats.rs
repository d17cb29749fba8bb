//! The formats a config chooses, built: the one place that knows every format by name (the
//! trait they implement is in [`super::format`]).

use super::format::Format;
use crate::config::Config;
#[cfg(doc)]
use crate::config::publish::FORMAT_NAMES;

/// The payload format `name` (checked against [`FORMAT_NAMES`] when the config is read).
pub fn build(config: &Config, name: &str) -> Box<dyn Format> {
    match name {
        "json" => Box::new(super::json::Json::new(config)),
        "sparkplug" => Box::new(super::sparkplug::Sparkplug::new(config)),
        other => unreachable_format(other, config),
    }
}

/// A name `check` let through that [`build`] does not know: JSON, logged (a programming error
/// between [`FORMAT_NAMES`] and [`build`], never a crash of the gateway).
fn unreachable_format(name: &str, config: &Config) -> Box<dyn Format> {
    tracing::error!("output format {name:?} is not built in; publishing JSON");
    Box::new(super::json::Json::new(config))
}

/// Every format the config chooses, in the order their messages go out: discovery first, so an
/// entity is announced before its first reading.
pub fn chosen(config: &Config) -> Vec<Box<dyn Format>> {
    let mut formats: Vec<Box<dyn Format>> = Vec::new();
    if config.homeassistant.discovery {
        formats.push(Box::new(super::discovery::Discovery::new(config)));
    }
    // Sparkplug first: its NDEATH must be the will (a connection has one), before JSON's
    // `offline` status.
    let mut names: Vec<&String> = config.mqtt.format.iter().collect();
    names.sort_by_key(|n| n.as_str() != "sparkplug");
    for name in names {
        formats.push(build(config, name));
    }
    formats
}
