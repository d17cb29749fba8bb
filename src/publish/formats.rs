//! The formats of each output, built: the one place that knows every format by its kind (the
//! trait they implement is in [`super::format`], the kinds in [`crate::config::OutputKind`]).

use super::format::Format;
use super::voice::Voice;
use crate::config::{Config, OutputConfig, OutputKind};

/// The formats of `output`, in the order their messages go out: Home Assistant's discovery
/// before the JSON readings (an entity is announced before its first reading), and the
/// gateway's voice on every connection that carries its JSON topics (its will is theirs).
pub fn build(config: &Config, output: &OutputConfig) -> Vec<Box<dyn Format>> {
    let mut formats: Vec<Box<dyn Format>> = Vec::new();
    if output.kind.carries_gateway_topics() {
        formats.push(Box::new(Voice::new(&output.mqtt.topic_root, &output.name)));
    }
    match output.kind {
        OutputKind::Json => formats.push(Box::new(super::json::Json::new(config, output))),
        OutputKind::HomeAssistant => {
            formats.push(Box::new(super::homeassistant::Discovery::new(
                config, output,
            )));
            formats.push(Box::new(super::json::Json::new(config, output)));
        }
        OutputKind::Sparkplug => {
            formats.push(Box::new(super::sparkplug::Sparkplug::new(config, output)));
        }
    }
    formats
}
