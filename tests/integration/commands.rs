//! Clear and preset from MQTT, checked against the simulated module's own registers.

use std::time::{Duration, Instant};

use bytes::Bytes;
use pulsegate::sim::Plant;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::PublishProperties;
use serde_json::{Value, json};

use crate::protocol::{Protocol, Side};
use crate::support::*;

const PLANT: &str = r#"
[buses.line1.devices.yl]
unit = 1
model = "yl67"
modes = [0, 1, 0, 0]
channels.enc0 = { count = 500 }
channels.a1 = { count = 777 }
[buses.line1.devices.ibf]
unit = 2
model = "ibf67"
[buses.line1.devices.wj]
unit = 3
model = "wj157"
modes = [1]
channels.a0 = { count = 42 }
[buses.line1.devices.zh]
unit = 4
model = "zh-yx1600"
channels.di1 = { count = 5, rate = 20.0 }
"#;

struct Rig {
    _side: Side,
    _broker: Broker,
    plant: Plant,
    sub: Subscriber,
    _gateway: Gateway,
}

impl Rig {
    async fn start(name: &str) -> Rig {
        Rig::start_over(name, Protocol::V5).await
    }

    /// A rig whose gateway speaks `protocol` (the test's own client speaks v5 to the broker).
    async fn start_over(name: &str, protocol: Protocol) -> Rig {
        let broker = Broker::start();
        let side = protocol.side(broker.port);
        let plant = plant(PLANT).await;
        let dir = temp_dir(name);
        let sub = Subscriber::start(broker.port, "#").await;
        let devices = [
            ("line1", "yl", 1, "yl67", "200ms"),
            ("line1", "ibf", 2, "ibf67", "200ms"),
            ("line1", "wj", 3, "wj157", "200ms"),
            ("line1", "zh", 4, "zh-yx1600", "200ms"),
        ];
        let gateway = side.start_gateway(&plant, &dir, &devices, "");
        for d in ["yl", "ibf", "wj", "zh"] {
            let t = format!("pulsegate/test/{d}/status");
            assert!(
                sub.wait_for(&t, Duration::from_secs(5), |m| m.payload == "online")
                    .await
                    .is_some(),
                "{d} online"
            );
        }
        // The ZH-YX1600 starts with its counters stopped (factory state): the gateway starts
        // them; tests that count writes begin once it has.
        let deadline = Instant::now() + Duration::from_secs(10);
        while !plant
            .with_module("line1", 4, |m, _| m.channels.iter().all(|c| c.running()))
            .unwrap()
        {
            assert!(
                Instant::now() < deadline,
                "the gateway started the counters"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        Rig {
            _side: side,
            _broker: broker,
            plant,
            sub,
            _gateway: gateway,
        }
    }

    async fn send(&self, topic: &str, payload: &str) {
        self.sub
            .client
            .publish(
                format!("pulsegate/test/{topic}"),
                QoS::AtLeastOnce,
                false,
                payload.to_string(),
            )
            .await
            .unwrap();
    }

    /// Sends a command with an id and waits for its result.
    async fn command(&self, topic: &str, mut payload: Value) -> Value {
        let id = format!("t{}", free_port());
        payload["id"] = json!(id);
        self.send(topic, &payload.to_string()).await;
        let result = format!("pulsegate/test/{topic}/result");
        self.sub
            .wait_for(&result, Duration::from_secs(5), |m| m.json()["id"] == id)
            .await
            .unwrap_or_else(|| panic!("no result on {result}"))
            .json()
    }

    fn count(&self, unit: u8, channel: &str) -> i64 {
        self.plant
            .with_module("line1", unit, |m, now| {
                m.channel(channel).unwrap().count(now)
            })
            .unwrap()
    }

    fn raw(&self, unit: u8, address: u16) -> Vec<u16> {
        self.plant
            .with_module("line1", unit, |m, now| m.read(now, address, 2).unwrap())
            .unwrap()
    }

    fn writes(&self) -> u64 {
        (1..=4)
            .map(|u| self.plant.with_module("line1", u, |m, _| m.writes).unwrap())
            .sum()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clear_and_preset_reach_every_seed_model() {
    clear_and_preset_reach_every_seed_model_over(Protocol::V5).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clear_and_preset_reach_every_seed_model_over_mqtt_3_1_1() {
    clear_and_preset_reach_every_seed_model_over(Protocol::V311).await;
}

async fn clear_and_preset_reach_every_seed_model_over(protocol: Protocol) {
    let rig = Rig::start_over("cmd-models", protocol).await;

    // YL67 encoder: preset by FC16, low word first.
    let r = rig
        .command("yl/enc0/cmd", json!({"op":"preset","value":-3000}))
        .await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(r["count"], -3000);
    assert_eq!(
        rig.raw(1, 16),
        vec![(-3000i32 as u32 & 0xFFFF) as u16, 0xFFFF]
    );
    let r = rig.command("yl/enc0/cmd", json!({"op":"clear"})).await;
    assert_eq!(
        (r["ok"].clone(), r["op"].clone()),
        (json!(true), json!("clear")),
        "{r}"
    );
    assert_eq!(rig.count(1, "enc0"), 0);

    // YL67 input counting on its own: clear code 22 for A1.
    let r = rig.command("yl/a1/cmd", json!({"op":"clear"})).await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(rig.count(1, "a1"), 0);

    // IBF67 (the YL67 map).
    let r = rig
        .command("ibf/enc2/cmd", json!({"op":"preset","value":2147483647}))
        .await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(rig.count(2, "enc2"), 2_147_483_647);
    let r = rig.command("ibf/enc2/cmd", json!({"op":"clear"})).await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(rig.count(2, "enc2"), 0);

    // WJ157 in counter mode.
    let r = rig
        .command("wj/a0/cmd", json!({"op":"preset","value":4000000000u64}))
        .await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(
        rig.raw(3, 32),
        vec![
            (4_000_000_000u32 & 0xFFFF) as u16,
            (4_000_000_000u32 >> 16) as u16
        ]
    );
    let r = rig.command("wj/a0/cmd", json!({"op":"clear"})).await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(rig.count(3, "a0"), 0);
    rig.command("wj/a0/cmd", json!({"op":"preset","value":5}))
        .await;
    let r = rig.command("wj/cmd", json!({"op":"clear_all"})).await;
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(rig.count(3, "a0"), 0);

    // ZH-YX1600: preset high word first; clear = stop-and-clear, then counting up again.
    let r = rig
        .command("zh/di1/cmd", json!({"op":"preset","value":100000}))
        .await;
    assert_eq!(r["ok"], true, "{r}");
    let words = rig.raw(4, 0x1160);
    assert_eq!(words[0], 0x0001, "high word first: {words:x?}");
    let r = rig.command("zh/di1/cmd", json!({"op":"clear"})).await;
    assert_eq!(r["ok"], true, "{r}");
    assert!(rig.count(4, "di1") < 20, "cleared");
    assert_eq!(rig.raw(4, 0x1100)[0], 0x00A2, "counting up again");
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(rig.count(4, "di1") > 0, "the counter runs after the clear");

    // The readings carry the events, and a clear or preset never moves the total.
    let readings = readings(&rig.sub, "pulsegate/test/yl/enc0");
    let preset = readings
        .iter()
        .find(|r| r["event"] == "preset")
        .expect("preset event");
    let before = readings
        .iter()
        .take_while(|r| r["event"] != "preset")
        .last()
        .unwrap();
    assert_eq!(preset["total"], before["total"]);
    assert!(readings.iter().any(|r| r["event"] == "cleared"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_malformed_payloads_get_a_thousand_error_results_and_no_write() {
    let rig = Rig::start("cmd-bad").await;
    let writes = rig.writes();
    let bad = [
        ("yl/enc0/cmd", "clear"),
        ("yl/enc0/cmd", "{}"),
        ("yl/enc0/cmd", r#"{"op":"explode"}"#),
        ("yl/enc0/cmd", r#"{"op":"preset"}"#),
        ("yl/enc0/cmd", r#"{"op":"preset","value":"12"}"#),
        ("yl/enc0/cmd", r#"{"op":"preset","value":2147483648}"#),
        ("yl/enc0/cmd", r#"{"op":"preset","value":-2147483648}"#),
        ("yl/a1/cmd", r#"{"op":"preset","value":-1}"#),
        ("yl/enc9/cmd", r#"{"op":"clear"}"#),
        ("nobody/enc0/cmd", r#"{"op":"clear"}"#),
        ("yl/cmd", r#"{"op":"clear"}"#),
    ];
    for i in 0..1000 {
        let (topic, payload) = bad[i % bad.len()];
        rig.send(topic, payload).await;
    }
    let deadline = Instant::now() + Duration::from_secs(20);
    let results = loop {
        let n: Vec<Message> = rig
            .sub
            .all()
            .into_iter()
            .filter(|m| m.topic.ends_with("/cmd/result"))
            .collect();
        if n.len() >= 1000 || Instant::now() > deadline {
            break n;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(results.len(), 1000);
    assert!(
        results.iter().all(|m| m.json()["ok"] == false),
        "every result is an error"
    );
    let codes: std::collections::BTreeSet<String> = results
        .iter()
        .map(|m| m.json()["error"].as_str().unwrap().to_string())
        .collect();
    for code in [
        "bad_json",
        "missing_op",
        "unknown_op",
        "missing_value",
        "bad_value",
        "out_of_range",
        "unknown_channel",
        "unknown_device",
    ] {
        assert!(codes.contains(code), "{code} missing from {codes:?}");
    }
    assert_eq!(rig.writes(), writes, "no write reached a module");
    // Still polling.
    let t = Instant::now();
    assert!(
        rig.sub
            .wait_for("pulsegate/test/yl/enc0", Duration::from_secs(2), |m| m.at
                > t)
            .await
            .is_some()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_retained_clear_waiting_on_the_broker_does_nothing_at_start() {
    a_retained_clear_does_nothing_at_start(Protocol::V5).await;
}

/// 3.1.1 has no retain-handling option: the broker delivers the retained clear at subscribe,
/// flagged retained, and the gateway must drop it on receipt.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_retained_clear_does_nothing_at_start_over_mqtt_3_1_1() {
    a_retained_clear_does_nothing_at_start(Protocol::V311).await;
}

async fn a_retained_clear_does_nothing_at_start(protocol: Protocol) {
    let broker = Broker::start();
    let side = protocol.side(broker.port);
    let plant = plant(PLANT).await;
    let dir = temp_dir("cmd-retained");
    let sub = Subscriber::start(broker.port, "#").await;
    sub.client
        .publish(
            "pulsegate/test/yl/enc0/cmd",
            QoS::AtLeastOnce,
            true,
            r#"{"op":"clear"}"#,
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let devices = [("line1", "yl", 1, "yl67", "200ms")];
    let gw = side.start_gateway(&plant, &dir, &devices, "");
    sub.expect_any("pulsegate/test/yl/enc0", Duration::from_secs(3))
        .await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_eq!(
        plant.with_module("line1", 1, |m, _| m.writes).unwrap(),
        0,
        "no write"
    );
    assert!(
        sub.on("pulsegate/test/yl/enc0/cmd/result").is_empty(),
        "no result"
    );
    assert_eq!(
        plant
            .with_module("line1", 1, |m, now| m.channel("enc0").unwrap().count(now))
            .unwrap(),
        500
    );
    if protocol == Protocol::V311 {
        // Delivered (3.1.1 cannot decline it) and dropped on receipt.
        let log = gw.log_text();
        assert!(
            log.contains("ignoring a retained command message"),
            "the retained clear reached the gateway and was ignored:\n{log}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_id_again_is_answered_again_without_a_second_write() {
    let rig = Rig::start("cmd-dup").await;
    let before = rig.writes();
    let payload = r#"{"op":"preset","value":10,"id":"same"}"#;
    rig.send("yl/enc0/cmd", payload).await;
    let topic = "pulsegate/test/yl/enc0/cmd/result";
    assert!(
        rig.sub
            .wait_for(topic, Duration::from_secs(5), |m| m.json()["ok"] == true)
            .await
            .is_some()
    );
    rig.send("yl/enc0/cmd", payload).await;
    let deadline = Instant::now() + Duration::from_secs(5);
    while rig.sub.on(topic).len() < 2 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let results = rig.sub.on(topic);
    assert_eq!(results.len(), 2);
    assert_eq!(results[0].json(), results[1].json());
    assert_eq!(rig.writes() - before, 1, "one preset write");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_mqtt5_request_is_answered_on_its_response_topic_with_its_correlation_data() {
    let rig = Rig::start("cmd-v5").await;
    let props = PublishProperties {
        response_topic: Some("app/replies/42".into()),
        correlation_data: Some(Bytes::from_static(b"corr-42")),
        ..Default::default()
    };
    rig.sub
        .client
        .publish_with_properties(
            "pulsegate/test/yl/enc0/cmd",
            QoS::AtLeastOnce,
            false,
            r#"{"op":"clear"}"#,
            props,
        )
        .await
        .unwrap();
    let reply = rig
        .sub
        .wait_for("app/replies/42", Duration::from_secs(5), |_| true)
        .await
        .expect("reply on the response topic");
    assert_eq!(reply.json()["ok"], true);
    assert_eq!(reply.correlation.as_deref(), Some(&b"corr-42"[..]));
}

/// MQTT 3.1.1 carries no response topic or correlation data: a v5 requester's response topic
/// never reaches a 3.1.1 gateway, and the result goes to `<command topic>/result` alone.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_mqtt_3_1_1_the_result_goes_to_the_result_topic_only() {
    let rig = Rig::start_over("cmd-v311-rt", Protocol::V311).await;
    let props = PublishProperties {
        response_topic: Some("app/replies/43".into()),
        correlation_data: Some(Bytes::from_static(b"corr-43")),
        ..Default::default()
    };
    rig.sub
        .client
        .publish_with_properties(
            "pulsegate/test/yl/enc0/cmd",
            QoS::AtLeastOnce,
            false,
            r#"{"op":"clear","id":"v311"}"#,
            props,
        )
        .await
        .unwrap();
    let result = rig
        .sub
        .wait_for(
            "pulsegate/test/yl/enc0/cmd/result",
            Duration::from_secs(5),
            |m| m.json()["id"] == "v311",
        )
        .await
        .expect("result on the result topic");
    assert_eq!(result.json()["ok"], true);
    assert_eq!(result.correlation, None);
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!(rig.sub.on("app/replies/43").is_empty());
}

/// Payloads a fuzzer would send: random bytes, cut and mutated JSON, wrong types, deep nesting.
fn fuzzed(rng: &mut u64) -> Vec<u8> {
    let mut next = || {
        *rng ^= *rng << 13;
        *rng ^= *rng >> 7;
        *rng ^= *rng << 17;
        *rng
    };
    let seeds: [&[u8]; 6] = [
        br#"{"op":"preset","value":3000,"id":"x"}"#,
        br#"{"op":"clear"}"#,
        br#"{"op":"clear_all"}"#,
        br#"[{"op":"clear"}]"#,
        br#"{"op":"preset","value":{"v":1}}"#,
        b"\xff\xfe\x00garbage",
    ];
    let mut p = seeds[(next() % 6) as usize].to_vec();
    match next() % 5 {
        0 => p = (0..next() % 64).map(|_| next() as u8).collect(),
        1 => p.truncate((next() as usize) % (p.len() + 1)),
        2 => {
            for _ in 0..1 + next() % 4 {
                let i = (next() as usize) % p.len().max(1);
                if i < p.len() {
                    p[i] = next() as u8;
                }
            }
        }
        3 => {
            p = format!(
                "{}{}",
                "[".repeat((next() % 200) as usize),
                "]".repeat((next() % 200) as usize)
            )
            .into_bytes()
        }
        _ => p.extend_from_slice(b",\"extra\":1}"),
    }
    p
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ten_thousand_fuzzed_payloads_cause_no_write_and_no_crash() {
    let rig = Rig::start("cmd-fuzz").await;
    let writes = rig.writes();
    let topics = [
        "yl/enc0/cmd",
        "yl/a1/cmd",
        "yl/cmd",
        "wj/a0/cmd",
        "zh/di1/cmd",
        "zh/cmd",
        "ibf/enc3/cmd",
    ];
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    let mut sent = 0;
    while sent < 10_000 {
        let p = fuzzed(&mut rng);
        let channel = !topics[sent % topics.len()].ends_with("/cmd")
            || topics[sent % topics.len()].matches('/').count() == 2;
        // Only malformed ones: a fuzzer that happens to write a valid command would rightly write.
        if pulsegate::command::parse_payload(&p, channel).is_ok() {
            continue;
        }
        rig.sub
            .client
            .publish(
                format!("pulsegate/test/{}", topics[sent % topics.len()]),
                QoS::AtMostOnce,
                false,
                p,
            )
            .await
            .unwrap();
        sent += 1;
    }
    let deadline = Instant::now() + Duration::from_secs(30);
    let results = loop {
        let n = rig
            .sub
            .all()
            .iter()
            .filter(|m| m.topic.ends_with("/cmd/result"))
            .count();
        if n >= 10_000 || Instant::now() > deadline {
            break n;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(results, 10_000, "every payload answered");
    assert_eq!(rig.writes(), writes, "no write reached a module");
    let t = Instant::now();
    assert!(
        rig.sub
            .wait_for("pulsegate/test/yl/enc0", Duration::from_secs(2), |m| m.at
                > t)
            .await
            .is_some(),
        "still polling"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_to_a_disabled_or_offline_device_are_refused_without_a_write() {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("cmd-refused");
    let sub = Subscriber::start(broker.port, "#").await;
    let devices = [
        ("line1", "yl", 1, "yl67", "200ms"),
        ("line1", "wj", 3, "wj157", "200ms"),
    ];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "").replace(
        "model = \"yl67\"\npoll = \"200ms\"\n",
        "model = \"yl67\"\npoll = \"200ms\"\ncommands = false\n",
    );
    assert!(text.contains("commands = false"));
    let config = write_config(&dir, &text);
    let _gw = Gateway::start(&config);
    for d in ["yl", "wj"] {
        let t = format!("pulsegate/test/{d}/status");
        assert!(
            sub.wait_for(&t, Duration::from_secs(5), |m| m.payload == "online")
                .await
                .is_some()
        );
    }
    sub.send("pulsegate/test/yl/enc0/cmd", r#"{"op":"clear","id":"d1"}"#)
        .await;
    let r = sub
        .wait_for(
            "pulsegate/test/yl/enc0/cmd/result",
            Duration::from_secs(3),
            |_| true,
        )
        .await
        .expect("result");
    assert_eq!(r.json()["error"], "disabled", "{}", r.payload);

    // The WJ157 stops answering: a command waits for it at most its 10 s expiry.
    plant
        .with_module("line1", 3, |m, _| m.silent = true)
        .unwrap();
    assert!(
        sub.wait_for("pulsegate/test/wj/status", Duration::from_secs(5), |m| m
            .payload
            == "offline")
            .await
            .is_some()
    );
    let sent = Instant::now();
    sub.send("pulsegate/test/wj/a0/cmd", r#"{"op":"clear","id":"o1"}"#)
        .await;
    let r = sub
        .wait_for(
            "pulsegate/test/wj/a0/cmd/result",
            Duration::from_secs(15),
            |_| true,
        )
        .await
        .expect("result");
    assert_eq!(r.json()["error"], "offline", "{}", r.payload);
    let waited = r.at - sent;
    assert!(
        waited >= Duration::from_secs(9) && waited < Duration::from_secs(13),
        "waited {waited:?}"
    );
    let writes: u64 = [1u8, 3]
        .iter()
        .map(|u| plant.with_module("line1", *u, |m, _| m.writes).unwrap())
        .sum();
    assert_eq!(writes, 0, "no write");
}
