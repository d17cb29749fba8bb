//! One message larger than the gateway takes (issue 38): on a command topic, retained before
//! the gateway starts and sent again while it runs, by an MQTT 3.1.1 client (`mosquitto_pub`,
//! as an MES or Home Assistant would). Over MQTT 3.1.1 the broker sends it (it cannot be told
//! a limit): the gateway skips it, acknowledges it, counts it and says so once, and stays
//! connected. Over MQTT 5 the CONNECT announces the limit and the broker does not send it at
//! all. On both, readings flow without a gap, and a 70 KB message (under the 256 KiB the
//! gateway takes, over the 64 KiB it took before) arrives and is answered or ignored as a
//! command is.
//!
//! Real time, a real broker: what is tested is what Mosquitto sends and what the gateway's
//! connection survives.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use crate::metrics::{sample, scrape_until};
use crate::protocol::Protocol;
use crate::support::*;

const ONE_ENCODER: &str = r#"
[buses.line1.devices.d]
unit = 1
model = "yl67"
channels.enc0 = { rate = 100.0 }
"#;

const READING: &str = "pulsegate/test/d/enc0";
/// A channel's command topic: the 300 KiB message goes here.
const CHANNEL_CMD: &str = "pulsegate/test/d/enc0/cmd";
/// The device's command topic: the 70 KB message goes here.
const DEVICE_CMD: &str = "pulsegate/test/d/cmd";
const DROPPED: &str = "pulsegate_mqtt_messages_dropped_total{output=\"json\",reason=\"too_large\"}";

/// A command of `size` bytes (a clear, padded) sent with `mosquitto_pub` over MQTT 3.1.1 at
/// QoS 1.
fn mosquitto_pub(port: u16, dir: &Path, topic: &str, size: usize, retain: bool) {
    let file = dir.join(format!("payload-{size}"));
    let pad = "p".repeat(size - 21);
    std::fs::write(&file, format!(r#"{{"op":"clear","p":"{pad}"}}"#)).unwrap();
    let mut args = vec!["-h", "127.0.0.1", "-V", "mqttv311", "-q", "1", "-t", topic];
    if retain {
        args.push("-r");
    }
    let port = port.to_string();
    let ok = Command::new("mosquitto_pub")
        .args(&args)
        .args(["-p", &port, "-f"])
        .arg(&file)
        .status()
        .expect("mosquitto_pub (scripts/test installs mosquitto-clients)");
    assert!(ok.success(), "mosquitto_pub {topic}");
}

/// The longest wait between two readings that arrived after `since`.
fn longest_gap(sub: &Subscriber, since: Instant) -> Duration {
    let at: Vec<Instant> = sub
        .on(READING)
        .iter()
        .map(|m| m.at)
        .filter(|t| *t >= since)
        .collect();
    at.windows(2)
        .map(|w| w[1] - w[0])
        .max()
        .unwrap_or(Duration::MAX)
}

async fn a_message_larger_than_the_gateway_takes_costs_only_itself(protocol: Protocol) {
    let broker = Broker::start();
    let side = protocol.side(broker.port);
    let plant = plant(ONE_ENCODER).await;
    let dir = temp_dir("big-messages");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    mosquitto_pub(broker.port, &dir, CHANNEL_CMD, 300 * 1024, true);
    mosquitto_pub(broker.port, &dir, DEVICE_CMD, 70 * 1000, true);
    let metrics = free_port();
    let extra = format!("[metrics]\nlisten = \"127.0.0.1:{metrics}\"\n");
    let gw = side.start_gateway(&plant, &dir, &[("line1", "d", 1, "yl67", "100ms")], &extra);
    sub.expect_any(READING, Duration::from_secs(5)).await;
    let since = Instant::now();
    tokio::time::sleep(Duration::from_secs(1)).await;
    // Again while it runs, not retained; the 70 KB one behind it is answered as too large
    // for a command: when its answer is there, the large one has come and gone.
    mosquitto_pub(broker.port, &dir, CHANNEL_CMD, 300 * 1024, false);
    mosquitto_pub(broker.port, &dir, DEVICE_CMD, 70 * 1000, false);
    let answer = sub
        .wait_for(
            &format!("{DEVICE_CMD}/result"),
            Duration::from_secs(5),
            |m| m.json()["error"] == "too_large",
        )
        .await;
    let log = gw.log_text();
    assert!(answer.is_some(), "the 70 KB command is answered:\n{log}");
    tokio::time::sleep(Duration::from_secs(2)).await;
    let gap = longest_gap(&sub, since);
    let log = gw.log_text();
    assert!(
        gap < Duration::from_millis(800),
        "readings without a gap ({gap:?}):\n{log}"
    );
    assert!(
        !log.contains("MQTT broker unreachable"),
        "no reconnect:\n{log}"
    );
    assert_eq!(
        log.matches("connected to MQTT broker").count(),
        1,
        "one connection:\n{log}"
    );
    let said = log.matches("dropped an MQTT message of").count();
    let exposition = scrape_until(metrics, Duration::from_secs(5), "metrics", |t| {
        t.contains("pulsegate_mqtt_connected{output=\"json\"} 1")
    })
    .await;
    let dropped = sample(&exposition, DROPPED);
    match protocol {
        Protocol::V311 => {
            assert_eq!(
                dropped,
                Some(2.0),
                "the retained one and the live one:\n{exposition}"
            );
            assert_eq!(said, 1, "said once a minute, the rest counted:\n{log}");
            assert!(log.contains("ignoring a retained command message"), "{log}");
        }
        Protocol::V5 => {
            // The CONNECT announced 260 KiB: Mosquitto never sent the large one.
            assert_eq!(dropped, None, "{exposition}");
            assert_eq!(said, 0, "{log}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_mqtt_3_1_1_a_message_larger_than_the_gateway_takes_is_dropped_and_counted_and_the_connection_stays()
 {
    a_message_larger_than_the_gateway_takes_costs_only_itself(Protocol::V311).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_mqtt_5_the_broker_is_told_the_largest_message_the_gateway_takes_and_keeps_larger_ones()
 {
    a_message_larger_than_the_gateway_takes_costs_only_itself(Protocol::V5).await;
}
