//! Issue 13: engineering units, publish policy, one JSON per device, Home Assistant discovery —
//! against the simulator and a real Mosquitto.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use rumqttc::v5::mqttbytes::QoS;
use serde_json::Value;

use crate::support::*;

/// The text of a top-level number in a JSON payload, exactly as sent.
fn raw_number<'a>(payload: &'a str, key: &str) -> Option<&'a str> {
    let start = payload.find(&format!("\"{key}\":"))? + key.len() + 3;
    let rest = &payload[start..];
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    Some(&rest[..end])
}

/// `t × 0.1` as a person writes it.
fn tenths(t: i64) -> String {
    if t % 10 == 0 {
        (t / 10).to_string()
    } else {
        format!("{}.{}", t / 10, t % 10)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_weighted_channel_publishes_its_scaled_total_and_rate_as_exact_decimal_text() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.meter]\nunit = 1\nmodel = \"zh-yx1600\"\nchannels.di1 = { rate = 37 }\n",
    )
    .await;
    let dir = temp_dir("units");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let _gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line1", "meter", 1, "zh-yx1600", "100ms")],
        "[buses.line1.devices.meter.channels.di1]\nscale = 0.1\nunit = \"L\"\n\
         rate_unit = \"L/min\"\nrate_per = \"min\"\ndevice_class = \"water\"\n",
    );
    let topic = "pulsegate/test/meter/di1";
    assert!(
        sub.wait_for(topic, Duration::from_secs(5), |m| m.json()["total"]
            .as_i64()
            .is_some_and(|t| t > 60))
            .await
            .is_some(),
        "no readings with a growing total"
    );
    let mut float_would_be_wrong = 0;
    for m in sub.on(topic) {
        let total = m.json()["total"].as_i64().unwrap();
        let value = raw_number(&m.payload, "value").expect("a value in every reading");
        assert_eq!(value, tenths(total), "in {}", m.payload);
        if (total as f64 * 0.1).to_string() != tenths(total) {
            float_would_be_wrong += 1;
        }
        if let Some(hz) = m.json()["rate_hz"].as_f64() {
            let rate = m.json()["rate"]
                .as_f64()
                .expect("a scaled rate beside rate_hz");
            // rate_hz is rounded to 3 decimals in the payload; rate is computed before that.
            let want = hz * 0.1 * 60.0;
            let slack = 0.0005 * 0.1 * 60.0 + want.abs() * 1e-5;
            assert!((rate - want).abs() <= slack, "{rate} vs {want}");
        }
    }
    assert!(
        float_would_be_wrong > 0,
        "the run must include totals whose f64 product prints float noise"
    );
}

/// Keys Home Assistant's MQTT sensor platform accepts, from
/// https://www.home-assistant.io/integrations/sensor.mqtt/ ("Configuration Variables"), plus
/// `origin`, which discovery payloads take (https://www.home-assistant.io/integrations/mqtt/,
/// "Discovery payload"). `object_id` is left out on purpose: deprecated since 2025.10.
const SENSOR_KEYS: &[&str] = &[
    "availability",
    "availability_mode",
    "availability_template",
    "availability_topic",
    "default_entity_id",
    "device",
    "device_class",
    "enabled_by_default",
    "encoding",
    "entity_category",
    "entity_picture",
    "expire_after",
    "force_update",
    "icon",
    "json_attributes_template",
    "json_attributes_topic",
    "last_reset_value_template",
    "name",
    "options",
    "payload_available",
    "payload_not_available",
    "platform",
    "qos",
    "state_class",
    "state_topic",
    "suggested_display_precision",
    "unique_id",
    "unit_of_measurement",
    "value_template",
    "origin",
];

