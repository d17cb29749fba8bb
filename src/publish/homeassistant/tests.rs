//! Discovery payloads and the discovery state machine, without a broker.

use std::path::Path;
use std::sync::Arc;

use serde_json::Value;

use super::Discovery;
use crate::config::Config;
use crate::publish::lifecycle::Stage;

/// The formats of the config's first output (discovery on: the JSON one, of kind
/// `homeassistant`).
fn chosen(config: &Config) -> Vec<Box<dyn crate::publish::lifecycle::MqttFormat>> {
    crate::publish::formats::build(config, &config.outputs.list[0])
}

/// Discovery over the config's first output.
fn discovery(config: &Config) -> Discovery {
    Discovery::new(config, &config.outputs.list[0])
}
use crate::profile::ChannelKind;
use crate::reading::{Output, Reading};

const CONFIG: &str = r#"
[gateway]
id = "edge"
[homeassistant]
discovery = true
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.meter]
unit = 3
model = "yl67"
[buses.line1.devices.meter.channels.a0]
scale = 0.001
unit = "kWh"
rate_unit = "kW"
rate_per = "h"
device_class = "energy"
[buses.line1.devices.press]
unit = 4
model = "yl67"
commands = false
"#;

fn config(text: &str) -> Config {
    Config::from_toml(
        text,
        Path::new("/etc/pulsegate/pulsegate.toml"),
        Some(Default::default()),
    )
    .unwrap()
}

fn reading(device: &str, channel: &str) -> Reading {
    let mut r = Reading::sample(device, channel, 1);
    (r.count, r.update.delta, r.update.total) = (0, 0, 0);
    r.kind = if channel.starts_with("enc") {
        ChannelKind::Encoder
    } else {
        ChannelKind::Counter
    };
    r
}

fn json(d: &mut Discovery, topic: &str) -> Value {
    let all = d.everything();
    let a = all.iter().find(|a| a.topic == topic).unwrap_or_else(|| {
        panic!(
            "no {topic} in {:?}",
            all.iter().map(|a| &a.topic).collect::<Vec<_>>()
        )
    });
    serde_json::from_str(&a.payload).unwrap()
}

#[test]
fn a_counter_total_is_total_increasing_in_its_units_with_both_statuses_for_availability() {
    let mut d = discovery(&config(CONFIG));
    d.start();
    assert!(!d.reading(&reading("meter", "a0")).is_empty());
    let v = json(&mut d, "homeassistant/sensor/edge/line1_u3_a0_total/config");
    assert_eq!(v["state_class"], "total_increasing");
    assert_eq!(v["device_class"], "energy");
    assert_eq!(v["unit_of_measurement"], "kWh");
    assert_eq!(v["suggested_display_precision"], 3);
    assert_eq!(v["state_topic"], "pulsegate/edge/meter/a0");
    assert!(v["value_template"].as_str().unwrap().contains("'value'"));
    assert_eq!(v["unique_id"], "pulsegate_edge_line1_u3_a0_total");
    assert_eq!(v["default_entity_id"], "sensor.edge_meter_a0_total");
    assert!(v.get("object_id").is_none(), "object_id is deprecated");
    assert_eq!(v["availability_mode"], "all");
    let topics: Vec<&str> = v["availability"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["topic"].as_str().unwrap())
        .collect();
    assert_eq!(
        topics,
        ["pulsegate/edge/status", "pulsegate/edge/meter/status"]
    );
    assert_eq!(v["device"]["via_device"], "pulsegate_edge");
    assert_eq!(v["device"]["model_id"], "yl67");
    assert!(
        v["device"]["manufacturer"]
            .as_str()
            .unwrap()
            .contains("俞霖")
    );
    assert_eq!(v["origin"]["name"], "pulsegate");
    let rate = json(&mut d, "homeassistant/sensor/edge/line1_u3_a0_rate/config");
    assert_eq!(rate["unit_of_measurement"], "kW");
    assert_eq!(rate["device_class"], "power");
    assert_eq!(rate["state_class"], "measurement");
}

