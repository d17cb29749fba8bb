//! A local broker over a Unix domain socket (`mqtt.socket`): readings reach a subscriber on
//! the same broker's TCP listener, and a socket that is not there yet is an outage like any
//! other (polling goes on, readings are spooled, delivered once it appears).

use std::path::Path;
use std::time::{Duration, Instant};

use pulsegate::sim::Plant;

use crate::support::*;

const PLANT: &str =
    "[buses.line1.devices.press]\nunit = 1\nmodel = \"yl67\"\nchannels.enc0 = { rate = 100.0 }\n";
const DEVICES: [(&str, &str, u8, &str, &str); 1] = [("line1", "press", 1, "yl67", "200ms")];
const TOPIC: &str = "pulsegate/test/press/enc0";

/// Gateway config that names `socket` and a TCP port nothing listens on: a reading that
/// arrives can only have come over the socket.
fn socket_config(plant: &Plant, dir: &Path, socket: &Path, mqtt: &str) -> String {
    let mqtt = format!("socket = {:?}\n{mqtt}", socket.display().to_string());
    pulsegate::sim::gateway::GatewayToml {
        id: "test",
        state_dir: dir,
        gateway: "state_flush = \"500ms\"\n",
        mqtt_host: "127.0.0.1",
        mqtt_port: Some(free_port()),
        mqtt: &mqtt,
        serial: "baud = 115200\ntimeout = \"100ms\"\nbackoff_min = \"500ms\"\nbackoff_max = \"2s\"\n",
        tcp: "timeout = \"100ms\"\n",
    }
    .render(plant, &DEVICES)
}

/// The `seq` of each reading on `TOPIC`, in arrival order.
fn seqs(sub: &Subscriber) -> Vec<u64> {
    readings(sub, TOPIC)
        .iter()
        .map(|r| r["seq"].as_u64().expect("seq"))
        .collect()
}

async fn readings_arrive_over_the_socket(mqtt: &str) {
    let dir = temp_dir("socket");
    let socket = dir.join("run").join("mqtt.sock");
    let broker = Broker::start_with_socket(free_port(), &socket);
    let plant = plant(PLANT).await;
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&write_config(
        &dir,
        &socket_config(&plant, &dir, &socket, mqtt),
    ));

    let enc0 = sub
        .wait_for(TOPIC, Duration::from_secs(5), |m| {
            m.json()["count"].is_i64()
        })
        .await;
    assert!(enc0.is_some(), "no reading over the socket within 5 s");
    let status = sub
        .wait_for("pulsegate/test/status", Duration::from_secs(2), |m| {
            m.payload == "online"
        })
        .await;
    assert!(status.is_some(), "gateway status online");
    let log = gw.log_text();
    assert!(
        log.contains("connected to MQTT broker") && log.contains(&socket.display().to_string()),
        "the log names the socket: {log}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_on_a_unix_socket_publishes_readings_a_tcp_subscriber_receives() {
    readings_arrive_over_the_socket("").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_on_a_unix_socket_publishes_readings_over_mqtt_3_1_1() {
    readings_arrive_over_the_socket("protocol = \"3.1.1\"").await;
}

/// The broker is up (its socket under another name, so the subscriber is listening before
/// the gateway can connect); the configured path appears after a few seconds, as it does
/// when Mosquitto starts after the gateway.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_socket_not_there_yet_is_an_outage_readings_are_spooled_and_delivered() {
    let dir = temp_dir("socket-late");
    let real = dir.join("run").join("broker.sock");
    let socket = dir.join("run").join("mqtt.sock");
    let broker = Broker::start_with_socket(free_port(), &real);
    let plant = plant(PLANT).await;
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&write_config(
        &dir,
        &socket_config(&plant, &dir, &socket, ""),
    ));

    let away = Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert!(sub.on(TOPIC).is_empty(), "nothing can arrive yet");
    let log = gw.log_text();
    assert!(
        log.contains("MQTT broker unreachable") && log.contains(&socket.display().to_string()),
        "the outage is logged naming the socket: {log}"
    );
    std::fs::rename(&real, &socket).unwrap();
    let away = away.elapsed();

    let after = Instant::now() + Duration::from_secs(1);
    let fresh = sub
        .wait_for(TOPIC, Duration::from_secs(15), |m| m.at > after)
        .await;
    assert!(fresh.is_some(), "readings once the socket is there");
    let seqs = seqs(&sub);
    for w in seqs.windows(2) {
        assert_eq!(w[1], w[0] + 1, "seq contiguous, in order: {seqs:?}");
    }
    // Polled every 200 ms while the socket was missing: every one of those was spooled.
    let due = (away.as_secs_f64() / 0.2) as usize;
    assert!(
        seqs.len() > due,
        "{} readings delivered, {due} were taken while the socket was missing",
        seqs.len()
    );
    assert!(
        seqs[0] <= 1,
        "the first reading ever taken arrives: {seqs:?}"
    );
    assert_eq!(
        gw.log_text().matches("MQTT broker unreachable").count(),
        1,
        "logged once, not per retry"
    );
}
