//! The router without a broker or a bus: what it refuses, what it hands on.

use std::collections::HashMap;
use std::path::Path;

use tokio::sync::mpsc::{channel, unbounded_channel};

use super::*;

const CONFIG: &str = r#"
[gateway]
id = "e1"
[mqtt]
topic_root = "pg/e1"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.locked]
unit = 1
model = "yl67"
commands = false
[buses.line1.devices.open]
unit = 2
model = "yl67"
"#;

fn router() -> (
    Router,
    tokio::sync::mpsc::UnboundedReceiver<Output>,
    Receiver<ScanRequest>,
) {
    let config = Config::from_toml(
        CONFIG,
        Path::new("/etc/pulsegate.toml"),
        Some(HashMap::new()),
    )
    .unwrap();
    let (bus, _) = unbounded_channel();
    let buses = HashMap::from([("line1".to_string(), bus)]);
    let (out, results) = unbounded_channel();
    let router = Router::new(&config, &buses, out);
    let (scan_tx, scans) = channel(1);
    router
        .scans()
        .write()
        .unwrap()
        .insert("line1".into(), scan_tx);
    (router, results, scans)
}

fn message(topic: &str, payload: &str, response_topic: Option<&str>) -> Incoming {
    Incoming {
        topic: topic.into(),
        payload: Bytes::from(payload.to_string()),
        retain: false,
        response_topic: response_topic.map(Into::into),
        correlation: None,
        via: None,
    }
}

#[test]
fn a_scan_leaves_out_the_units_of_devices_with_commands_false() {
    let (router, _results, mut scans) = router();
    router.handle(message("pg/e1/bus/line1/scan", r#"{"units":"1-3"}"#, None));
    let request = scans.try_recv().expect("the scan goes to its bus");
    assert_eq!(
        request.units,
        [2, 3],
        "unit 1 (commands = false) is neither asked nor listed; unit 2 is listed as configured"
    );
}

#[test]
fn a_response_topic_into_the_gateways_own_topics_is_answered_on_the_result_topic_only() {
    let (router, mut results, mut scans) = router();
    for (topic, response) in [
        ("pg/e1/open/enc0/cmd", "pg/e1/status"),
        ("pg/e1/open/enc0/cmd", "pg/e1/open/status"),
        ("pg/e1/open/enc0/cmd", "pg/e1/open/enc1"),
        ("pg/e1/open/enc0/cmd", "homeassistant/status"),
        ("pg/e1/bus/line1/scan", "pg/e1/line1/status"),
    ] {
        router.handle(message(topic, r#"{"op":"clear"}"#, Some(response)));
        let Ok(Output::CommandResult { reply, .. }) = results.try_recv() else {
            panic!("{response}: refused at once, with a result");
        };
        assert_eq!(reply.topics, [format!("{topic}/result")], "{response}");
    }
    assert!(scans.try_recv().is_err(), "the refused scan went nowhere");
}
