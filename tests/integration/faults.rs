//! Nothing lost: broker outages, line faults, unplugged adapters, shutdown.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::protocol::Protocol;
use crate::support::*;

/// Checks that each channel's readings arrived with seq contiguous and in order. An exact
/// re-delivery (same seq, same payload: a message the broker had when the connection dropped,
/// sent again because its acknowledgement was lost) is tolerated; a hole or a step back is not.
fn assert_contiguous(sub: &Subscriber, prefix: &str) -> usize {
    let mut by_topic: BTreeMap<String, Vec<(i64, String)>> = BTreeMap::new();
    for m in sub.all() {
        if m.topic.starts_with(prefix)
            && !m.topic.ends_with("/status")
            && !m.topic.contains("/bus/")
        {
            let seq = m.json()["seq"].as_i64().unwrap_or(-1);
            by_topic
                .entry(m.topic.clone())
                .or_default()
                .push((seq, m.payload.clone()));
        }
    }
    let mut total = 0;
    for (topic, msgs) in &by_topic {
        let mut seen: BTreeMap<i64, &str> = BTreeMap::new();
        let mut last = None;
        for (seq, payload) in msgs {
            if let Some(earlier) = seen.get(seq) {
                assert_eq!(
                    earlier, payload,
                    "{topic}: seq {seq} delivered twice with different content"
                );
                continue;
            }
            if let Some(l) = last {
                assert_eq!(*seq, l + 1, "{topic}: after seq {l} came {seq}");
            }
            seen.insert(*seq, payload);
            last = Some(*seq);
            total += 1;
        }
    }
    assert!(!by_topic.is_empty());
    total
}

/// The same outage over MQTT 3.1.1 (shorter: the mechanism is the same spool and window).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_away_while_400_readings_spool_loses_no_reading_over_mqtt_3_1_1() {
    a_broker_away_loses_no_reading(Protocol::V311, 400).await;
}

