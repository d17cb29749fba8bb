//! The format built from a config: shapes from profiles and channel settings.

use super::*;
use crate::config::OutputConfig;
use crate::profile::ChannelKind;

fn config(extra: &str) -> Config {
    let state = std::env::temp_dir().join(format!("pg-sparkplug-{}", std::process::id()));
    std::fs::create_dir_all(&state).unwrap();
    let text = format!(
        "[gateway]\nid = \"e1\"\nstate_dir = {state:?}\n[mqtt]\nformat = [\"json\", \"sparkplug\"]\n\
         [sparkplug]\ngroup_id = \"plant\"\n\
         [buses.l]\nhost = \"127.0.0.1\"\nport = 502\n\
         [buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n{extra}"
    );
    let env = Some(std::collections::HashMap::new());
    Config::from_toml(&text, std::path::Path::new("x.toml"), env).expect("config")
}

/// The Sparkplug format of the config's output of kind `sparkplug`.
fn node_of(c: &Config) -> Sparkplug {
    Sparkplug::new(c, sparkplug_output(c))
}

fn sparkplug_output(c: &Config) -> &OutputConfig {
    let kind = &crate::config::outputs::sparkplug::KIND;
    c.outputs.list.iter().find(|o| o.kind.is(kind)).unwrap()
}

/// Every format of that output.
fn outputs_formats(c: &Config) -> Vec<Box<dyn crate::publish::lifecycle::MqttFormat>> {
    crate::publish::formats::build(c, sparkplug_output(c))
}

#[test]
fn every_enabled_channel_is_one_shape_with_its_units() {
    let c = config(
        "[buses.l.devices.d.channels.a1]\nenabled = false\n\
         [buses.l.devices.d.channels.a0]\nscale = 0.001\nunit = \"kWh\"\n",
    );
    let shapes = shapes(&c, true);
    assert_eq!(shapes.len(), 1);
    let (device, channels) = &shapes[0];
    assert_eq!(device, "d");
    let names: Vec<&str> = channels.iter().map(|s| s.name.as_str()).collect();
    assert!(names.contains(&"a0") && !names.contains(&"a1"), "{names:?}");
    let mut unique = names.clone();
    unique.dedup();
    assert_eq!(unique.len(), names.len(), "one shape per name");
    let a0 = channels.iter().find(|s| s.name == "a0").unwrap();
    assert_eq!(a0.value_unit, Some(Some("kWh".into())));
    assert_eq!(a0.kind, ChannelKind::Counter);
    assert!(a0.writable);
}

#[test]
fn the_edge_node_id_defaults_to_the_gateway_id() {
    let c = config("");
    let s = c.outputs.settings::<Settings>().unwrap();
    assert_eq!(
        (s.group_id.as_str(), s.edge_node_id.as_str()),
        ("plant", "e1")
    );
    assert_eq!(s.primary_host, None);
    let subs = node_of(&c).subscriptions();
    assert_eq!(subs, ["spBv1.0/plant/NCMD/e1", "spBv1.0/plant/DCMD/e1/+"]);
}

#[test]
fn a_retained_dcmd_is_stale_and_ignored_a_fresh_one_is_a_command() {
    use proto::{Metric, Value, datatype};
    let mut f = node_of(&config(""));
    let topic = "spBv1.0/plant/DCMD/e1/d";
    let clear = Metric::new(
        "a0/Clear",
        None,
        datatype::BOOLEAN,
        Some(Value::Boolean(true)),
    );
    let payload = command::dcmd(vec![clear]);
    assert!(f.received_retained(topic, &payload).commands.is_empty());
    let fresh = f.received(topic, &payload).commands;
    assert_eq!(fresh.len(), 1);
    assert_eq!(fresh[0].topic, "pulsegate/e1/d/a0/cmd");
}

/// Each output leaves its own will: with both formats in the config, the Sparkplug output's is
/// the NDEATH and the JSON output's the gateway's `offline` (one connection had room for one).
#[test]
fn with_both_formats_each_output_leaves_its_own_will() {
    let c = config("");
    let mut stage = crate::publish::lifecycle::Stage::new(outputs_formats(&c));
    let will = stage.will().unwrap();
    assert_eq!(will.topic, "spBv1.0/plant/NDEATH/e1");
    assert!(!will.retain);
    let json = c.outputs.list.iter().find(|o| o.name == "json").unwrap();
    let mut stage = crate::publish::lifecycle::Stage::new(crate::publish::formats::build(&c, json));
    let will = stage.will().unwrap();
    assert_eq!(
        (will.topic.as_str(), &will.payload[..]),
        ("pulsegate/e1/status", &b"offline"[..])
    );
    assert!(will.retain);
}
