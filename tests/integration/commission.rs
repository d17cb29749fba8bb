//! Commissioning from the command line (issue 14): the `pulsegate` binary against the simulator
//! on real pseudo-terminals, and the gateway it configures against a real Mosquitto.
//!
//! Modules at two baud rates share one pseudo-terminal: a simulated module answers only while
//! the line is set to its own rate (see `sim::comm`).

use std::path::Path;
use std::process::Output;
use std::time::Duration;

use pulsegate::sim::Endpoint;

use crate::support::*;

/// Runs `pulsegate ARGS` to the end.
async fn pg(args: &[&str]) -> Output {
    tokio::process::Command::new(bin())
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .await
        .expect("run pulsegate")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

fn port_of(plant: &pulsegate::sim::Plant, bus: &str) -> String {
    match &plant.bus(bus).unwrap().endpoint {
        Endpoint::Serial(p) => p.display().to_string(),
        Endpoint::Tcp(_) => unreachable!("serial bus"),
    }
}

/// Five modules of three models at scattered unit ids; two answer at 19200, three at 9600.
const MIXED_LINE: &str = r#"
[buses.line.devices.press]
unit = 1
model = "yl67"
baud = 9600
modes = [0, 1, 0, 0]
channels.enc0 = { count = -13680 }
channels.a1 = { count = 4294953616 }
[buses.line.devices.doors]
unit = 3
model = "zh-yx1600"
baud = 9600
channels.di1 = { count = 100000 }
[buses.line.devices.spindle]
unit = 17
model = "wj157"
baud = 19200
modes = [1]
channels.a0 = { count = 4242 }
[buses.line.devices.feeder]
unit = 42
model = "ibf67"
baud = 19200
channels.enc3 = { count = -5 }
[buses.line.devices.saw]
unit = 200
model = "wj157"
baud = 9600
channels.enc0 = { count = 777 }
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scan_all_bauds_finds_five_mixed_modules_and_its_config_publishes_all_five() {
    let plant = plant(MIXED_LINE).await;
    let port = port_of(&plant, "line");
    // Units 1-50 and 195-205 at all seven rates, with a short answer time to keep the test
    // short (a full 1-247 scan is measured for the README instead).
    let scan = pg(&[
        "scan",
        "--port",
        &port,
        "--baud",
        "all",
        "--units",
        "1-50,195-205",
        "--timeout",
        "30ms",
        "--toml",
    ])
    .await;
    let (toml_text, progress) = text(&scan);
    assert!(scan.status.success(), "{progress}");
    let found: toml::Value = toml::from_str(&toml_text).expect("the snippet is TOML");
    let devices = found["buses"]["line1"]["devices"].as_table().unwrap();
    let mut seen: Vec<(i64, String, Option<i64>)> = devices
        .values()
        .map(|d| {
            (
                d["unit"].as_integer().unwrap(),
                d["model"].as_str().unwrap().to_string(),
                d.get("baud").and_then(|b| b.as_integer()),
            )
        })
        .collect();
    seen.sort();
    assert_eq!(
        seen,
        [
            (1, "yl67".into(), None),
            (3, "zh-yx1600".into(), None),
            (17, "wj157".into(), Some(19200)),
            (42, "yl67".into(), Some(19200)),
            (200, "wj157".into(), None),
        ],
        "{toml_text}"
    );
    assert_eq!(found["buses"]["line1"]["baud"].as_integer(), Some(9600));
    assert!(
        progress.contains("scanning 61 units at 115200 baud"),
        "{progress}"
    );

    let dir = temp_dir("commission-scan");
    let config = dir.join("scanned.toml");
    std::fs::write(&config, &toml_text).unwrap();
    let check = pg(&["check", "--config", config.to_str().unwrap()]).await;
    assert!(check.status.success(), "{:?}", text(&check));

    // Run as is: only the broker's port and the state directory come from the environment.
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port, "pulsegate/scanned/#").await;
    let _gw = RunningGateway::start(&config, broker.port, &dir);
    for (topic, count) in [
        ("yl67-1/enc0", -13680i64),
        ("yl67-1/a1", 4_294_953_616),
        ("zh-yx1600-3/di1", 100_000),
        ("wj157-17/a0", 4242),
        ("yl67-42/enc3", -5),
        ("wj157-200/enc0", 777),
    ] {
        let topic = format!("pulsegate/scanned/{topic}");
        let m = sub
            .wait_for(&topic, Duration::from_secs(10), |m| {
                m.json()["count"] == count
            })
            .await;
        assert!(m.is_some(), "{topic} did not publish {count}");
    }
}

