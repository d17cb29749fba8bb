//! The output stage: today's JSON messages, and a second format that lives in this file only.

use std::time::{Duration, SystemTime};

use super::*;
use crate::config::{OutputConfig, OutputKind};
use crate::counter::Update;
use crate::outbox::{MemoryStore, Outbox, Step, Store};
use crate::publish::formats::Registry;
use crate::publish::lifecycle::Stage;
use crate::reading::Reading;
use crate::topics::Topics;

/// The JSON kind.
fn json() -> OutputKind {
    OutputKind::of(&crate::config::outputs::json::KIND)
}

/// The output stage of `config`'s first output of `kind`.
fn build(config: &crate::config::Config, kind: OutputKind) -> Stage {
    let output = output_of(config, kind);
    Stage::new(crate::publish::formats::build(config, &output))
}

fn output_of(config: &crate::config::Config, kind: OutputKind) -> OutputConfig {
    config
        .outputs
        .list
        .iter()
        .find(|o| o.kind == kind)
        .cloned()
        .unwrap_or_else(|| OutputConfig {
            name: kind.name().into(),
            kind,
            mqtt: config.mqtt.clone(),
        })
}

fn reading(total: i64) -> Reading {
    Reading {
        device: "press1".into(),
        channel: "enc0".into(),
        ts: SystemTime::UNIX_EPOCH + Duration::from_millis(1_795_300_723_123),
        count: total,
        freq_hz: None,
        rpm: None,
        update: Update {
            delta: 1,
            total,
            seq: 7,
            rate_hz: None,
            event: None,
        },
        after_seq: None,
        meter: None,
        kind: crate::profile::ChannelKind::Encoder,
        units: None,
        measured: None,
    }
}

const BUS: &str = "[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n";

fn check(mqtt: &str) -> Result<crate::config::Config, crate::config::ConfigErrors> {
    let text = format!("[gateway]\nid = \"e1\"\n[mqtt]\ntopic_root = \"pg/e1\"\n{mqtt}\n{BUS}");
    let env = Some(std::collections::HashMap::new());
    crate::config::Config::from_toml(&text, std::path::Path::new("x.toml"), env)
}

fn config() -> crate::config::Config {
    check("retain = true\nqos = 0").expect("config")
}

#[test]
fn json_readings_go_to_the_channel_topic_with_the_configured_qos_and_retain() {
    let mut json = build(&config(), json());
    let m = json.render(&Output::single(reading(42)));
    assert_eq!(m.len(), 1);
    assert_eq!(m[0].topic, "pg/e1/press1/enc0");
    assert_eq!((m[0].qos, m[0].retain, m[0].transient), (0, true, false));
    assert_eq!(
        m[0].payload,
        crate::publish::payload::reading(&reading(42)).into_bytes()
    );
}

#[test]
fn json_status_is_retained_and_bus_health_is_transient() {
    let mut json = build(&config(), json());
    let status = Output::DeviceStatus {
        device: "press1".into(),
        online: false,
    };
    let m = json.render(&status);
    assert_eq!(
        (m[0].topic.as_str(), &m[0].payload[..]),
        ("pg/e1/press1/status", &b"offline"[..])
    );
    assert_eq!((m[0].qos, m[0].retain), (1, true));
    let stats = crate::bus_health::BusStats {
        utilisation: 0.5,
        transactions: 3,
        transactions_per_s: 0.1,
        timeouts: 1,
        garbled: 0,
        stale_dropped: 0,
        io_errors: 0,
        exceptions: 0,
        reconnects: 1,
        devices: Default::default(),
    };
    let stats = Output::BusStats {
        bus: "line1".into(),
        stats: Box::new(stats),
    };
    let m = json.render(&stats);
    assert_eq!(m[0].topic, "pg/e1/bus/line1/stats");
    assert!(m[0].transient && m[0].qos == 0);
    let v: serde_json::Value = serde_json::from_slice(&m[0].payload).unwrap();
    assert_eq!(
        (v["transactions"].as_u64(), v["utilisation"].as_f64()),
        (Some(3), Some(0.5))
    );
}

#[test]
fn a_command_result_carries_the_correlation_data_to_the_response_topic_only() {
    let mut json = build(&config(), json());
    let result = Output::CommandResult {
        reply: crate::command::Reply {
            topics: vec!["pg/e1/press1/cmd/result".into(), "app/replies".into()],
            correlation: Some(bytes::Bytes::from_static(b"c-1")),
            via: Some(crate::command::Via {
                output: "json".into(),
                wrote: None,
            }),
        },
        outcome: crate::outcome::Outcome::Command(crate::outcome::CommandOutcome {
            id: None,
            op: None,
            result: Ok(None),
        }),
    };
    let m = json.render(&result);
    assert_eq!(m.len(), 2);
    assert_eq!(m[0].properties.correlation, None);
    assert_eq!(m[1].properties.correlation.as_deref(), Some(&b"c-1"[..]));
    assert_eq!(&m[1].payload[..], br#"{"ok":true}"#);
}

/// A toy second format: each reading's total as 8 big-endian bytes on `<reading topic>/total`.
/// Everything it needs is the output stage's: the [`Format`] trait, [`Topics`], [`Message`].
struct PackedTotals {
    topics: Topics,
}

impl Format for PackedTotals {
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        let Output::DeviceReadings { readings, .. } = event else {
            return Vec::new();
        };
        let total = |r: &crate::reading::Reading| {
            let topic = format!("{}/total", self.topics.reading(&r.device, &r.channel));
            let payload = r.update.total.to_be_bytes().to_vec();
            Message::new(topic, payload, 1, false)
        };
        readings.iter().map(total).collect()
    }
}