/// https://www.home-assistant.io/integrations/button.mqtt/ ("Configuration Variables").
const BUTTON_KEYS: &[&str] = &[
    "availability",
    "availability_mode",
    "availability_template",
    "availability_topic",
    "command_template",
    "command_topic",
    "default_entity_id",
    "device",
    "device_class",
    "enabled_by_default",
    "encoding",
    "entity_category",
    "entity_picture",
    "icon",
    "json_attributes_template",
    "json_attributes_topic",
    "name",
    "payload_available",
    "payload_not_available",
    "payload_press",
    "platform",
    "qos",
    "retain",
    "unique_id",
    "origin",
];

/// The `device` map of both pages.
const DEVICE_KEYS: &[&str] = &[
    "configuration_url",
    "connections",
    "hw_version",
    "identifiers",
    "manufacturer",
    "model",
    "model_id",
    "name",
    "serial_number",
    "suggested_area",
    "sw_version",
    "via_device",
];

/// One entry of the `availability` list of both pages.
const AVAILABILITY_KEYS: &[&str] = &[
    "payload_available",
    "payload_not_available",
    "topic",
    "value_template",
];

/// The `origin` map of the discovery page.
const ORIGIN_KEYS: &[&str] = &["name", "sw_version", "support_url"];

fn keys_within(v: &Value, allowed: &[&str], what: &str) {
    let map = v
        .as_object()
        .unwrap_or_else(|| panic!("{what} is not a map: {v}"));
    for k in map.keys() {
        assert!(
            allowed.contains(&k.as_str()),
            "{what}: key {k:?} is not accepted"
        );
    }
}

/// Checks one discovery config against the platform's keys; returns its JSON.
pub(crate) fn valid_config(topic: &str, payload: &str) -> Value {
    let v: Value = serde_json::from_str(payload).unwrap_or_else(|e| panic!("{topic}: {e}"));
    let component = topic.split('/').nth(1).unwrap();
    let allowed = match component {
        "sensor" => SENSOR_KEYS,
        "button" => BUTTON_KEYS,
        other => panic!("{topic}: unexpected component {other}"),
    };
    keys_within(&v, allowed, topic);
    for required in ["unique_id", "device", "origin", "default_entity_id"] {
        assert!(v.get(required).is_some(), "{topic}: no {required}");
    }
    keys_within(&v["device"], DEVICE_KEYS, &format!("{topic} device"));
    keys_within(&v["origin"], ORIGIN_KEYS, &format!("{topic} origin"));
    if let Some(list) = v.get("availability") {
        for a in list.as_array().unwrap() {
            keys_within(a, AVAILABILITY_KEYS, &format!("{topic} availability"));
        }
    }
    v
}

/// The latest payload of every topic seen, empty ones included.
fn latest(sub: &Subscriber) -> BTreeMap<String, String> {
    sub.all()
        .into_iter()
        .map(|m| (m.topic, m.payload))
        .collect()
}

const DISCOVERY_PLANT: &str = r#"
[buses.line1.devices.meter]
unit = 1
model = "yl67"
modes = [1, 0, 0, 0]
channels.a0 = { rate = 40 }
channels.enc1 = { rate = -30 }
[buses.line1.devices.doors]
unit = 2
model = "zh-yx1600"
channels.di3 = { rate = 5 }
"#;