/// The gateway started on a file as written, with the broker port, state directory and id
/// from the environment.
struct RunningGateway(std::process::Child);

impl RunningGateway {
    fn start(config: &Path, broker: u16, dir: &Path) -> RunningGateway {
        let child = std::process::Command::new(bin())
            .args(["run", "--config"])
            .arg(config)
            .env("PULSEGATE__MQTT__PORT", broker.to_string())
            .env("PULSEGATE__GATEWAY__STATE_DIR", dir.join("state"))
            .env("PULSEGATE__GATEWAY__ID", "scanned")
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(dir.join("gateway.log")).unwrap())
            .spawn()
            .unwrap();
        RunningGateway(child)
    }
}

impl Drop for RunningGateway {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

const FACTORY_LINE: &str = r#"
[buses.line.devices.new_yl67]
unit = 1
model = "yl67"
baud = 9600
channels.enc0 = { count = 31 }
[buses.line.devices.zh]
unit = 3
model = "zh-yx1600"
baud = 9600
channels.di1 = { rate = 200.0 }
[buses.line.devices.wj]
unit = 5
model = "wj157"
baud = 9600
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn setup_new_unit_is_read_back_and_taken_at_the_power_cycle_the_datasheet_asks_for() {
    let plant = plant(FACTORY_LINE).await;
    let port = port_of(&plant, "line");

    // YL67: 40201 "重启后生效" (after a restart): read back at unit 1, answers at 7 only after.
    let setup = pg(&[
        "setup",
        "--port",
        &port,
        "--unit",
        "1",
        "--new-unit",
        "7",
        "--yes",
    ])
    .await;
    let (out, err) = text(&setup);
    assert!(setup.status.success(), "{err}");
    assert!(
        out.contains("answers at unit 7 after its next power-up"),
        "{out}"
    );
    let raw = pg(&["raw", "--port", &port, "--unit", "1", "read", "200"]).await;
    assert!(text(&raw).0.contains("0x0007"), "{:?}", text(&raw));
    assert!(
        !pg(&["read", "--port", &port, "--unit", "7"])
            .await
            .status
            .success()
    );
    assert_eq!(plant.power_cycle("line", 1).unwrap(), 7);
    let read = pg(&["read", "--port", &port, "--unit", "7", "--json"]).await;
    assert!(read.status.success(), "{:?}", text(&read));
    let v: serde_json::Value = serde_json::from_slice(&read.stdout).unwrap();
    assert_eq!(
        (v["model"].as_str(), v["unit"].as_u64()),
        (Some("yl67"), Some(7))
    );
    assert!(
        !pg(&["read", "--port", &port, "--unit", "1"])
            .await
            .status
            .success()
    );

    // ZH-YX1600: "返回数据后, 后续就必须用 02 设备地址来进行通讯": at once, read back at the new id.
    let setup = pg(&[
        "setup",
        "--port",
        &port,
        "--unit",
        "3",
        "--new-unit",
        "4",
        "--yes",
    ])
    .await;
    let (out, err) = text(&setup);
    assert!(setup.status.success(), "{err}");
    assert!(
        out.contains("read back at unit 4") && out.contains("from now on"),
        "{out}"
    );

    // WJ157 baud rate, after a restart: still 9600 until the power cycle, then 19200 only.
    let setup = pg(&[
        "setup",
        "--port",
        &port,
        "--unit",
        "5",
        "--new-baud",
        "19200",
        "--yes",
    ])
    .await;
    assert!(setup.status.success(), "{:?}", text(&setup));
    assert!(
        text(&setup)
            .0
            .contains("answers at 19200 baud after its next power-up")
    );
    assert!(
        pg(&["read", "--port", &port, "--unit", "5"])
            .await
            .status
            .success()
    );
    plant.power_cycle("line", 5).unwrap();
    assert!(
        !pg(&["read", "--port", &port, "--unit", "5"])
            .await
            .status
            .success()
    );
    let at_19200 = pg(&["read", "--port", &port, "--unit", "5", "--baud", "19200"]).await;
    assert!(at_19200.status.success(), "{:?}", text(&at_19200));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_json_matches_what_the_gateway_publishes_for_the_same_module() {
    let plant = plant(
        r#"
[buses.line.devices.press]
unit = 9
model = "yl67"
modes = [0, 1, 0, 0]
channels.enc0 = { count = -13680 }
channels.a1 = { count = 4294953616 }
channels.enc2 = { count = 5, rate = 0, ppr = 500 }
[buses.line.devices.zh]
unit = 2
model = "zh-yx1600"
channels.di5 = { count = 100000 }
"#,
    )
    .await;
    let port = port_of(&plant, "line");
    let mut by_cli = Vec::new();
    for unit in ["9", "2"] {
        let read = pg(&[
            "read", "--port", &port, "--baud", "115200", "--unit", unit, "--json",
        ])
        .await;
        assert!(read.status.success(), "{:?}", text(&read));
        by_cli.push(serde_json::from_slice::<serde_json::Value>(&read.stdout).unwrap());
    }
    assert_eq!(by_cli[0]["channels"]["enc2"]["ppr"], 500);

    let broker = Broker::start();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let dir = temp_dir("commission-read");
    let _gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[
            ("line", "press", 9, "yl67", "200ms"),
            ("line", "zh", 2, "zh-yx1600", "200ms"),
        ],
        "",
    );
    for (device, read) in [("press", &by_cli[0]), ("zh", &by_cli[1])] {
        let channels = read["channels"].as_object().unwrap();
        assert!(channels.len() >= 5, "{read}");
        for (name, ch) in channels {
            let topic = format!("pulsegate/test/{device}/{name}");
            let published = sub
                .wait_for(&topic, Duration::from_secs(5), |_| true)
                .await
                .unwrap_or_else(|| panic!("{topic} not published"))
                .json();
            for key in ["count", "freq_hz", "rpm"] {
                assert_eq!(published.get(key), ch.get(key), "{topic} {key}");
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_held_by_a_running_gateway_names_its_process() {
    let plant = plant(FACTORY_LINE).await;
    let port = port_of(&plant, "line");
    let broker = Broker::start();
    let dir = temp_dir("commission-held");
    let gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line", "wj", 5, "wj157", "1s")],
        "",
    );
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    loop {
        let scan = pg(&["scan", "--port", &port, "--units", "1-5"]).await;
        let (_, err) = text(&scan);
        if err.contains(&format!("process {}", gw.pid())) {
            assert!(!scan.status.success());
            assert!(
                err.contains("pulsegate run") && err.contains("stop it first"),
                "{err}"
            );
            break;
        }
        assert!(std::time::Instant::now() < deadline, "not named: {err}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_is_refused_before_anything_is_written() {
    let plant = plant(FACTORY_LINE).await;
    let port = port_of(&plant, "line");
    let refused: [(&[&str], &str); 9] = [
        (
            &["setup", "--unit", "1", "--new-unit", "248", "--yes"],
            "1..=247",
        ),
        (
            &["setup", "--unit", "1", "--new-unit", "5", "--yes"],
            "unit 5 already answers",
        ),
        (
            &["setup", "--unit", "1", "--new-baud", "14400", "--yes"],
            "not one of",
        ),
        (
            &["setup", "--unit", "1", "--power-on", "up", "--yes"],
            "no setting \"power_on\"",
        ),
        (
            &["setup", "--unit", "1", "--ppr", "enc0=0", "--yes"],
            "1..=65535",
        ),
        (
            &[
                "setup",
                "--unit",
                "1",
                "--model",
                "yl99",
                "--new-unit",
                "8",
                "--yes",
            ],
            "unknown model",
        ),
        (&["read", "--unit", "1", "--baud", "1200"], "1200"),
        (
            &[
                "preset",
                "--unit",
                "1",
                "--channel",
                "enc0",
                "--value",
                "2147483648",
            ],
            "outside",
        ),
        (
            &["clear", "--unit", "1", "--channel", "di1"],
            "no channel di1",
        ),
    ];
    for (args, cause) in refused {
        let mut all = args.to_vec();
        all.extend(["--port", port.as_str()]);
        let o = pg(&all).await;
        let (_, err) = text(&o);
        assert!(
            !o.status.success() && err.contains(cause),
            "{args:?}: {err}"
        );
    }
    let unit0 = pg(&["read", "--port", &port, "--unit", "0"]).await;
    assert!(!unit0.status.success() && text(&unit0).1.contains("1..=247"));
    let writes = plant.with_module("line", 1, |m, _| m.writes).unwrap();
    assert_eq!(writes, 0, "a refused request wrote to the module");
}

/// Mean time between consecutive messages on `topic` that arrived within `from..to`.
fn mean_interval(
    sub: &Subscriber,
    topic: &str,
    from: std::time::Instant,
    to: std::time::Instant,
) -> f64 {
    // The readings' own times, not their arrival: readings of several polls arrive together
    // (`mqtt.batch`).
    let at: Vec<std::time::SystemTime> = sub
        .on(topic)
        .iter()
        .filter(|m| m.at >= from && m.at <= to)
        .map(|m| humantime::parse_rfc3339(m.json()["ts"].as_str().unwrap()).unwrap())
        .collect();
    assert!(
        at.len() >= 10,
        "{topic}: only {} readings in the window",
        at.len()
    );
    let span = at[at.len() - 1].duration_since(at[0]).unwrap();
    span.as_secs_f64() / (at.len() - 1) as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_through_the_running_gateway_finds_an_added_module_without_slowing_the_polls() {
    use rumqttc::v5::mqttbytes::QoS;
    let plant = plant(
        r#"
[buses.line.devices.press]
unit = 1
model = "yl67"
[buses.line.devices.doors]
unit = 3
model = "zh-yx1600"
"#,
    )
    .await;
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let dir = temp_dir("commission-mqtt-scan");
    let _gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[
            ("line", "press", 1, "yl67", "200ms"),
            ("line", "doors", 3, "zh-yx1600", "200ms"),
        ],
        "",
    );
    let press = "pulsegate/test/press/enc0";
    let doors = "pulsegate/test/doors/di1";
    sub.expect_any(press, Duration::from_secs(5)).await;
    let base_from = std::time::Instant::now();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let base_to = std::time::Instant::now();

    // A WJ157 is wired onto the running line at unit 60.
    wire_module(&plant, "line", 60, "wj157", &[0]);

    let scan_from = std::time::Instant::now();
    sub.send(
        "pulsegate/test/bus/line/scan",
        r#"{"units": "1-3,50-70", "id": "survey-1"}"#,
    )
    .await;
    let result = sub
        .wait_for(
            "pulsegate/test/bus/line/scan/result",
            Duration::from_secs(30),
            |m| m.json()["id"] == "survey-1",
        )
        .await
        .expect("a scan result")
        .json();
    let scan_to = std::time::Instant::now();
    assert_eq!(result["complete"], true, "{result}");
    assert_eq!(result["configured"], serde_json::json!([1, 3]), "{result}");
    assert_eq!(result["asked"], 22, "{result}");
    let found = result["found"].as_array().unwrap();
    assert_eq!(found.len(), 1, "{result}");
    assert_eq!(
        (found[0]["unit"].as_u64(), found[0]["model"].as_str()),
        (Some(60), Some("wj157"))
    );

    for topic in [press, doors] {
        let base = mean_interval(&sub, topic, base_from, base_to);
        let during = mean_interval(&sub, topic, scan_from, scan_to);
        println!(
            "{topic}: poll interval {base:.4} s before, {during:.4} s during the scan ({:.3}x)",
            during / base
        );
        assert!(
            during <= base * 1.05,
            "{topic}: {base} s before, {during} s during the scan"
        );
    }

    // A second request while none runs is fine; a bad one is refused with its cause.
    sub.client
        .publish("pulsegate/test/bus/nope/scan", QoS::AtLeastOnce, false, "")
        .await
        .unwrap();
    let refused = sub
        .wait_for(
            "pulsegate/test/bus/nope/scan/result",
            Duration::from_secs(5),
            |_| true,
        )
        .await
        .expect("an answer")
        .json();
    assert_eq!(refused["error"], "unknown_bus");
}

/// A whole scan through the service in the idle time of a busy 9600-baud line takes minutes; a
/// module at a low unit is named on the progress topic, with the scan's id, as soon as it
/// answers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_of_a_busy_line_names_a_module_at_a_low_unit_within_45_s() {
    let plant = plant(
        r#"
[buses.line]
line = { baud = 9600, turnaround = "2ms" }
[buses.line.devices.press]
unit = 1
model = "yl67"
[buses.line.devices.doors]
unit = 3
model = "zh-yx1600"
"#,
    )
    .await;
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let dir = temp_dir("commission-busy-scan");
    let devices = [
        ("line", "press", 1, "yl67", "500ms"),
        ("line", "doors", 3, "zh-yx1600", "500ms"),
    ];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "")
        .replace("baud = 115200", "baud = 9600")
        .replace(
            "state_flush = \"500ms\"",
            "state_flush = \"500ms\"\nstats_interval = \"2s\"",
        );
    let gw = Gateway::start(&write_config(&dir, &text));
    // The polls keep the line busy most of the time.
    let busy = sub
        .wait_for(
            "pulsegate/test/bus/line/stats",
            Duration::from_secs(20),
            |m| m.json()["utilisation"].as_f64() >= Some(0.5),
        )
        .await
        .expect("a busy line");
    println!("busy scan: line use {}", busy.json()["utilisation"]);

    // A WJ157 is wired onto the running line at unit 5.
    wire_module(&plant, "line", 5, "wj157", &[0]);

    let asked = std::time::Instant::now();
    sub.send("pulsegate/test/bus/line/scan", r#"{"id": "busy-1"}"#)
        .await;
    let progress = sub
        .wait_for(
            "pulsegate/test/bus/line/scan/progress",
            Duration::from_secs(45),
            |m| m.json()["found"]["unit"] == 5,
        )
        .await
        .unwrap_or_else(|| {
            panic!(
                "the module at unit 5 named within 45 s of the request:\n{}",
                gw.log_text()
            )
        })
        .json();
    println!(
        "busy scan: unit 5 named after {:?}: {progress}",
        asked.elapsed()
    );
    assert_eq!(progress["id"], "busy-1", "{progress}");
    assert_eq!(progress["bus"], "line", "{progress}");
    assert_eq!(progress["found"]["model"], "wj157", "{progress}");
    assert!(progress["pending"].as_u64() > Some(200), "{progress}");
    // The scan goes on: its result (all 245 units) is still to come.
    assert!(sub.on("pulsegate/test/bus/line/scan/result").is_empty());
}

/// Starts `pulsegate ARGS`, sends SIGINT after `after`, and returns its output.
async fn pg_interrupted(args: &[&str], after: Duration) -> Output {
    let child = tokio::process::Command::new(bin())
        .args(args)
        .env("RUST_LOG", "warn")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run pulsegate");
    let pid = child.id().expect("running");
    tokio::time::sleep(after).await;
    let _ = std::process::Command::new("kill")
        .args(["-INT", &pid.to_string()])
        .status();
    tokio::time::timeout(Duration::from_secs(5), child.wait_with_output())
        .await
        .expect("exits after Ctrl-C")
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ctrl_c_during_a_scan_prints_what_was_found_so_far() {
    let plant = plant(FACTORY_LINE).await;
    let port = port_of(&plant, "line");
    // Units 1..247 at 9600 take half a minute; units 1, 3 and 5 answer in the first second.
    let scan = pg_interrupted(
        &["scan", "--port", &port, "--json"],
        Duration::from_millis(2500),
    )
    .await;
    let (out, err) = text(&scan);
    assert!(scan.status.success(), "{err}");
    assert!(err.contains("interrupted"), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("JSON");
    assert_eq!(v["interrupted"], true);
    let units: Vec<u64> = v["found"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["unit"].as_u64().unwrap())
        .collect();
    assert_eq!(units, [1, 3, 5], "{out}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn read_watch_refreshes_with_deltas_until_ctrl_c() {
    let plant = plant(
        r#"
[buses.line.devices.flow]
unit = 4
model = "wj157"
modes = [1]
channels.a0 = { count = 1000, rate = 100.0 }
"#,
    )
    .await;
    let port = port_of(&plant, "line");
    let watch = pg_interrupted(
        &["read", "--port", &port, "--unit", "4", "--watch", "300ms"],
        Duration::from_millis(1600),
    )
    .await;
    let (out, err) = text(&watch);
    assert!(watch.status.success(), "{err}");
    let a0: Vec<&str> = out.lines().filter(|l| l.starts_with("a0 ")).collect();
    assert!(a0.len() >= 3, "{out}");
    // Pulses at 100/s: each refresh after the first shows a positive delta of about 30.
    let delta: i64 = a0[2].split_whitespace().nth(3).unwrap().parse().unwrap();
    assert!((15..=60).contains(&delta), "{out}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_modbus_tcp_scan_finds_the_ethernet_zh_yx1600() {
    let plant = plant(
        r#"
[buses.hall]
listen = "127.0.0.1:0"
[buses.hall.devices.gates]
unit = 2
model = "zh-yx1600"
"#,
    )
    .await;
    let Endpoint::Tcp(addr) = plant.bus("hall").unwrap().endpoint.clone() else {
        unreachable!("TCP bus")
    };
    let scan = pg(&[
        "scan",
        "--host",
        &addr.to_string(),
        "--units",
        "1-5",
        "--json",
    ])
    .await;
    let (out, err) = text(&scan);
    assert!(scan.status.success(), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let found = &v["found"][0];
    assert_eq!(
        (found["unit"].as_u64(), found["model"].as_str()),
        (Some(2), Some("zh-yx1600")),
        "{out}"
    );
    assert!(
        found.get("baud").is_none() || found["baud"].is_null(),
        "{out}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_silent_on_registers_it_lacks_is_found_with_every_probe() {
    // No datasheet says whether a module refuses a register it lacks or stays silent. This
    // ZH-YX1600 stays silent on register 210 (the first identification read).
    let plant = plant(
        r#"
[buses.line.devices.yl]
unit = 1
model = "yl67"
[buses.line.devices.zh]
unit = 3
model = "zh-yx1600"
silent_on_unknown = true
"#,
    )
    .await;
    let port = port_of(&plant, "line");
    let units = |o: &Output| -> Vec<u64> {
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["found"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["unit"].as_u64().unwrap())
            .collect()
    };
    let quick = pg(&["scan", "--port", &port, "--units", "1-4", "--json"]).await;
    assert_eq!(units(&quick), [1], "one read per unit misses it");
    let thorough = pg(&[
        "scan",
        "--port",
        &port,
        "--units",
        "1-4",
        "--json",
        "--every-probe",
    ])
    .await;
    assert_eq!(units(&thorough), [1, 3], "{:?}", text(&thorough));
    let read = pg(&["read", "--port", &port, "--unit", "3", "--json"]).await;
    assert!(
        read.status.success(),
        "read --model auto asks every probe: {:?}",
        text(&read)
    );
}
