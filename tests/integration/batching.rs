//! `mqtt.batch`: the readings of several polls go to the broker together, never later than the
//! window; command results are never held.

use std::time::{Duration, Instant};

use serde_json::json;

use pulsegate::sim::Plant;

use crate::hostile::{KILLED_ENCODER, consume, stop_and_collect};
use crate::support::*;

const PLANT: &str = r#"
[buses.hall]
listen = "127.0.0.1:0"
[buses.hall.devices.yl]
unit = 1
model = "yl67"
channels.enc0 = { rate = 50.0 }
"#;

/// A gateway polling one YL67 every 50 ms with `mqtt.batch = batch`, and a subscriber.
async fn rig(name: &str, batch: &str) -> (Broker, Plant, Subscriber, Gateway) {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir(name);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [("hall", "yl", 1, "yl67", "50ms")];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "");
    let text = text.replacen("[mqtt]\n", &format!("[mqtt]\nbatch = {batch:?}\n"), 1);
    let gateway = Gateway::start(&write_config(&dir, &text));
    sub.expect_any("pulsegate/test/yl/enc0", Duration::from_secs(5))
        .await;
    (broker, plant, sub, gateway)
}

/// The arrivals of `enc0` readings over `window`, grouped into bursts (a gap of more than
/// `gap` starts a new one): (readings, bursts, longest gap between bursts).
async fn bursts(sub: &Subscriber, window: Duration, gap: Duration) -> (usize, usize, Duration) {
    sub.clear();
    tokio::time::sleep(window).await;
    let arrivals: Vec<Instant> = sub
        .on("pulsegate/test/yl/enc0")
        .iter()
        .map(|m| m.at)
        .collect();
    let gaps: Vec<Duration> = arrivals.windows(2).map(|w| w[1] - w[0]).collect();
    let bursts = 1 + gaps.iter().filter(|g| **g > gap).count();
    let longest = gaps.iter().copied().max().unwrap_or_default();
    (arrivals.len(), bursts, longest)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_of_several_polls_reach_the_broker_together_within_the_window() {
    let (_broker, _plant, sub, _gw) = rig("batch-1s", "1s").await;
    let (readings, n, longest) =
        bursts(&sub, Duration::from_secs(4), Duration::from_millis(300)).await;
    // A poll every 50 ms: some 80 readings in 4 s, in bursts of one window's polls.
    assert!(readings >= 30, "{readings} readings in 4 s");
    assert!(
        n <= 10,
        "{readings} readings came in {n} bursts: not held together"
    );
    // None waits longer than the window (1 s), plus the broker's and this machine's delays.
    assert!(
        longest < Duration::from_millis(1600),
        "{longest:?} between two bursts"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_batch_every_poll_reaches_the_broker_on_its_own() {
    let (_broker, _plant, sub, _gw) = rig("batch-0", "0s").await;
    let (readings, n, _) = bursts(&sub, Duration::from_secs(3), Duration::from_millis(20)).await;
    assert!(readings >= 20, "{readings} readings in 3 s");
    assert!(
        n * 2 >= readings,
        "{readings} readings in only {n} bursts: held without a batch"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_command_result_is_not_held_by_a_long_batch() {
    let (_broker, _plant, sub, _gw) = rig("batch-cmd", "5s").await;
    let sent = Instant::now();
    sub.send(
        "pulsegate/test/yl/enc0/cmd",
        json!({"op": "clear", "id": "b1"}).to_string(),
    )
    .await;
    let result = sub
        .wait_for(
            "pulsegate/test/yl/enc0/cmd/result",
            Duration::from_secs(5),
            |m| m.json()["id"] == "b1",
        )
        .await
        .expect("a result");
    assert_eq!(result.json()["ok"], json!(true), "{}", result.payload);
    assert!(
        result.at - sent < Duration::from_secs(2),
        "the result took {:?}: held with the readings",
        result.at - sent
    );
}

/// SIGKILL while readings are held for a long batch: the state saved before the kill records
/// seqs whose readings must have reached the broker (a save releases the batch first), so the
/// next run's `after_seq` never points past what a consumer has. Without that, the deltas of
/// the held readings would be gone with the process (the totals would still be right).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_crash_with_readings_held_loses_no_counted_pulse() {
    let broker = Broker::start();
    let plant = plant(KILLED_ENCODER).await;
    let dir = temp_dir("batch-kill");
    let topic = "pulsegate/test/m/a0";
    let sub = Subscriber::start(broker.port, topic).await;
    let devices = [("line1", "m", 1, "yl67", "50ms")];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "");
    // Saves every 500 ms (the test config's state_flush), a batch far longer.
    let text = text.replacen("[mqtt]\n", "[mqtt]\nbatch = \"5s\"\n", 1);
    let config = write_config(&dir, &text);
    let gw = Gateway::start(&config);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    gw.kill();
    let gw = Gateway::start(&config);
    let (all, generated) = stop_and_collect(&plant, &sub, gw, topic).await;
    let first_count = all[0]["count"].as_i64().unwrap();
    assert!(
        all.iter().any(|r| r["after_seq"].is_i64()),
        "the second run's first reading counts from the saved seq"
    );
    assert_eq!(consume(&all), generated - first_count, "summed deltas");
}
