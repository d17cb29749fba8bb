//! A hostile and unlucky world (issue 11): bad MQTT input, a second gateway with our client id,
//! command floods, unreadable TLS files, SIGKILL, corrupt state files, a closed stderr.

use std::time::{Duration, Instant};

use bytes::Bytes;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::PublishProperties;

use crate::support::*;

const ONE_ENCODER: &str = r#"
[buses.line1.devices.d]
unit = 1
model = "yl67"
channels.enc0 = { rate = 100.0 }
"#;

fn count_on(sub: &Subscriber, topic: &str, since: Instant) -> usize {
    sub.on(topic).iter().filter(|m| m.at >= since).count()
}

/// One command with a wildcard response topic, one with a 2 KB id, one 11 KB payload: each is
/// refused with an error result where one can be sent, the gateway stays connected and readings
/// keep flowing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wildcard_response_topic_a_long_id_and_a_large_payload_do_not_silence_the_gateway() {
    let broker = Broker::start();
    let plant = plant(ONE_ENCODER).await;
    let dir = temp_dir("hostile-mqtt");
    let sub = Subscriber::start(broker.port, "#").await;
    let gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line1", "d", 1, "yl67", "100ms")],
        "",
    );
    let reading = "pulsegate/test/d/enc0";
    assert!(
        sub.wait_for(reading, Duration::from_secs(5), |_| true)
            .await
            .is_some()
    );
    let cmd = "pulsegate/test/d/enc0/cmd";
    let result = "pulsegate/test/d/enc0/cmd/result";
    let props = PublishProperties {
        response_topic: Some("evil/#".into()),
        correlation_data: Some(Bytes::from_static(b"c1")),
        ..Default::default()
    };
    sub.client
        .publish_with_properties(cmd, QoS::AtLeastOnce, false, r#"{"op":"clear"}"#, props)
        .await
        .unwrap();
    let long_id = format!(r#"{{"op":"clear","id":"{}"}}"#, "i".repeat(2048));
    sub.client
        .publish(cmd, QoS::AtLeastOnce, false, long_id)
        .await
        .unwrap();
    let big = format!(r#"{{"op":"clear","pad":"{}"}}"#, "p".repeat(11 * 1024));
    sub.client
        .publish(cmd, QoS::AtLeastOnce, false, big)
        .await
        .unwrap();

    for code in ["bad_response_topic", "too_large"] {
        assert!(
            sub.wait_for(result, Duration::from_secs(5), |m| m.json()["error"]
                == code)
                .await
                .is_some(),
            "an error result {code}: {:?}\n{}",
            sub.all()
                .iter()
                .map(|m| m.topic.clone())
                .collect::<std::collections::BTreeSet<_>>(),
            gw.log_text()
        );
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    let results = sub.on(result);
    assert_eq!(results.len(), 3, "one result each: {results:?}");
    assert!(results.iter().all(|m| m.json()["ok"] == false));
    assert_eq!(plant.with_module("line1", 1, |m, _| m.writes).unwrap(), 0);

    let since = Instant::now();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(
        count_on(&sub, reading, since) >= 10,
        "readings keep flowing:\n{}",
        gw.log_text()
    );
    let log = gw.log_text();
    assert!(!log.contains("MQTT connection failed"), "{log}");
    assert!(
        !sub.on("pulsegate/test/status")
            .iter()
            .any(|m| m.payload == "offline"),
        "the last will never fired"
    );
}

/// A message the gateway can never send, left in the spool by an earlier version or a crash,
/// is dropped with an error instead of blocking everything behind it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unsendable_message_in_the_spool_does_not_block_the_ones_behind_it() {
    let broker = Broker::start();
    let plant = plant(ONE_ENCODER).await;
    let dir = temp_dir("hostile-spool");
    let spool = dir.join("spool");
    std::fs::create_dir_all(&spool).unwrap();
    std::fs::write(
        spool.join(format!("{:020}.jsonl", 1)),
        concat!(
            r#"{"seq":1,"topic":"evil/#","payload":"{}","qos":1,"retain":false}"#,
            "\n",
            r#"{"seq":2,"topic":"app/after","payload":"behind","qos":1,"retain":false}"#,
            "\n"
        ),
    )
    .unwrap();
    let sub = Subscriber::start(broker.port, "#").await;
    let gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line1", "d", 1, "yl67", "100ms")],
        "",
    );
    assert!(
        sub.wait_for("app/after", Duration::from_secs(5), |m| m.payload
            == "behind")
            .await
            .is_some(),
        "the message behind it is sent:\n{}",
        gw.log_text()
    );
    assert!(
        sub.wait_for("pulsegate/test/d/enc0", Duration::from_secs(5), |_| true)
            .await
            .is_some()
    );
    assert!(gw.log_text().contains("it can never be sent"));
}

/// Two gateways configured with one id (so one client id and one topic root) kick each other
/// off the broker: the second one to start sees the first one's boot marker and says so loudly,
/// and the first one says so too once it is back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_gateway_with_the_same_id_is_detected_and_logged() {
    let broker = Broker::start();
    let plant_a = plant(ONE_ENCODER).await;
    let plant_b = plant(ONE_ENCODER).await;
    let (dir_a, dir_b) = (temp_dir("hostile-dup-a"), temp_dir("hostile-dup-b"));
    let sub = Subscriber::start(broker.port, "#").await;
    let devices = [("line1", "d", 1, "yl67", "100ms")];
    let a = start_gateway(&plant_a, broker.port, &dir_a, &devices, "");
    assert!(
        sub.wait_for("pulsegate/test/d/enc0", Duration::from_secs(5), |_| true)
            .await
            .is_some()
    );
    // A restart of the same gateway (its own previous boot) is not a second gateway.
    drop(a);
    let a = start_gateway(&plant_a, broker.port, &dir_a, &devices, "");
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(
        !a.log_text().contains("another gateway"),
        "{}",
        a.log_text()
    );

    let b = start_gateway(&plant_b, broker.port, &dir_b, &devices, "");
    let deadline = Instant::now() + Duration::from_secs(10);
    let loud = |log: &str| {
        log.lines().any(|l| {
            l.contains("ERROR") && l.contains("another gateway publishes under this topic root")
        })
    };
    while !(loud(&a.log_text()) && loud(&b.log_text())) && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        loud(&b.log_text()),
        "the second gateway says so:\n{}",
        b.log_text()
    );
    assert!(
        loud(&a.log_text()),
        "the first gateway says so:\n{}",
        a.log_text()
    );
}
