//! First release: config → buses → decoded readings → MQTT.

use std::time::{Duration, Instant};

use crate::protocol::Protocol;
use crate::support::*;

const PLANT: &str = r#"
[buses.line1.devices.press]
unit = 1
model = "yl67"
modes = [0, 1, 0, 0]
channels.enc0 = { count = -13680 }
channels.a1 = { count = 4294953616 }
[buses.line1.devices.spindle]
unit = 2
model = "wj157"
modes = [0]
channels.enc0 = { rate = 1234.5, ppr = 500 }
[buses.line2.devices.doors]
unit = 7
model = "zh-yx1600"
channels.di1 = { count = 100000 }
[buses.hall]
listen = "127.0.0.1:0"
[buses.hall.devices.gates]
unit = 1
model = "zh-yx1600"
channels.di5 = { count = 100000 }
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_model_publishes_its_decoded_values_within_two_seconds() {
    each_model_publishes_its_decoded_values(Protocol::V5).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_model_publishes_its_decoded_values_over_mqtt_3_1_1() {
    each_model_publishes_its_decoded_values(Protocol::V311).await;
}

/// Readings, availability and the last will, on either protocol.
async fn each_model_publishes_its_decoded_values(protocol: Protocol) {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("pipeline");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "press", 1, "yl67", "200ms"),
        ("line1", "spindle", 2, "wj157", "200ms"),
        ("line2", "doors", 7, "zh-yx1600", "200ms"),
        ("hall", "gates", 1, "zh-yx1600", "200ms"),
    ];
    let side = protocol.side(broker.port);
    let config = write_config(&dir, &side.config(&plant, &dir, &devices, ""));
    let started = Instant::now();
    let gw = Gateway::start(&config);

    let within = Duration::from_secs(2);
    let enc0 = sub
        .wait_for("pulsegate/test/press/enc0", within, |m| {
            m.json()["count"] == -13680
        })
        .await;
    assert!(
        enc0.is_some(),
        "YL67 encoder 0 holding -13680 was not published within 2 s"
    );
    let elapsed = enc0.unwrap().at - started;
    assert!(elapsed <= within, "took {elapsed:?}");

    let a1 = sub
        .wait_for("pulsegate/test/press/a1", within, |m| {
            m.json()["count"] == 4_294_953_616u64
        })
        .await;
    assert!(
        a1.is_some(),
        "the same raw words on an input counting on its own must read 4294953616"
    );

    for topic in ["pulsegate/test/doors/di1", "pulsegate/test/gates/di5"] {
        let m = sub
            .wait_for(topic, within, |m| m.json()["count"] == 100_000)
            .await;
        assert!(
            m.is_some(),
            "{topic}: ZH-YX1600 words 0x0001 0x86A0 must publish 100000"
        );
    }

    let spindle = sub
        .wait_for("pulsegate/test/spindle/enc0", within, |m| {
            m.json()["freq_hz"].is_f64()
        })
        .await
        .expect("WJ157 encoder frequency published");
    let v = spindle.json();
    assert_eq!(v["freq_hz"], 1234.5);
    assert_eq!(v["rpm"], 1234.5 * 60.0 / 500.0);
    assert!(v["ts"].as_str().unwrap().ends_with('Z'));

    let status = sub
        .wait_for("pulsegate/test/status", within, |m| m.payload == "online")
        .await;
    assert!(status.is_some(), "gateway status online");
    let status = sub
        .wait_for("pulsegate/test/press/status", within, |m| {
            m.payload == "online"
        })
        .await;
    assert!(status.is_some(), "device status online");
    // A subscriber arriving later gets the device status from the broker: it is retained.
    let late = Subscriber::start(broker.port, "pulsegate/test/press/status").await;
    let retained = late
        .wait_for("pulsegate/test/press/status", within, |m| m.retain)
        .await;
    assert_eq!(retained.expect("retained device status").payload, "online");

    // Killed without a word: the broker publishes the gateway's last will.
    sub.clear();
    gw.kill();
    let will = sub
        .wait_for("pulsegate/test/status", Duration::from_secs(5), |m| {
            m.payload == "offline"
        })
        .await;
    assert!(
        will.is_some(),
        "the last will (gateway offline) over {protocol:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_module_goes_offline_and_the_others_keep_their_poll_rate() {
    let broker = Broker::start();
    let plant = plant(
        r#"
[buses.line1.devices.a]
unit = 1
model = "yl67"
[buses.line1.devices.b]
unit = 2
model = "wj157"
[buses.line1.devices.c]
unit = 3
model = "zh-yx1600"
"#,
    )
    .await;
    let dir = temp_dir("silent");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "a", 1, "yl67", "200ms"),
        ("line1", "b", 2, "wj157", "200ms"),
        ("line1", "c", 3, "zh-yx1600", "200ms"),
    ];
    let _gw = start_gateway(&plant, broker.port, &dir, &devices, "");
    for d in ["a", "b", "c"] {
        let topic = format!("pulsegate/test/{d}/status");
        assert!(
            sub.wait_for(&topic, Duration::from_secs(3), |m| m.payload == "online")
                .await
                .is_some()
        );
    }

    plant
        .with_module("line1", 2, |m, _| m.silent = true)
        .unwrap();
    let offline = sub
        .wait_for("pulsegate/test/b/status", Duration::from_secs(5), |m| {
            m.payload == "offline"
        })
        .await;
    assert!(
        offline.is_some(),
        "the silent module's status must turn offline"
    );

    sub.clear();
    let window = Duration::from_secs(3);
    tokio::time::sleep(window).await;
    let expected = window.as_secs_f64() / 0.2;
    for topic in ["pulsegate/test/a/enc0", "pulsegate/test/c/di1"] {
        let n = sub.on(topic).len() as f64;
        // Functional check with room for a loaded CI machine; the benchmark measures the ratio.
        assert!(
            n >= expected * 0.75,
            "{topic}: {n} readings in {window:?}, expected about {expected}"
        );
    }
    assert!(
        sub.on("pulsegate/test/b/enc0").is_empty(),
        "no readings from the silent module"
    );
}