#[test]
fn an_encoder_position_is_a_measurement_never_total_increasing() {
    let mut d = discovery(&config(CONFIG));
    d.reading(&reading("meter", "enc1"));
    let v = json(
        &mut d,
        "homeassistant/sensor/edge/line1_u3_enc1_position/config",
    );
    assert_eq!(v["state_class"], "measurement");
    let rpm = json(&mut d, "homeassistant/sensor/edge/line1_u3_enc1_rpm/config");
    assert!(rpm.get("device_class").is_none(), "rpm has no device class");
    assert_eq!(rpm["unit_of_measurement"], "rpm");
}

#[test]
fn buttons_exist_only_where_commands_are_enabled() {
    let mut d = discovery(&config(CONFIG));
    let start: Vec<String> = d.start().into_iter().map(|a| a.topic).collect();
    assert!(start.contains(&"homeassistant/button/edge/line1_u3_clear_all/config".to_string()));
    assert!(!start.iter().any(|t| t.contains("line1_u4")));
    let press: Vec<String> = d
        .reading(&reading("press", "enc0"))
        .into_iter()
        .map(|a| a.topic)
        .collect();
    assert!(!press.iter().any(|t| t.contains("/button/")), "{press:?}");
    let meter = d.reading(&reading("meter", "a0"));
    let button = meter
        .iter()
        .find(|a| a.topic == "homeassistant/button/edge/line1_u3_a0_clear/config")
        .unwrap();
    let v: Value = serde_json::from_str(&button.payload).unwrap();
    assert_eq!(v["command_topic"], "pulsegate/edge/meter/a0/cmd");
    assert_eq!(v["payload_press"], r#"{"op":"clear"}"#);
}

#[test]
fn a_channel_is_announced_once_and_everything_again_when_home_assistant_returns() {
    let mut d = discovery(&config(CONFIG));
    let first = d.start().len();
    let announced = d.reading(&reading("meter", "a0")).len();
    assert!(d.reading(&reading("meter", "a0")).is_empty());
    let now = tokio::time::Instant::now();
    assert_eq!(d.ha_status(b"online", now).len(), first + announced);
    assert!(d.ha_status(b"offline", now).is_empty());
}

#[test]
fn retained_configs_of_devices_no_longer_configured_are_cleared() {
    let mut d = discovery(&config(CONFIG));
    let gone = "homeassistant/sensor/edge/line9_u7_a0_total/config";
    let cleared = d.config_seen(gone, b"{}").unwrap();
    assert_eq!(
        (cleared.topic.as_str(), cleared.payload.as_str()),
        (gone, "")
    );
    let ours = "homeassistant/sensor/edge/line1_u3_a0_total/config";
    assert!(d.config_seen(ours, b"{}").is_none());
    assert!(
        d.config_seen(gone, b"").is_none(),
        "an empty config is already gone"
    );
}

#[test]
fn a_reload_clears_a_removed_device_and_keeps_a_renamed_one() {
    let mut d = discovery(&config(CONFIG));
    d.start();
    d.reading(&reading("meter", "a0"));
    d.reading(&reading("press", "enc0"));
    let renamed = CONFIG.replace("devices.meter", "devices.energy").replace(
        "[buses.line1.devices.press]\nunit = 4\nmodel = \"yl67\"\ncommands = false\n",
        "",
    );
    let out = d.reload(&config(&renamed));
    let cleared: Vec<&str> = out
        .iter()
        .filter(|a| a.payload.is_empty())
        .map(|a| a.topic.as_str())
        .collect();
    assert!(cleared.contains(&"homeassistant/sensor/edge/line1_u4_enc0_position/config"));
    assert!(
        !cleared.iter().any(|t| t.contains("line1_u3")),
        "{cleared:?}"
    );
    let total = out
        .iter()
        .find(|a| a.topic == "homeassistant/sensor/edge/line1_u3_a0_total/config")
        .expect("the renamed device's total is announced again");
    let v: Value = serde_json::from_str(&total.payload).unwrap();
    assert_eq!(v["state_topic"], "pulsegate/edge/energy/a0");
    assert_eq!(v["unique_id"], "pulsegate_edge_line1_u3_a0_total");
}

#[test]
fn with_one_message_per_device_templates_reach_into_the_channel() {
    let text = CONFIG.replace("id = \"edge\"", "id = \"edge\"\npayload = \"device\"");
    let mut d = discovery(&config(&text));
    d.reading(&reading("meter", "a0"));
    let v = json(&mut d, "homeassistant/sensor/edge/line1_u3_a0_total/config");
    assert_eq!(v["state_topic"], "pulsegate/edge/meter");
    assert!(
        v["value_template"]
            .as_str()
            .unwrap()
            .contains("value_json['a0']['value']")
    );
}

#[test]
fn a_zh_yx1600_pair_in_quadrature_mode_is_a_position_not_a_meter_total() {
    let text = CONFIG.replace(
        "model = \"yl67\"\ncommands = false",
        "model = \"zh-yx1600\"",
    );
    let mut d = discovery(&config(&text));
    let mut r = reading("press", "di1");
    r.kind = ChannelKind::Encoder;
    d.reading(&r);
    let v = json(
        &mut d,
        "homeassistant/sensor/edge/line1_u4_di1_position/config",
    );
    assert_eq!(v["state_class"], "measurement");
    let mut r = reading("press", "di3");
    r.kind = ChannelKind::Counter;
    d.reading(&r);
    let v = json(
        &mut d,
        "homeassistant/sensor/edge/line1_u4_di3_total/config",
    );
    assert_eq!(v["state_class"], "total_increasing");
}

#[test]
fn after_a_full_poll_configs_of_another_work_modes_channels_are_cleared() {
    let mut d = discovery(&config(CONFIG));
    // Left over from when encoder 0 of the meter ran in quadrature mode.
    let old = "homeassistant/sensor/edge/line1_u3_enc0_position/config";
    assert!(
        d.config_seen(old, b"{}").is_none(),
        "possible until the mode is known"
    );
    d.reading(&reading("meter", "a0"));
    d.reading(&reading("meter", "b0"));
    let settled = d.reading(&reading("meter", "a0"));
    assert_eq!(settled.len(), 1, "{settled:?}");
    assert_eq!(
        (settled[0].topic.as_str(), settled[0].payload.as_str()),
        (old, "")
    );
    let ours = "homeassistant/sensor/edge/line1_u3_a0_total/config";
    assert!(d.config_seen(ours, b"{}").is_none());
    let late = "homeassistant/sensor/edge/line1_u3_enc0_rpm/config";
    assert!(
        d.config_seen(late, b"{}").is_some(),
        "a late retained one too"
    );
}

#[test]
fn a_disabled_device_or_channel_has_no_entities_and_its_configs_are_cleared() {
    let mut d = discovery(&config(CONFIG));
    d.start();
    d.reading(&reading("meter", "a0"));
    d.reading(&reading("meter", "a1"));
    d.reading(&reading("press", "enc0"));
    let disabled = CONFIG
        .replace(
            "device_class = \"energy\"\n",
            "device_class = \"energy\"\nenabled = false\n",
        )
        .replace("commands = false\n", "commands = false\nenabled = false\n");
    let out = d.reload(&config(&disabled));
    let cleared: Vec<&str> = out
        .iter()
        .filter(|a| a.payload.is_empty())
        .map(|a| a.topic.as_str())
        .collect();
    for gone in [
        "homeassistant/sensor/edge/line1_u3_a0_total/config",
        "homeassistant/sensor/edge/line1_u3_a0_rate/config",
        "homeassistant/button/edge/line1_u3_a0_clear/config",
        "homeassistant/sensor/edge/line1_u4_enc0_position/config",
    ] {
        assert!(cleared.contains(&gone), "{gone} not in {cleared:?}");
    }
    let kept = "homeassistant/sensor/edge/line1_u3_a1_total/config";
    assert!(!cleared.contains(&kept), "{cleared:?}");
    // A config of a disabled channel retained on the broker is cleared too, and readings of
    // disabled ones announce nothing.
    assert!(
        d.config_seen("homeassistant/sensor/edge/line1_u3_a0_total/config", b"{}")
            .is_some()
    );
    assert!(d.config_seen(kept, b"{}").is_none());
    assert!(d.reading(&reading("press", "enc0")).is_empty());
    assert!(d.reading(&reading("meter", "a0")).is_empty());
}

/// Discovery is a format: chosen by `[homeassistant] discovery`, it runs in the output stage
/// before the payload format.
#[test]
fn discovery_is_a_format_chosen_by_its_config_key_that_announces_before_the_first_reading() {
    let mut stage = Stage::new(chosen(&config(CONFIG)));
    assert_eq!(
        stage.subscriptions(),
        ["homeassistant/status", "homeassistant/+/edge/+/config"]
    );
    let start = stage.start();
    let gateway = "homeassistant/sensor/edge/gateway_status/config";
    assert!(
        start
            .iter()
            .any(|m| m.topic == gateway && m.retain && m.qos == 1)
    );
    let out = stage.render(&Output::single(reading("meter", "a0")));
    let (last, configs) = out.split_last().unwrap();
    assert_eq!(last.topic, "pulsegate/edge/meter/a0", "the reading last");
    assert!(
        configs
            .iter()
            .any(|m| m.topic == "homeassistant/sensor/edge/line1_u3_a0_total/config")
    );
    assert!(
        configs
            .iter()
            .all(|m| m.topic.starts_with("homeassistant/") && m.retain)
    );
    let again = stage.render(&Output::single(reading("meter", "a0")));
    assert_eq!(again.len(), 1, "announced once");
    // Without the key the payload format runs alone.
    let off = CONFIG.replace("discovery = true", "discovery = false");
    let mut plain = Stage::new(chosen(&config(&off)));
    assert!(plain.subscriptions().is_empty() && plain.start().is_empty());
    assert_eq!(
        plain.render(&Output::single(reading("meter", "a0"))).len(),
        1
    );
}

#[test]
fn what_arrives_on_its_subscriptions_and_a_reload_reach_the_discovery_format() {
    let mut stage = Stage::new(chosen(&config(CONFIG)));
    let mut announced = stage.start().len();
    announced += stage.render(&Output::single(reading("press", "a0"))).len() - 1;
    let again = stage.received("homeassistant/status", b"online").messages;
    assert_eq!(
        again.len(),
        announced,
        "Home Assistant back: everything again"
    );
    assert!(
        stage
            .received("homeassistant/status", b"offline")
            .messages
            .is_empty()
    );
    assert!(
        stage
            .received("pulsegate/edge/meter/cmd", b"{}")
            .messages
            .is_empty()
    );
    let stale = stage
        .received("homeassistant/sensor/edge/line9_u1_a0_total/config", b"{}")
        .messages;
    assert_eq!(stale.len(), 1);
    assert!(stale[0].payload.is_empty() && stale[0].retain, "cleared");
    let without_press = CONFIG.replace(
        "[buses.line1.devices.press]\nunit = 4\nmodel = \"yl67\"\ncommands = false\n",
        "",
    );
    assert_ne!(without_press, CONFIG);
    let reloaded = stage.reload(&config(&without_press));
    let press_total = "homeassistant/sensor/edge/line1_u4_a0_total/config";
    assert!(
        reloaded
            .iter()
            .any(|m| m.topic == press_total && m.payload.is_empty())
    );
}

#[test]
fn a_metered_channel_has_a_meter_reading_and_one_consumption_sensor_per_interval_period() {
    let text = CONFIG.replace(
        "[buses.line1.devices.meter.channels.a0]",
        "intervals = [\"15min\", \"1d\"]\n[buses.line1.devices.meter.channels.a0]",
    );
    let mut d = discovery(&config(&text));
    d.start();
    assert!(!d.reading(&reading("meter", "a0")).is_empty());
    let total = json(&mut d, "homeassistant/sensor/edge/line1_u3_a0_total/config");
    assert_eq!(
        total["state_class"], "total_increasing",
        "consumption never jumps"
    );
    let r = json(
        &mut d,
        "homeassistant/sensor/edge/line1_u3_a0_reading/config",
    );
    assert_eq!(r["state_class"], "total");
    assert_eq!(r["device_class"], "energy");
    assert_eq!(r["unit_of_measurement"], "kWh");
    assert_eq!(r["state_topic"], "pulsegate/edge/meter/a0");
    assert!(r["value_template"].as_str().unwrap().contains("'reading'"));
    assert!(
        r["last_reset_value_template"]
            .as_str()
            .unwrap()
            .contains("reading_since")
    );
    assert_eq!(r["unique_id"], "pulsegate_edge_line1_u3_a0_reading");
    for period in ["15min", "1d"] {
        let topic = format!("homeassistant/sensor/edge/line1_u3_a0_interval_{period}/config");
        let v = json(&mut d, &topic);
        assert_eq!(v["state_class"], "total");
        assert_eq!(v["last_reset_value_template"], "{{ value_json.start }}");
        assert_eq!(v["value_template"], "{{ value_json.value }}");
        assert_eq!(
            v["state_topic"],
            format!("pulsegate/edge/meter/a0/interval/{period}")
        );
        assert_eq!(v["device_class"], "energy");
        assert_eq!(
            v["default_entity_id"],
            format!("sensor.edge_meter_a0_interval_{period}")
        );
    }
}

/// An encoder's position is no meter: no reading, no intervals; the press has no intervals and
/// no scale: neither.
#[test]
fn only_a_metered_counter_has_a_reading_and_interval_sensors() {
    let text = CONFIG.replace(
        "[buses.line1.devices.meter.channels.a0]",
        "intervals = [\"15min\", \"1d\"]\n[buses.line1.devices.meter.channels.a0]",
    );
    use crate::publish::homeassistant::entities::{channel_entities, channel_spec};
    use crate::publish::homeassistant::entity::{Module, Site};
    let c = config(&text);
    let site = Site::of(&c);
    let objects = |device: &str, channel: &str, kind| -> Vec<String> {
        let (bus, dev) = c.devices().find(|(_, d)| d.name == device).unwrap();
        let m = Module {
            bus: &bus.name,
            device: dev,
        };
        let spec = channel_spec(m, channel, kind).unwrap();
        channel_entities(&site, m, &spec)
            .into_iter()
            .map(|e| e.object_id)
            .collect()
    };
    let meter_a0 = objects("meter", "a0", ChannelKind::Counter);
    assert!(
        meter_a0.iter().any(|o| o.ends_with("a0_interval_1d")),
        "{meter_a0:?}"
    );
    let enc = objects("meter", "enc0", ChannelKind::Encoder);
    assert!(
        !enc.iter()
            .any(|o| o.contains("reading") || o.contains("interval")),
        "{enc:?}"
    );
    let press = objects("press", "a0", ChannelKind::Counter);
    assert!(
        !press
            .iter()
            .any(|o| o.contains("reading") || o.contains("interval")),
        "{press:?}"
    );
}

const METERS: &str = r#"
[gateway]
id = "edge"
[homeassistant]
discovery = true
[buses.mb]
protocol = "mbus"
host = "10.0.0.5:10001"
[buses.mb.devices.water]
address = 5
[buses.mb.devices.heat]
id = "12345678"
"#;

/// A meter's reading as its driver declared it: a register in m³ (water) or a gauge in °C.
fn meter_reading(device: &str, channel: &str, gauge: bool) -> Reading {
    use crate::config::units::{ChannelUnits, RatePer};
    use crate::decimal::Decimal;
    let mut r = reading(device, channel);
    r.units = Some(Arc::new(match gauge {
        true => ChannelUnits {
            unit: Some("°C".into()),
            ..ChannelUnits::default()
        },
        false => ChannelUnits {
            scale: Some(Decimal::parse("0.001").unwrap()),
            unit: Some("m³".into()),
            rate_unit: Some("m³/h".into()),
            rate_per: RatePer::Hour,
            device_class: Some("water".into()),
            obis: None,
        },
    }));
    if gauge {
        r.measured = Some(crate::reading::Measure::Exact(
            Decimal::parse("60.25").unwrap(),
        ));
    }
    r
}

#[test]
fn a_meters_register_and_gauges_are_announced_from_their_readings_without_clear_buttons() {
    let mut d = discovery(&config(METERS));
    let start: Vec<String> = d.start().into_iter().map(|a| a.topic).collect();
    assert!(start.iter().all(|t| !t.contains("/button/")), "{start:?}");
    d.reading(&meter_reading("water", "volume", false));
    let v = json(
        &mut d,
        "homeassistant/sensor/edge/mb_a5_volume_total/config",
    );
    assert_eq!(
        (
            &v["state_class"],
            &v["device_class"],
            &v["unit_of_measurement"]
        ),
        (&"total_increasing".into(), &"water".into(), &"m³".into())
    );
    assert_eq!(v["device"]["serial_number"], "mb address 5");
    let rate = json(&mut d, "homeassistant/sensor/edge/mb_a5_volume_rate/config");
    assert_eq!(rate["device_class"], "volume_flow_rate");
    d.reading(&meter_reading("heat", "flow_temperature", true));
    let t = json(
        &mut d,
        "homeassistant/sensor/edge/mb_id12345678_flow_temperature/config",
    );
    assert_eq!(
        (
            &t["state_class"],
            &t["device_class"],
            &t["unit_of_measurement"]
        ),
        (&"measurement".into(), &"temperature".into(), &"°C".into())
    );
    assert!(t["value_template"].as_str().unwrap().contains("'value'"));
    assert!(d.everything().iter().all(|a| !a.topic.contains("/button/")));
    // A meter's configs retained from an earlier run are its own, not stale: its channels are
    // known only once it answers.
    let retained = "homeassistant/sensor/edge/mb_id12345678_power/config";
    assert_eq!(d.config_seen(retained, b"{}"), None);
    let stale = "homeassistant/sensor/edge/mb_id87654321_power/config";
    assert!(d.config_seen(stale, b"{}").is_some());
}

/// The example config with a calendar, monthly billing with demand, and intervals and an OBIS
/// name on the meter's a0 (the press has no intervals).
fn account_discovery() -> Discovery {
    let text = CONFIG
        .replace(
            "[buses.line1]",
            "[tariffs]\ndefault = \"offpeak\"\n[[tariffs.rule]]\ntariff = \"peak\"\n\
             days = [\"mon\"]\nfrom = \"07:00\"\nto = \"21:00\"\n\
             [billing]\nperiod = \"monthly\"\nday = 1\ndemand = \"15min\"\n[buses.line1]",
        )
        .replace(
            "[buses.line1.devices.meter.channels.a0]",
            "intervals = [\"15min\"]\n[buses.line1.devices.meter.channels.a0]\nobis = \"1-0:1.8.0\"",
        );
    let mut d = discovery(&config(&text));
    d.start();
    assert!(!d.reading(&reading("meter", "a0")).is_empty());
    assert!(!d.reading(&reading("press", "a0")).is_empty());
    d
}

/// With a calendar, a metered channel has a `total_increasing` sensor per tariff register (what
/// the Energy dashboard takes); a channel without intervals has none.
#[test]
fn each_tariff_register_of_a_metered_channel_is_a_total_increasing_sensor() {
    let mut d = account_discovery();
    for tariff in ["offpeak", "peak"] {
        let v = json(
            &mut d,
            &format!("homeassistant/sensor/edge/line1_u3_a0_tariff_{tariff}/config"),
        );
        assert_eq!(v["state_class"], "total_increasing");
        assert_eq!(v["device_class"], "energy");
        assert_eq!(v["unit_of_measurement"], "kWh");
        assert_eq!(v["value_template"], "{{ value_json.value }}");
        assert_eq!(
            v["state_topic"],
            format!("pulsegate/edge/meter/a0/tariff/{tariff}")
        );
        assert!(
            v["json_attributes_template"]
                .as_str()
                .unwrap()
                .contains("obis")
        );
    }
    let total = json(&mut d, "homeassistant/sensor/edge/line1_u3_a0_total/config");
    assert!(
        total["json_attributes_template"]
            .as_str()
            .unwrap()
            .contains("'obis'")
    );
    let all = d.everything();
    assert!(
        all.iter().all(|a| !a.topic.contains("line1_u4_a0_tariff")
            && !a.topic.contains("line1_u4_a0_billing")
            && !a.topic.contains("line1_u4_a0_demand")),
        "the press has no account: {:?}",
        all.iter().map(|a| &a.topic).collect::<Vec<_>>()
    );
}

/// With billing, a metered channel has its period's maximum demand as a power `measurement`
/// and its last billing record, the record's fields as attributes.
#[test]
fn the_demand_and_the_last_billing_period_are_sensors_of_a_metered_channel() {
    let mut d = account_discovery();
    let demand = json(
        &mut d,
        "homeassistant/sensor/edge/line1_u3_a0_demand/config",
    );
    assert_eq!(demand["state_class"], "measurement");
    assert_eq!(demand["device_class"], "power");
    assert_eq!(demand["unit_of_measurement"], "kW");
    assert_eq!(demand["state_topic"], "pulsegate/edge/meter/a0/billing");
    assert!(
        demand["value_template"]
            .as_str()
            .unwrap()
            .contains("demand.value")
    );
    let period = json(
        &mut d,
        "homeassistant/sensor/edge/line1_u3_a0_billing/config",
    );
    assert_eq!(period["state_class"], "total");
    assert_eq!(
        period["last_reset_value_template"],
        "{{ value_json.start }}"
    );
    assert_eq!(
        period["json_attributes_topic"],
        "pulsegate/edge/meter/a0/billing"
    );
    assert!(
        period.get("json_attributes_template").is_none(),
        "every field of the record is an attribute"
    );
}

/// Without `demand`, billing records carry none, and there is no demand sensor.
#[test]
fn billing_without_demand_has_no_demand_sensor() {
    let text = CONFIG
        .replace(
            "[buses.line1]",
            "[billing]\nperiod = \"daily\"\n[buses.line1]",
        )
        .replace(
            "[buses.line1.devices.meter.channels.a0]",
            "intervals = [\"15min\"]\n[buses.line1.devices.meter.channels.a0]",
        );
    let mut d = discovery(&config(&text));
    d.start();
    d.reading(&reading("meter", "a0"));
    let topics: Vec<String> = d.everything().into_iter().map(|a| a.topic).collect();
    assert!(
        topics
            .iter()
            .any(|t| t.ends_with("line1_u3_a0_billing/config"))
    );
    assert!(!topics.iter().any(|t| t.ends_with("_demand/config")));
    assert!(!topics.iter().any(|t| t.contains("_tariff_")));
}