fn discovery_config(plant: &pulsegate::sim::Plant, port: u16, dir: &std::path::Path) -> String {
    gateway_toml(
        plant,
        port,
        dir,
        &[
            ("line1", "meter", 1, "yl67", "200ms"),
            ("line1", "doors", 2, "zh-yx1600", "200ms"),
        ],
        "[homeassistant]\ndiscovery = true\n\
         [buses.line1.devices.meter.channels.a0]\nscale = 0.001\nunit = \"kWh\"\n\
         rate_unit = \"kW\"\nrate_per = \"h\"\ndevice_class = \"energy\"\n",
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_channel_is_discovered_with_valid_configs_cleared_when_removed_and_republished() {
    let broker = Broker::start();
    let plant = plant(DISCOVERY_PLANT).await;
    let dir = temp_dir("discovery");
    let ha = Subscriber::start(broker.port, "homeassistant/#").await;
    let readings = Subscriber::start(broker.port, "pulsegate/test/#").await;
    // A module removed while the gateway was away left its config retained.
    let stale = "homeassistant/sensor/test/line9_u9_a0_total/config";
    ha.client
        .publish(stale, QoS::AtLeastOnce, true, r#"{"name":"old"}"#)
        .await
        .unwrap();
    // The meter's encoder 0 ran in quadrature mode before it was set to count A and B.
    let other_mode = "homeassistant/sensor/test/line1_u1_enc0_position/config";
    ha.client
        .publish(other_mode, QoS::AtLeastOnce, true, r#"{"name":"old"}"#)
        .await
        .unwrap();
    let config = write_config(&dir, &discovery_config(&plant, broker.port, &dir));
    let gw = Gateway::start(&config);

    assert!(
        ha.wait_for(stale, Duration::from_secs(5), |m| m.payload.is_empty())
            .await
            .is_some(),
        "a retained config of a module no longer configured is cleared at start"
    );
    assert!(
        ha.wait_for(other_mode, Duration::from_secs(5), |m| m.payload.is_empty())
            .await
            .is_some(),
        "a config of a channel the module's work mode does not have is cleared"
    );
    // Every channel that publishes readings has a config, and every config is valid: waited
    // for until the five channels of the meter and the doors' inputs have published four
    // readings each.
    let units = BTreeMap::from([("meter", 1), ("doors", 2)]);
    let wanted = || {
        let mut wanted = BTreeMap::new();
        for m in readings.all() {
            let parts: Vec<&str> = m.topic.split('/').collect();
            let [_, _, device, channel] = parts[..] else {
                continue;
            };
            if channel == "status" || m.json().get("total").is_none() {
                continue;
            }
            let entity = if channel.starts_with("enc") {
                "position"
            } else {
                "total"
            };
            let config = format!(
                "homeassistant/sensor/test/line1_u{}_{channel}_{entity}/config",
                units[device]
            );
            *wanted.entry(config).or_insert(0) += 1;
        }
        wanted
    };
    let doors = |w: &BTreeMap<String, usize>| w.keys().any(|t| t.contains("_u2_"));
    let announced = || {
        let (w, configs) = (wanted(), latest(&ha));
        w.len() >= 6 && doors(&w) && w.iter().all(|(t, n)| *n > 3 && configs.contains_key(t))
    };
    until(
        Duration::from_secs(15),
        "a config for every channel",
        announced,
        || format!("{:?}", wanted()),
    )
    .await;
    let configs = latest(&ha);
    let wanted = wanted();
    for topic in wanted.keys() {
        let payload = configs
            .get(topic)
            .unwrap_or_else(|| panic!("no config {topic}"));
        assert!(!payload.is_empty(), "{topic} is empty");
    }
    let channels = wanted.len();
    assert!(
        channels >= 5,
        "readings of a0, b0, enc1..3 and the doors' inputs expected"
    );
    let mut increasing = 0;
    for (topic, payload) in configs
        .iter()
        .filter(|(t, p)| t.ends_with("/config") && !p.is_empty())
    {
        if topic == "homeassistant/status" {
            continue;
        }
        let v = valid_config(topic, payload);
        if topic.contains("/button/") {
            continue;
        }
        if topic.contains("gateway_status") {
            continue;
        }
        assert_eq!(v["availability_mode"], "all", "{topic}");
        assert_eq!(v["device"]["via_device"], "pulsegate_test", "{topic}");
        if v["state_class"] == "total_increasing" {
            increasing += 1;
            assert!(
                !topic.contains("_enc"),
                "an encoder is never total_increasing: {topic}"
            );
            let state = v["state_topic"].as_str().unwrap();
            let totals: Vec<i64> = readings
                .on(state)
                .iter()
                .filter_map(|m| m.json()["total"].as_i64())
                .collect();
            assert!(totals.len() > 3, "{state}");
            assert!(
                totals.windows(2).all(|w| w[0] <= w[1]),
                "{state}: {totals:?}"
            );
        }
    }
    assert!(
        increasing >= 3,
        "a0, b0 and the doors' inputs are meter totals"
    );
    let enc = serde_json::from_str::<Value>(
        &configs["homeassistant/sensor/test/line1_u1_enc1_position/config"],
    )
    .unwrap();
    assert_eq!(enc["state_class"], "measurement", "enc1 turns backwards");

    // Home Assistant restarts: every config comes again.
    ha.clear();
    ha.client
        .publish("homeassistant/status", QoS::AtLeastOnce, false, "online")
        .await
        .unwrap();
    let total = "homeassistant/sensor/test/line1_u1_a0_total/config";
    assert!(
        ha.wait_for(total, Duration::from_secs(3), |m| !m.payload.is_empty())
            .await
            .is_some(),
        "configs are republished when Home Assistant says online"
    );

    // The doors module is removed by SIGHUP: its configs are cleared.
    let doors_topics: Vec<String> = configs
        .iter()
        .filter(|(t, p)| t.contains("/line1_u2_") && !p.is_empty())
        .map(|(t, _)| t.clone())
        .collect();
    assert!(doors_topics.len() >= 3, "{doors_topics:?}");
    let text = std::fs::read_to_string(&config).unwrap();
    let without = text.replace(
        "[buses.line1.devices.doors]\nunit = 2\nmodel = \"zh-yx1600\"\npoll = \"200ms\"\n",
        "",
    );
    assert_ne!(text, without);
    std::fs::write(&config, without).unwrap();
    ha.clear();
    gw.signal("HUP");
    for topic in &doors_topics {
        assert!(
            ha.wait_for(topic, Duration::from_secs(5), |m| m.payload.is_empty())
                .await
                .is_some(),
            "{topic} not cleared after the device was removed"
        );
    }
    assert!(
        ha.on(total).iter().all(|m| !m.payload.is_empty()),
        "the meter stays"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pressing_the_clear_button_clears_the_channel_and_the_total_keeps_increasing() {
    let broker = Broker::start();
    let plant = plant(DISCOVERY_PLANT).await;
    let dir = temp_dir("button");
    let ha = Subscriber::start(broker.port, "homeassistant/#").await;
    let readings = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let _gw = Gateway::start(&write_config(
        &dir,
        &discovery_config(&plant, broker.port, &dir),
    ));
    let button = ha
        .wait_for(
            "homeassistant/button/test/line1_u1_a0_clear/config",
            Duration::from_secs(5),
            |m| !m.payload.is_empty(),
        )
        .await
        .expect("a clear button for a0");
    let b = valid_config(&button.topic, &button.payload);
    let state = "pulsegate/test/meter/a0";
    assert!(
        readings
            .wait_for(state, Duration::from_secs(5), |m| m.json()["count"]
                .as_i64()
                > Some(60))
            .await
            .is_some()
    );
    let before = readings.on(state).last().unwrap().json()["total"]
        .as_i64()
        .unwrap();
    let pressed = Instant::now();
    readings
        .client
        .publish(
            b["command_topic"].as_str().unwrap(),
            QoS::AtLeastOnce,
            false,
            b["payload_press"].as_str().unwrap().to_string(),
        )
        .await
        .unwrap();
    let cleared = readings
        .wait_for(state, Duration::from_secs(5), |m| {
            m.json()["event"] == "cleared"
        })
        .await
        .expect("the press clears the channel through the command path");
    assert!(
        cleared.json()["count"].as_i64().unwrap() < 20,
        "{}",
        cleared.payload
    );
    assert!(
        readings
            .wait_for(state, Duration::from_secs(3), |m| m.at > pressed
                && m.json()["total"].as_i64() > Some(before + 40))
            .await
            .is_some(),
        "the total goes on from where it was"
    );
    let totals: Vec<i64> = readings
        .on(state)
        .iter()
        .filter_map(|m| m.json()["total"].as_i64())
        .collect();
    assert!(totals.windows(2).all(|w| w[0] <= w[1]), "{totals:?}");
}

fn ts_ms(m: &Message) -> u64 {
    let ts = m.json()["ts"].as_str().unwrap().to_string();
    let t = humantime::parse_rfc3339(&ts).unwrap();
    pulsegate::reading::unix_ms(t)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_change_a_still_channel_beats_a_moving_one_is_paced_and_no_pulse_is_lost() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.io]\nunit = 1\nmodel = \"zh-yx1600\"\n").await;
    let dir = temp_dir("policy");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "io", 1, "zh-yx1600", "100ms")],
        "[buses.line1.devices.io.channels.di2]\nmin_interval = \"500ms\"\n",
    )
    .replace(
        "[gateway]\n",
        "[gateway]\npublish = \"change\"\nheartbeat = \"1s\"\n",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    let (still, moving) = ("pulsegate/test/io/di1", "pulsegate/test/io/di2");
    sub.expect_any(moving, Duration::from_secs(5)).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    plant.with_module("line1", 1, |m, now| m.set_rate(now, "di2", 40.0));
    tokio::time::sleep(Duration::from_secs(3)).await;
    plant.with_module("line1", 1, |m, now| m.set_rate(now, "di2", 0.0));
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let generated = plant
        .with_module("line1", 1, |m, now| {
            m.channel("di2").unwrap().generated(now)
        })
        .unwrap();

    let beats: Vec<u64> = sub.on(still).iter().map(ts_ms).collect();
    assert!(beats.len() >= 4, "about one per second over 7 s: {beats:?}");
    for w in beats.windows(2) {
        let gap = w[1] - w[0];
        // Paced at 1 s: never sooner; later only by a poll's delay (generous for a loaded
        // test machine, where a poll may wait).
        assert!((1000..2500).contains(&gap), "still channel gaps {beats:?}");
    }

    let moved = sub.on(moving);
    let times: Vec<u64> = moved.iter().map(ts_ms).collect();
    for w in times.windows(2) {
        assert!(
            w[1] - w[0] >= 500,
            "moving channel published within 500 ms: {times:?}"
        );
    }
    let polls_while_moving = 30;
    assert!(moved.len() < polls_while_moving, "{} messages", moved.len());
    let deltas: i64 = moved
        .iter()
        .map(|m| m.json()["delta"].as_i64().unwrap())
        .sum();
    assert!(generated > 100, "{generated}");
    assert_eq!(
        deltas, generated,
        "published deltas sum to the pulses generated"
    );
    let seqs: Vec<u64> = moved
        .iter()
        .map(|m| m.json()["seq"].as_u64().unwrap())
        .collect();
    let expected: Vec<u64> = (1..=seqs.len() as u64).collect();
    assert_eq!(seqs, expected, "seq counts published readings only");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_can_publish_all_its_channels_in_one_message() {
    let broker = Broker::start();
    let plant = plant(DISCOVERY_PLANT).await;
    let dir = temp_dir("device-payload");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[
            ("line1", "meter", 1, "yl67", "200ms"),
            ("line1", "doors", 2, "zh-yx1600", "200ms"),
        ],
        "",
    )
    .replace(
        "[buses.line1.devices.meter]\n",
        "[buses.line1.devices.meter]\npayload = \"device\"\n",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    let m = sub
        .wait_for("pulsegate/test/meter", Duration::from_secs(5), |_| true)
        .await
        .expect("one message per poll on <root>/<device>");
    let v = m.json();
    for ch in ["a0", "b0", "enc1", "enc2", "enc3"] {
        assert!(v[ch]["total"].is_i64(), "{ch} missing in {}", m.payload);
    }
    sub.expect_any("pulsegate/test/doors/di3", Duration::from_secs(3))
        .await;
    assert!(
        sub.on("pulsegate/test/meter/a0").is_empty(),
        "no per-channel messages"
    );
}