/// The broker is stopped with 48 channels publishing at 2 Hz and kept away until the gateway's
/// spool holds `spooled` readings (its metrics say so; about 100 a second, so several reconnect
/// attempts a second apart fail meanwhile): then every reading arrives, each channel's seq
/// contiguous and in order, and the outage is logged once, not per attempt.
pub(crate) async fn a_broker_away_loses_no_reading(protocol: Protocol, spooled: usize) {
    let dir = temp_dir("outage");
    let port = free_port();
    let http = free_port();
    let mut broker = Broker::start_persistent(port, &dir);
    let side = protocol.side(port);
    let mut plant_toml = String::new();
    let mut devices = Vec::new();
    let names: Vec<String> = (1..=16).map(|i| format!("m{i}")).collect();
    for i in 1..=8u8 {
        plant_toml += &format!(
            "[buses.line1.devices.m{i}]\nunit = {i}\nmodel = \"yl67\"\nchannels.enc0 = {{ rate = 100.0 }}\n"
        );
        plant_toml += &format!(
            "[buses.line2.devices.m{}]\nunit = {i}\nmodel = \"wj157\"\nmodes = [1]\nchannels.a0 = {{ rate = 10.0 }}\n",
            i + 8
        );
    }
    for i in 1..=8u8 {
        devices.push((
            "line1",
            names[usize::from(i) - 1].as_str(),
            i,
            "yl67",
            "500ms",
        ));
        devices.push((
            "line2",
            names[usize::from(i) + 7].as_str(),
            i,
            "wj157",
            "500ms",
        ));
    }
    let plant = plant(&plant_toml).await;
    let sub = Subscriber::start_persistent(port, "pulsegate/test/#", "outage-consumer").await;
    let metrics = format!("[metrics]\nlisten = \"127.0.0.1:{http}\"\n");
    let gw = side.start_gateway(&plant, &dir, &devices, &metrics);
    for n in &names {
        let t = format!("pulsegate/test/{n}/status");
        assert!(
            sub.wait_for(&t, Duration::from_secs(5), |m| m.payload == "online")
                .await
                .is_some(),
            "{n} online"
        );
    }
    // Readings flow on both lines before the broker goes.
    for topic in ["pulsegate/test/m1/enc0", "pulsegate/test/m16/a0"] {
        sub.wait_more_than(topic, 2, Duration::from_secs(10)).await;
    }

    broker.terminate();
    let outage = Instant::now();
    crate::metrics::scrape_until(http, Duration::from_secs(60), "readings spooled", |t| {
        let depth = crate::metrics::sample(t, "pulsegate_spool_messages{output=\"json\"}");
        depth.is_some_and(|d| d >= spooled as f64)
            && crate::metrics::sample(t, "pulsegate_mqtt_connected{output=\"json\"}") == Some(0.0)
    })
    .await;
    let restarted = Broker::start_persistent(port, &dir);
    let outage = outage.elapsed();

    // Wait until the backlog is through: readings taken after the restart reach the consumer.
    let after = Instant::now() + Duration::from_secs(3);
    for n in ["m1", "m16"] {
        let topic = if n == "m1" {
            "pulsegate/test/m1/enc0"
        } else {
            "pulsegate/test/m16/a0"
        };
        let got = sub
            .wait_for(topic, Duration::from_secs(30), |m| m.at > after)
            .await;
        assert!(got.is_some(), "{n}: readings after the broker came back");
    }
    let delivered = assert_contiguous(&sub, "pulsegate/test/");
    // 8 x 4 + 8 x 2 channels at 2 Hz through the outage.
    let during = 48.0 * 2.0 * outage.as_secs_f64();
    assert!(
        delivered as f64 > during,
        "{delivered} readings delivered, {during} were due during the outage alone"
    );
    let log = gw.log_text();
    assert!(log.contains("MQTT broker unreachable"), "outage logged");
    assert_eq!(
        log.matches("MQTT broker unreachable").count(),
        1,
        "logged once, not per retry"
    );
    drop(restarted);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_finishes_saves_state_says_offline_and_exits_0_within_5s() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.d]\nunit = 1\nmodel = \"yl67\"\nchannels.enc0 = { rate = 100.0 }\n",
    )
    .await;
    let dir = temp_dir("sigterm");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line1", "d", 1, "yl67", "100ms")],
        "",
    );
    sub.expect_any("pulsegate/test/d/enc0", Duration::from_secs(3))
        .await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    let _ = std::fs::remove_file(dir.join("bus-line1.json"));
    let (status, took) = gw.terminate();
    assert!(status.success(), "exit status {status:?}");
    assert!(took < Duration::from_secs(5), "took {took:?}");
    assert!(
        dir.join("bus-line1.json").exists(),
        "state saved at shutdown"
    );
    let offline = sub
        .wait_for("pulsegate/test/status", Duration::from_secs(2), |m| {
            m.payload == "offline"
        })
        .await;
    assert!(offline.is_some(), "gateway status offline");
    let dev = sub
        .wait_for("pulsegate/test/d/status", Duration::from_secs(2), |m| {
            m.payload == "offline"
        })
        .await;
    assert!(dev.is_some(), "device status offline at shutdown");
    let state: Value =
        serde_json::from_slice(&std::fs::read(dir.join("bus-line1.json")).unwrap()).unwrap();
    assert!(state["channels"]["1/yl67/enc0"]["total"].as_i64().unwrap() > 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_adapter_unplugged_and_plugged_back_resumes_polling_within_5s() {
    let broker = Broker::start();
    let dir = temp_dir("unplug");
    let link = dir.join("ttyRS485-line1");
    let plant = plant(&format!(
        "[buses.line1]\nlink = {link:?}\n[buses.line1.devices.d]\nunit = 1\nmodel = \"yl67\"\nchannels.enc0 = {{ rate = 50.0 }}\n"
    ))
    .await;
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line1", "d", 1, "yl67", "200ms")],
        "",
    );
    assert!(
        sub.wait_for("pulsegate/test/d/status", Duration::from_secs(3), |m| m
            .payload
            == "online")
            .await
            .is_some()
    );

    plant.unplug("line1");
    assert!(!link.exists(), "the adapter's path is gone");
    let offline = sub
        .wait_for("pulsegate/test/d/status", Duration::from_secs(5), |m| {
            m.payload == "offline"
        })
        .await;
    assert!(offline.is_some(), "the device goes offline with its line");
    // Unplugged long enough for the line's probes to back off to their most (500 ms, 1 s,
    // 2 s: `backoff_max`) and fail there again: the fault is still logged once.
    tokio::time::sleep(Duration::from_secs(5)).await;

    plant.plug("line1").unwrap();
    let plugged = Instant::now();
    let back = sub
        .wait_for("pulsegate/test/d/enc0", Duration::from_secs(10), |m| {
            m.at > plugged
        })
        .await;
    let took = back.expect("polling resumed").at - plugged;
    assert!(
        took < Duration::from_secs(5),
        "polling resumed after {took:?}"
    );
    let log = gw.log_text();
    assert_eq!(
        log.matches("line fault").count(),
        1,
        "the fault is logged once, not per poll:\n{log}"
    );
    assert!(log.contains("line is answering again"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_answering_nonsense_is_refused_without_a_panic_or_a_wrong_value() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.a]\nunit = 1\nmodel = \"yl67\"\n[buses.line1.devices.b]\nunit = 2\nmodel = \"yl67\"\nnonsense = true\n",
    )
    .await;
    let dir = temp_dir("nonsense");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "a", 1, "yl67", "100ms"),
        ("line1", "b", 2, "yl67", "100ms"),
    ];
    let gw = start_gateway(&plant, broker.port, &dir, &devices, "");
    // The nonsense module is polled between the sane one's polls all the while.
    assert!(
        sub.wait_more_than("pulsegate/test/a/enc0", 10, Duration::from_secs(15))
            .await
            > 10,
        "the sane module is polled"
    );
    assert!(
        sub.all()
            .iter()
            .all(|m| !m.topic.starts_with("pulsegate/test/b/enc")),
        "nothing published from nonsense"
    );
    let log = gw.log_text();
    assert!(
        log.contains("does not match the request") || log.contains("refused"),
        "{log}"
    );
    let (status, _) = gw.terminate();
    assert!(status.success(), "no panic: {status:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_answer_is_never_taken_for_the_next_modules() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.slow]\nunit = 1\nmodel = \"yl67\"\nanswer_delay = \"180ms\"\nchannels.enc0 = { count = 111111 }\n\
         [buses.line1.devices.fast]\nunit = 2\nmodel = \"yl67\"\nchannels.enc0 = { count = 222222 }\n",
    )
    .await;
    let dir = temp_dir("late");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "slow", 1, "yl67", "100ms"),
        ("line1", "fast", 2, "yl67", "100ms"),
    ];
    let gw = start_gateway(&plant, broker.port, &dir, &devices, "");
    // Each of these polls of the fast module follows one of the slow module's late answers.
    sub.wait_more_than("pulsegate/test/fast/enc0", 10, Duration::from_secs(20))
        .await;
    let fast = readings(&sub, "pulsegate/test/fast/enc0");
    assert!(
        fast.len() > 10,
        "the module behind the slow one is polled: {}",
        fast.len()
    );
    assert!(
        fast.iter().all(|r| r["count"] == 222222),
        "a late answer was bound to the wrong module"
    );
    assert!(
        sub.on("pulsegate/test/slow/enc0").is_empty(),
        "answers after the timeout are not readings"
    );
    assert!(
        sub.wait_for("pulsegate/test/slow/status", Duration::from_secs(10), |m| m
            .payload
            == "offline")
            .await
            .is_some()
    );
    let log = gw.log_text();
    assert!(
        log.contains("no answer within") || log.contains("does not match"),
        "{log}"
    );
}
