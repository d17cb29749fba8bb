//! Edges a hostile or hurried world reaches (issue 23): response topics into the gateway's own
//! topics, a device undoing an inherited `min_interval`, scans and `commands = false`, reloads
//! and metric series, the state tools beside a running gateway, the spool's fallback, and a
//! broker that refuses MQTT 5.

use std::time::Duration;

use crate::support::{Broker, Gateway, Subscriber, gateway_toml, plant, temp_dir, write_config};

/// `[gateway] min_interval = "1s"`, a device with `publish = "poll"` and `min_interval = "0s"`:
/// that device publishes every poll, the other one still once a second.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_with_zero_min_interval_publishes_every_poll_under_a_paced_gateway() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.fast]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.line1.devices.paced]\nunit = 2\nmodel = \"yl67\"\n",
    )
    .await;
    let dir = temp_dir("zero-min-interval");
    let sub = Subscriber::start(broker.port, "pulsegate/test/+/enc0").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[
            ("line1", "fast", 1, "yl67", "200ms"),
            ("line1", "paced", 2, "yl67", "200ms"),
        ],
        "",
    )
    .replace("[gateway]\n", "[gateway]\nmin_interval = \"1s\"\n")
    .replace(
        "[buses.line1.devices.fast]\n",
        "[buses.line1.devices.fast]\npublish = \"poll\"\nmin_interval = \"0s\"\n",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    let (fast, paced) = ("pulsegate/test/fast/enc0", "pulsegate/test/paced/enc0");
    sub.expect_any(fast, Duration::from_secs(10)).await;
    sub.clear();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let (f, p) = (sub.on(fast).len(), sub.on(paced).len());
    // 20 polls in 4 s: every one published; the paced device at most one a second.
    assert!(f >= 15, "the 0s device publishes every poll: {f} in 4 s");
    assert!((2..=5).contains(&p), "the inherited 1s still paces the other: {p}");
}