#[test]
fn a_second_format_is_one_type_and_its_binary_payload_reaches_the_client_unchanged() {
    let mut packed = PackedTotals {
        topics: Topics::new("pg/e1"),
    };
    let now = tokio::time::Instant::now();
    let mut outbox = Outbox::new(MemoryStore::new(1 << 20), 10, now);
    outbox.connected(None, now);
    for m in packed.messages(&Output::single(reading(-2))) {
        outbox.enqueue(m).unwrap();
    }
    assert_eq!(outbox.store().len(), 1);
    let Some(Step::Send { entry: e, .. }) = outbox.next(now) else {
        panic!("nothing to send")
    };
    assert_eq!(e.topic, "pg/e1/press1/enc0/total");
    assert_eq!(
        &e.payload[..],
        &[0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xfe]
    );
}

#[test]
fn an_unknown_format_is_a_config_error_naming_the_choices() {
    let err = check("format = \"xml\"").unwrap_err().to_string();
    assert!(err.contains("mqtt.format") && err.contains("json"), "{err}");
}

#[test]
fn every_output_kind_the_config_takes_is_built_and_publishes_a_reading() {
    let c = check("format = [\"json\", \"sparkplug\"]\n[sparkplug]\ngroup_id = \"g\"").unwrap();
    for kind in Registry::standard().kinds().all() {
        let mut built = build(&c, kind);
        let mut r = reading(1);
        (r.device, r.channel) = ("d".into(), "a0".into());
        assert!(!built.render(&Output::single(r)).is_empty(), "{kind}");
    }
}

#[test]
fn the_kinds_are_named_once_and_the_error_lists_them_all() {
    let kinds = Registry::standard().kinds();
    for kind in kinds.all() {
        assert_eq!(
            crate::config::outputs::parse_kind(&kinds, kind.name()),
            Ok(kind)
        );
        let err = crate::config::outputs::parse_kind(&kinds, "xml");
        let err = err.unwrap_err().to_string();
        assert!(err.contains(&format!("{:?}", kind.name())), "{err}");
    }
}

#[test]
fn a_batch_is_a_duration_of_at_most_five_seconds() {
    assert_eq!(
        config().mqtt.batch,
        Duration::from_millis(250),
        "the default"
    );
    assert_eq!(check("batch = \"0s\"").unwrap().mqtt.batch, Duration::ZERO);
    assert_eq!(
        check("batch = \"1s\"").unwrap().mqtt.batch,
        Duration::from_secs(1)
    );
    let err = check("batch = \"6s\"").unwrap_err().to_string();
    assert!(err.contains("mqtt.batch: must be at most 5s"), "{err}");
    let err = check("batch = \"soon\"").unwrap_err().to_string();
    assert!(err.contains("mqtt.batch: bad duration"), "{err}");
}

/// The payload shape is the format's: one event for a device's poll goes as one message per
/// channel, or as one message for a device with `payload = "device"`.
#[test]
fn a_polls_readings_go_one_per_channel_or_as_one_device_message() {
    let poll = Output::DeviceReadings {
        device: "d".into(),
        readings: vec![
            Reading {
                device: "d".into(),
                ..reading(1)
            },
            Reading {
                device: "d".into(),
                channel: "enc1".into(),
                ..reading(2)
            },
        ],
    };
    let mut per_channel = build(&config(), json());
    let topics: Vec<String> = per_channel
        .render(&poll)
        .into_iter()
        .map(|m| m.topic)
        .collect();
    assert_eq!(topics, ["pg/e1/d/enc0", "pg/e1/d/enc1"]);
    let text = format!(
        "[gateway]\nid = \"e1\"\npayload = \"device\"\n[mqtt]\ntopic_root = \"pg/e1\"\n{BUS}"
    );
    let env = Some(std::collections::HashMap::new());
    let device_config =
        crate::config::Config::from_toml(&text, std::path::Path::new("x.toml"), env).unwrap();
    let mut per_device = build(&device_config, json());
    let m = per_device.render(&poll);
    assert_eq!(m.len(), 1);
    assert_eq!(m[0].topic, "pg/e1/d");
}