#[test]
fn a_broken_config_exits_non_zero_and_names_every_error() {
    let dir = temp_dir("badconfig");
    let config = write_config(
        &dir,
        r#"
[gateway]
id = "test"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.press]
unit = 1
model = "yl67"
pol = "1s"
[buses.line1.devices.other]
unit = 1
model = "wj157"
poll = "fast"
"#,
    );
    let out = std::process::Command::new(bin())
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("buses.line1.devices.press.pol: unknown key"),
        "{err}"
    );
    assert!(
        err.contains(".unit: unit 1 is already used by device"),
        "{err}"
    );
    assert!(
        err.contains("buses.line1.devices.other.poll") && err.contains("fast"),
        "{err}"
    );
    assert!(
        err.contains(&config.display().to_string()),
        "errors name the file: {err}"
    );
}

#[test]
fn check_prints_the_poll_plan_of_a_valid_config() {
    let dir = temp_dir("goodconfig");
    let config = write_config(
        &dir,
        r#"
[buses.line1]
port = "/dev/ttyUSB0"
baud = 9600
[buses.line1.devices.press]
unit = 1
model = "yl67"
poll = "500ms"
"#,
    );
    let out = std::process::Command::new(bin())
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("press") && text.contains("2 request(s) [16+8, 128+8]"),
        "{text}"
    );
    assert!(text.contains("ms on the line"), "{text}");
}

#[test]
fn the_demo_shows_live_readings_of_every_model() {
    let broker = Broker::start();
    let out = std::process::Command::new(bin())
        .args([
            "demo",
            "--mqtt",
            &format!("127.0.0.1:{}", broker.port),
            "--duration",
            "5s",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    // The last table drawn: rows for the YL67, IBF67, both WJ157s and the ZH-YX1600 on TCP,
    // and the M-Bus heat meter's register and a value of it.
    let last = text.rsplit("pulsegate demo: readings").next().unwrap();
    for row in [
        "press1/enc0",
        "press1/a2",
        "spindle/enc0",
        "conveyor/enc3",
        "bottles/a0",
        "doors/di1",
        "heat1/energy",
        "heat1/flow_temperature",
    ] {
        assert!(last.contains(row), "no {row} in the live table:\n{last}");
    }
    assert!(
        last.contains("press1/status=online") && last.contains("doors/status=online"),
        "{last}"
    );
}
