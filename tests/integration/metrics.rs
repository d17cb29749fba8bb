//! The Prometheus endpoint during a bad hour: a module goes silent and the broker stops. The
//! scrape must show it (device up 0, MQTT connected 0, the spool growing) and pass promtool.

use std::io::{Read, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::support::*;

/// `GET path` over plain HTTP/1.1; returns (status, body).
pub(crate) fn http_get(port: u16, path: &str) -> (u16, String) {
    let Ok(mut s) = std::net::TcpStream::connect(("127.0.0.1", port)) else {
        return (0, String::new()); // not listening (yet)
    };
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = text.split_once("\r\n\r\n").map(|(_, b)| b).unwrap_or("");
    (status, body.to_string())
}

/// The value of the sample `series` (name with labels, exactly as exposed).
pub(crate) fn sample(text: &str, series: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(series)?.strip_prefix(' ')?.parse().ok())
}

/// Scrapes until `pred` holds on the exposition; returns that exposition.
pub(crate) async fn scrape_until(
    port: u16,
    timeout: Duration,
    what: &str,
    pred: impl Fn(&str) -> bool,
) -> String {
    let deadline = Instant::now() + timeout;
    loop {
        let last = tokio::task::spawn_blocking(move || http_get(port, "/metrics").1)
            .await
            .unwrap();
        if pred(&last) {
            return last;
        }
        assert!(Instant::now() < deadline, "{what}; last scrape:\n{last}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

fn promtool_check(exposition: &str) {
    let mut child = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("promtool is not installed: run the README's test command (scripts/test), which installs it");
    child
        .stdin
        .take()
        .unwrap()
        .write_all(exposition.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "promtool check metrics: {}{}\n{exposition}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

const UP_A: &str = "pulsegate_device_up{bus=\"line1\",device=\"a\"}";
const UP_B: &str = "pulsegate_device_up{bus=\"line1\",device=\"b\"}";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_show_a_silent_module_and_a_stopped_broker_and_pass_promtool() {
    let mut broker = Broker::start();
    let plant = plant(
        r#"
[buses.line1.devices.a]
unit = 1
model = "yl67"
modes = [1, 1, 1, 1]
channels.a0 = { rate = 100.0 }
[buses.line1.devices.b]
unit = 2
model = "wj157"
channels.enc0 = { rate = -50.0 }
"#,
    )
    .await;
    let dir = temp_dir("metrics");
    let port = free_port();
    let devices = [
        ("line1", "a", 1, "yl67", "200ms"),
        ("line1", "b", 2, "wj157", "200ms"),
    ];
    let extra = format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n");
    let gw = start_gateway(&plant, broker.port, &dir, &devices, &extra);

    let healthy = scrape_until(
        port,
        Duration::from_secs(10),
        "both devices up, MQTT connected",
        |t| {
            sample(t, UP_A) == Some(1.0)
                && sample(t, UP_B) == Some(1.0)
                && sample(t, "pulsegate_mqtt_connected{output=\"json\"}") == Some(1.0)
                && sample(
                    t,
                    "pulsegate_channel_pulses_total{bus=\"line1\",channel=\"a0\",device=\"a\"}",
                )
                .is_some_and(|v| v > 0.0)
        },
    )
    .await;
    assert!(
        sample(
            &healthy,
            "pulsegate_channel_position_pulses{bus=\"line1\",channel=\"enc0\",device=\"b\"}"
        )
        .is_some(),
        "{healthy}"
    );
    assert!(healthy.contains(
        "pulsegate_device_latency_seconds_bucket{bus=\"line1\",device=\"a\",le=\"0.1\"}"
    ));
    let (status, body) = http_get(port, "/healthz");
    assert_eq!(status, 200, "{body}");

    plant
        .with_module("line1", 2, |m, _| m.silent = true)
        .unwrap();
    broker.stop();
    let first = scrape_until(
        port,
        Duration::from_secs(10),
        "b down and MQTT disconnected",
        |t| {
            sample(t, UP_B) == Some(0.0)
                && sample(t, "pulsegate_mqtt_connected{output=\"json\"}") == Some(0.0)
        },
    )
    .await;
    assert_eq!(sample(&first, UP_A), Some(1.0), "the other device stays up");
    let depth = sample(&first, "pulsegate_spool_messages{output=\"json\"}").unwrap();
    let during = scrape_until(
        port,
        Duration::from_secs(10),
        "the spool grows while the broker is away",
        |t| {
            sample(t, "pulsegate_spool_messages{output=\"json\"}").is_some_and(|d| d > depth)
                && sample(t, "pulsegate_spool_bytes{output=\"json\"}").is_some_and(|b| b > 0.0)
        },
    )
    .await;
    assert!(
        sample(
            &during,
            "pulsegate_device_timeouts_total{bus=\"line1\",device=\"b\"}"
        )
        .is_some_and(|v| v > 0.0),
        "{during}"
    );
    promtool_check(&during);

    let (status, _) = http_get(port, "/nothing");
    assert_eq!(status, 404);
    // Hostile clients cost little and break nothing: garbage, an endless header, idle sockets.
    let junk = |bytes: Vec<u8>| {
        let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let _ = s.write_all(&bytes);
        let mut answer = Vec::new();
        let _ = s.read_to_end(&mut answer);
        String::from_utf8_lossy(&answer).into_owned()
    };
    assert!(!junk(b"\x00\xff garbage\r\n\r\n".to_vec()).contains(" 200 "));
    let mut long = b"GET /metrics HTTP/1.1\r\nX: ".to_vec();
    long.resize(100_000, b'a');
    assert!(!junk(long).contains(" 200 "));
    let idle: Vec<_> = (0..20)
        .map(|_| std::net::TcpStream::connect(("127.0.0.1", port)).unwrap())
        .collect();
    drop(idle);
    let (status, body) = http_get(port, "/metrics");
    assert_eq!(status, 200, "still serving after hostile clients");
    assert!(body.contains("pulsegate_build_info"));
    drop(gw);
}

#[test]
fn a_metrics_listen_address_that_is_not_one_is_a_config_error() {
    let dir = temp_dir("metrics-bad");
    let config = write_config(
        &dir,
        "[mqtt]\nport = 1883\n[metrics]\nlisten = \"localhost\"\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n",
    );
    let out = Command::new(bin())
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("metrics.listen") && err.contains("not an IP address and port"),
        "{err}"
    );
}
