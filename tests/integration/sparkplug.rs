//! Sparkplug B, read by a host from another project: pysparkplug (on Eclipse Tahu's protobuf),
//! driven by tests/sparkplug_host.py, which prints every message it decodes as a JSON line and
//! sends the host's commands. A real Mosquitto and the simulated modules, as everywhere.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use pulsegate::sim::Plant;
use serde_json::{Value, json};

use crate::support::*;

pub(crate) const PLANT: &str = r#"
[buses.line1.devices.yl]
unit = 1
model = "yl67"
channels.enc0 = { rate = 50.0 }
[buses.line1.devices.wj]
unit = 2
model = "wj157"
modes = [1]
channels.a0 = { count = 100000, rate = 10.0 }
"#;

pub(crate) const DEVICES: [(&str, &str, u8, &str, &str); 2] = [
    ("line1", "yl", 1, "yl67", "100ms"),
    ("line1", "wj", 2, "wj157", "100ms"),
];

/// The Sparkplug host: a pysparkplug client in a child process.
pub(crate) struct Host {
    child: Child,
    stdin: ChildStdin,
    lines: Arc<Mutex<Vec<Value>>>,
}

impl Host {
    /// Connects to the broker on `port` (with a session the broker keeps, when `persistent`)
    /// and waits until it is subscribed.
    pub(crate) fn start(port: u16, persistent: bool) -> Host {
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/sparkplug_host.py");
        let mut cmd = Command::new("python3");
        cmd.arg(script).arg(port.to_string());
        if persistent {
            cmd.arg("persistent");
        }
        let mut child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("python3 runs tests/sparkplug_host.py (scripts/test installs pysparkplug)");
        let stdout = child.stdout.take().unwrap();
        let lines = Arc::new(Mutex::new(Vec::new()));
        let sink = lines.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let v = serde_json::from_str(&line).unwrap_or_else(|_| json!({"error": line}));
                sink.lock().unwrap().push(v);
            }
        });
        let host = Host {
            stdin: child.stdin.take().unwrap(),
            child,
            lines,
        };
        let deadline = Instant::now() + Duration::from_secs(20);
        while !host.lines().iter().any(|l| l["type"] == "READY") {
            assert!(
                Instant::now() < deadline,
                "the Sparkplug host did not start"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        host
    }

    pub(crate) fn lines(&self) -> Vec<Value> {
        self.lines.lock().unwrap().clone()
    }

    /// Waits until the lines satisfy `done`.
    pub(crate) async fn wait(
        &self,
        timeout: Duration,
        what: &str,
        done: impl Fn(&[Value]) -> bool,
    ) {
        let deadline = Instant::now() + timeout;
        while !done(&self.lines()) {
            assert!(Instant::now() < deadline, "host: {what} within {timeout:?}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Sends the host's process `sig` (`STOP`: it takes and acknowledges nothing until `CONT`).
    pub(crate) fn signal(&self, sig: &str) {
        let pid = self.child.id().to_string();
        let _ = Command::new("kill")
            .args([&format!("-{sig}"), &pid])
            .status();
    }

    pub(crate) fn send(&mut self, command: Value) {
        writeln!(self.stdin, "{command}").unwrap();
        self.stdin.flush().unwrap();
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The gateway's config: JSON and Sparkplug side by side, a scaled channel.
fn config(plant: &Plant, port: u16, dir: &std::path::Path) -> std::path::PathBuf {
    config_with(plant, port, dir, "")
}

/// The same with more `[sparkplug]` keys.
fn config_with(
    plant: &Plant,
    port: u16,
    dir: &std::path::Path,
    sparkplug: &str,
) -> std::path::PathBuf {
    let extra = format!(
        "[sparkplug]\ngroup_id = \"plant\"\n{sparkplug}\
         [buses.line1.devices.wj.channels.a0]\nscale = 0.001\nunit = \"kWh\"\n"
    );
    let text = gateway_toml(plant, port, dir, &DEVICES, &extra).replacen(
        "[mqtt]\n",
        "[mqtt]\nformat = [\"json\", \"sparkplug\"]\n",
        1,
    );
    write_config(dir, &text)
}

pub(crate) fn of_type<'a>(lines: &'a [Value], kind: &str) -> impl Iterator<Item = &'a Value> {
    lines.iter().filter(move |l| l["type"] == kind)
}

pub(crate) fn metric<'a>(line: &'a Value, name: &str) -> Option<&'a Value> {
    line["metrics"]
        .as_array()?
        .iter()
        .find(|m| m["name"] == name)
}

/// A metric of a DDATA by name and timestamp (a DDATA may carry two readings of a channel: a
/// poll's and a command's read-back).
fn metric_at<'a>(line: &'a Value, name: &str, ts: u64) -> Option<&'a Value> {
    line["metrics"]
        .as_array()?
        .iter()
        .find(|m| m["name"] == name && m["timestamp"] == ts)
}

fn bd_seq(line: &Value) -> i64 {
    metric(line, "bdSeq").unwrap()["value"].as_i64().unwrap()
}

/// Checks `seq` over the node's messages in arrival order: 0 at each NBIRTH, then one more
/// each time, mod 256. Returns how many numbered messages there were and how often it wrapped.
pub(crate) fn assert_seq_unbroken(lines: &[Value]) -> (usize, usize) {
    let numbered = ["NBIRTH", "DBIRTH", "DDATA", "DDEATH", "NDATA"];
    let mut last: Option<i64> = None;
    let (mut count, mut wraps) = (0, 0);
    for l in lines
        .iter()
        .filter(|l| numbered.contains(&l["type"].as_str().unwrap_or("")))
    {
        let seq = l["seq"].as_i64().unwrap_or_else(|| panic!("no seq: {l}"));
        if l["type"] == "NBIRTH" {
            assert_eq!(seq, 0, "an NBIRTH starts at 0: {l}");
        } else {
            let want = (last.expect("a birth first") + 1) % 256;
            assert_eq!(seq, want, "after seq {last:?} came {l}");
            wraps += usize::from(seq == 0);
        }
        last = Some(seq);
        count += 1;
    }
    (count, wraps)
}

pub(crate) fn no_errors(lines: &[Value]) {
    let errors: Vec<&Value> = lines.iter().filter(|l| l.get("error").is_some()).collect();
    assert!(errors.is_empty(), "the host could not read: {errors:?}");
}

fn ms(rfc3339: &str) -> u64 {
    let t = humantime::parse_rfc3339(rfc3339).unwrap();
    t.duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64
}

/// Starts broker, host, plant and gateway; waits until both devices are born.
async fn rig(name: &str) -> (Broker, Host, Plant, std::path::PathBuf, Gateway) {
    let broker = Broker::start();
    let host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir(name);
    let gw = Gateway::start(&config(&plant, broker.port, &dir));
    host.wait(Duration::from_secs(15), "both devices born", |l| {
        of_type(l, "DBIRTH").count() >= 2
    })
    .await;
    (broker, host, plant, dir, gw)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sparkplug_host_reads_births_and_data_that_match_the_json_readings() {
    let broker = Broker::start();
    let host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("sparkplug-host");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let _gw = Gateway::start(&config(&plant, broker.port, &dir));
    // Two devices polled ten times a second: past 256 messages, `seq` has wrapped.
    host.wait(Duration::from_secs(60), "300 DDATA", |l| {
        of_type(l, "DDATA").count() >= 300
    })
    .await;
    let lines = host.lines();
    no_errors(&lines);
    let (numbered, wraps) = assert_seq_unbroken(&lines);
    assert!(
        numbered > 256 && wraps >= 1,
        "{numbered} messages, {wraps} wraps"
    );

    let wj = of_type(&lines, "DBIRTH")
        .find(|l| l["device"] == "wj")
        .unwrap();
    let yl = of_type(&lines, "DBIRTH")
        .find(|l| l["device"] == "yl")
        .unwrap();
    assert_eq!(metric(wj, "a0/Total").unwrap()["datatype"], "UINT64");
    assert_eq!(metric(yl, "enc0/Total").unwrap()["datatype"], "INT64");
    let value = metric(wj, "a0/Value").unwrap();
    assert_eq!(value["properties"]["engUnit"], "kWh", "{value}");
    assert_eq!(metric(wj, "a0/Clear").unwrap()["datatype"], "BOOLEAN");
    assert_eq!(metric(wj, "a0/Preset").unwrap()["datatype"], "INT64");
    // Every DDATA metric went out as an alias alone (pysparkplug resolved it through the
    // DBIRTH: an undeclared one would be an error line).
    for d in of_type(&lines, "DDATA") {
        for m in d["metrics"].as_array().unwrap() {
            assert_eq!(m["named_on_wire"], false, "{d}");
            assert!(m["alias"].is_u64(), "{d}");
        }
    }
    // The same polls, read in JSON: the same values.
    let end = Instant::now() - Duration::from_secs(2);
    let mut matched = 0;
    for (device, channel) in [("wj", "a0"), ("yl", "enc0")] {
        let total_name = format!("{channel}/Total");
        let data: Vec<&Value> = of_type(&lines, "DDATA")
            .filter(|l| l["device"] == device && metric(l, &total_name).is_some())
            .collect();
        for m in sub.on(&format!("pulsegate/test/{device}/{channel}")) {
            if m.at > end {
                continue;
            }
            let j = m.json();
            let ts = ms(j["ts"].as_str().unwrap());
            let d = data
                .iter()
                .find(|d| metric_at(d, &total_name, ts).is_some())
                .unwrap_or_else(|| panic!("no DDATA for the JSON reading {j}"));
            let value = |what: &str| {
                metric_at(d, &format!("{channel}/{what}"), ts).unwrap()["value"].clone()
            };
            assert_eq!(value("Total"), j["total"], "{j} / {d}");
            assert_eq!(value("Count"), j["count"], "{j} / {d}");
            assert_eq!(value("Delta"), j["delta"], "{j} / {d}");
            if let Some(rate) = j.get("rate_hz") {
                assert_eq!(value("Rate").as_f64(), rate.as_f64(), "{j} / {d}");
            }
            if let Some(v) = j.get("value") {
                assert_eq!(value("Value").as_f64(), v.as_f64(), "{j} / {d}");
            }
            matched += 1;
        }
    }
    assert!(matched > 40, "{matched} JSON readings compared");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_leaves_the_ndeath_of_the_last_nbirth_and_the_restart_births_with_the_next_bdseq() {
    let (broker, host, plant, dir, gw) = rig("sparkplug-kill").await;
    let first = of_type(&host.lines(), "NBIRTH").last().unwrap().clone();
    gw.kill();
    host.wait(Duration::from_secs(10), "the NDEATH", |l| {
        of_type(l, "NDEATH").count() == 1
    })
    .await;
    let death = of_type(&host.lines(), "NDEATH").next().unwrap().clone();
    assert_eq!(bd_seq(&death), bd_seq(&first), "{death} / {first}");
    assert!(death["seq"].is_null(), "a death has no seq");

    let _gw = Gateway::start(&config(&plant, broker.port, &dir));
    host.wait(Duration::from_secs(15), "the births again", |l| {
        of_type(l, "NBIRTH").count() == 2
    })
    .await;
    let again = of_type(&host.lines(), "NBIRTH").nth(1).unwrap().clone();
    assert_eq!(bd_seq(&again), (bd_seq(&first) + 1) % 256, "{again}");
    no_errors(&host.lines());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_host_asks_for_a_rebirth_and_clears_a_count_with_a_dcmd() {
    let (_broker, mut host, plant, _dir, _gw) = rig("sparkplug-commands").await;
    host.send(json!({"ncmd": "plant/test", "rebirth": true}));
    host.wait(
        Duration::from_secs(10),
        "NBIRTH and both DBIRTHs again",
        |l| {
            let Some(at) = l.iter().rposition(|x| x["type"] == "NBIRTH") else {
                return false;
            };
            of_type(l, "NBIRTH").count() == 2 && of_type(&l[at..], "DBIRTH").count() == 2
        },
    )
    .await;

    let count = || {
        plant
            .with_module("line1", 2, |m, now| m.channel("a0").unwrap().count(now))
            .unwrap()
    };
    assert!(count() >= 100_000);
    host.send(
        json!({"dcmd": "plant/test/wj", "metric": "a0/Clear", "type": "BOOLEAN", "value": true}),
    );
    let cleared = |l: &Value| {
        l["type"] == "DDATA"
            && l["device"] == "wj"
            && metric(l, "a0/Event").is_some_and(|m| m["value"] == "cleared")
    };
    host.wait(Duration::from_secs(10), "a DDATA with the clear", |l| {
        l.iter().any(cleared)
    })
    .await;
    assert!(
        count() < 1000,
        "the module's count was cleared: {}",
        count()
    );
    let lines = host.lines();
    let d = lines.iter().find(|l| cleared(l)).unwrap();
    // A poll and the clear's read-back may share a DDATA: the count of the clear's reading.
    let metrics = d["metrics"].as_array().unwrap();
    let at = metrics.iter().find(|m| m["value"] == "cleared").unwrap()["timestamp"].clone();
    let shown = metrics
        .iter()
        .find(|m| m["name"] == "a0/Count" && m["timestamp"] == at)
        .unwrap()["value"]
        .as_i64()
        .unwrap();
    assert!(shown < 1000, "the host sees the cleared count: {d}");
    no_errors(&lines);
    assert_seq_unbroken(&lines);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_a_primary_host_the_node_waits_for_its_state_and_follows_it() {
    let broker = Broker::start();
    let mut host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("sparkplug-primary");
    let config = config_with(&plant, broker.port, &dir, "primary_host = \"scada\"\n");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let _gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/status", Duration::from_secs(10))
        .await;
    // Polls while the host is away, counted by the module itself (on a loaded machine the
    // gateway may take seconds to start polling): 40 of the WJ157's reads, discovery and a
    // couple of seconds of polls.
    let reads = || plant.with_module("line1", 2, |m, _| m.reads).unwrap();
    let start = reads();
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    while reads() < start + 40 && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let quiet = host.lines();
    assert!(
        quiet.iter().all(|l| l["type"] == "READY"),
        "nothing before the host is online: {quiet:?}"
    );

    host.send(json!({"state": "scada", "online": true}));
    host.wait(Duration::from_secs(10), "births, then live data", |l| {
        of_type(l, "DBIRTH").count() == 2
            && l.iter()
                .any(|x| x["type"] == "DDATA" && x["metrics"][0]["is_historical"] == false)
    })
    .await;
    let lines = host.lines();
    let first = lines.iter().position(|l| l["type"] == "NBIRTH").unwrap();
    let data = lines.iter().position(|l| l["type"] == "DDATA").unwrap();
    assert!(first < data, "the births first");
    let held = of_type(&lines, "DDATA")
        .take_while(|l| l["metrics"][0]["is_historical"] == true)
        .count();
    let historical = of_type(&lines, "DDATA")
        .filter(|l| l["metrics"][0]["is_historical"] == true)
        .count();
    let shape: Vec<String> = lines
        .iter()
        .take(12)
        .map(|l| format!("{}:{}", l["type"], l["metrics"][0]["is_historical"]))
        .collect();
    assert!(
        held > 10,
        "what was polled while waiting follows, as history: {held} ({historical} historical in all)\n{shape:?}"
    );
    assert_seq_unbroken(&lines);
    no_errors(&lines);
    let birth = lines[first].clone();

    host.send(json!({"state": "scada", "online": false}));
    host.wait(Duration::from_secs(10), "an NDEATH", |l| {
        of_type(l, "NDEATH").count() == 1
    })
    .await;
    let death = of_type(&host.lines(), "NDEATH").next().unwrap().clone();
    assert_eq!(bd_seq(&death), bd_seq(&birth));
    host.send(json!({"state": "scada", "online": true}));
    host.wait(Duration::from_secs(10), "born again", |l| {
        of_type(l, "NBIRTH").count() == 2
    })
    .await;
    no_errors(&host.lines());
}

/// A Sparkplug message of the node `test` in group `plant` (one metric), as a node sends it.
fn node_message(kind: &str, seq: u64) -> Vec<u8> {
    use pulsegate::publish::sparkplug::proto::{Metric, Payload, Value, datatype};
    let name = if kind == "NBIRTH" { "bdSeq" } else { "x" };
    let metric = Metric::new(name, None, datatype::INT64, Some(Value::Long(seq)));
    let payload = Payload {
        timestamp: Some(1_700_000_000_000 + seq),
        metrics: vec![metric],
        seq: Some(seq),
        ..Payload::default()
    };
    payload.encode()
}

/// A broker restarted with the host's session sends again, flagged DUP, what it had sent the
/// host but not seen acknowledged (MQTT's at-least-once): the host takes each message once, so
/// the node's `seq` runs on unbroken. Decoded twice it would seem to go back (4, then 3): what
/// made `burn_in::outputs_the_scada_broker_away` fail on a loaded machine, where the host's
/// acknowledgements were still on their way when the broker stopped. Here the host is stopped
/// (SIGSTOP) while three messages reach it, so none of them is acknowledged before the broker
/// goes; the one sent after the restart comes after the broker's resends.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn what_a_restarted_broker_sends_again_the_host_takes_once() {
    let dir = temp_dir("sparkplug-resent");
    let port = free_port();
    let mut broker = Broker::start_persistent(port, &dir);
    let host = Host::start(port, true);
    let node = Subscriber::start(port, "spBv1.0/plant/#").await;
    let send = |kind: &'static str, seq: u64| {
        let topic = format!("spBv1.0/plant/{kind}/test");
        let client = node.client.clone();
        async move {
            let qos = rumqttc::v5::mqttbytes::QoS::AtLeastOnce;
            let payload = node_message(kind, seq);
            client.publish(topic, qos, false, payload).await.unwrap();
        }
    };
    send("NBIRTH", 0).await;
    for seq in 1..=2 {
        send("NDATA", seq).await;
    }
    host.wait(Duration::from_secs(10), "taken", |l| {
        of_type(l, "NDATA").count() == 2
    })
    .await;
    host.signal("STOP");
    for seq in 3..=5 {
        send("NDATA", seq).await;
    }
    // The broker routed them to the host too (in the same step) once they are back here.
    until(
        Duration::from_secs(10),
        "the broker has them",
        || node.all().len() == 6,
        String::new,
    )
    .await;
    broker.terminate();
    host.signal("CONT");
    let _broker = Broker::start_persistent(port, &dir);
    // Sent after the restart: it reaches the host after what the broker sends again.
    send("NDATA", 6).await;
    host.wait(
        Duration::from_secs(20),
        "the message after the restart",
        |l| of_type(l, "NDATA").any(|d| d["seq"] == 6),
    )
    .await;
    let lines = host.lines();
    no_errors(&lines);
    assert_seq_unbroken(&lines);
    assert_eq!(of_type(&lines, "NDATA").count(), 6, "{lines:?}");
    assert!(
        of_type(&lines, "REDELIVERED").count() >= 1,
        "the broker sent again what the stopped host had not acknowledged: {lines:?}"
    );
}

/// The one long outage: the broker away until the node has spooled a hundred messages (about
/// 5 s of polls ten times a second, five reconnect attempts), then the readings of that time
/// arrive after the rebirth, in order, flagged historical, with their own timestamps. Run from
/// `burn_in` (it starts with the other long runs). A minute's outage of the same store and
/// forward runs on paused time in `src/publish/mqtt/paused_tests.rs`; this one proves it
/// against a real broker.
pub(crate) async fn after_a_broker_outage_the_historical_readings_follow_the_rebirth_in_order() {
    let dir = temp_dir("sparkplug-outage");
    let port = free_port();
    let http = free_port();
    let mut broker = Broker::start_persistent(port, &dir);
    let host = Host::start(port, true);
    let plant = plant(PLANT).await;
    let metrics = format!("[metrics]\nlisten = \"127.0.0.1:{http}\"\n");
    let _gw = Gateway::start(&config_with(&plant, port, &dir, &metrics));
    host.wait(Duration::from_secs(15), "data", |l| {
        of_type(l, "DDATA").count() >= 20
    })
    .await;
    let first = of_type(&host.lines(), "NBIRTH").last().unwrap().clone();

    broker.terminate();
    let away = SystemTime::now();
    crate::metrics::scrape_until(http, Duration::from_secs(60), "a hundred spooled", |t| {
        let spooled = crate::metrics::sample(t, "pulsegate_spool_messages{output=\"sparkplug\"}");
        spooled.is_some_and(|n| n >= 100.0)
    })
    .await;
    let _broker = Broker::start_persistent(port, &dir);
    let back = SystemTime::now();
    let live = |l: &Value| l["type"] == "DDATA" && l["metrics"][0]["is_historical"] == false;
    host.wait(
        Duration::from_secs(60),
        "live data after the rebirth",
        |l| {
            let Some(at) = l.iter().rposition(|x| x["type"] == "NBIRTH") else {
                return false;
            };
            at > 0
                && bd_seq(&l[at]) != bd_seq(&first)
                && l[at..].iter().filter(|x| live(x)).count() > 10
        },
    )
    .await;

    let lines = host.lines();
    no_errors(&lines);
    let at = lines.iter().rposition(|x| x["type"] == "NBIRTH").unwrap();
    // Each CONNECT takes the next bdSeq (spec 3.0), attempts against the absent broker too.
    let ahead = (bd_seq(&lines[at]) - bd_seq(&first)).rem_euclid(256);
    assert!((1..=60).contains(&ahead), "bdSeq moved on by {ahead}");
    let session = &lines[at..];
    assert_seq_unbroken(session);
    let (away_ms, back_ms) = (ms_of(away), ms_of(back));
    for device in ["wj", "yl"] {
        let data: Vec<&Value> = of_type(session, "DDATA")
            .filter(|l| l["device"] == device)
            .collect();
        let historical = data.iter().take_while(|l| !live(l)).count();
        assert!(
            data[historical..].iter().all(|l| live(l)),
            "{device}: historical data first, then live"
        );
        let stamps: Vec<u64> = data[..historical]
            .iter()
            .map(|l| l["timestamp"].as_u64().unwrap())
            .collect();
        assert!(
            stamps.windows(2).all(|w| w[0] <= w[1]),
            "{device}: in order"
        );
        let during = stamps
            .iter()
            .filter(|t| (away_ms..back_ms).contains(t))
            .count();
        // Polled ten times a second: the hundred spooled are about fifty a device (fewer on a busy
        // machine, where polls are late).
        assert!(during > 25, "{device}: {during} readings of the outage");
        for l in &data[..historical] {
            let flags = l["metrics"].as_array().unwrap();
            assert!(flags.iter().all(|m| m["is_historical"] == true), "{l}");
        }
    }
}

fn ms_of(t: SystemTime) -> u64 {
    t.duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64
}

/// The gateway's config with a primary host and the metrics endpoint on `http`.
fn with_host_and_metrics(
    plant: &Plant,
    port: u16,
    dir: &std::path::Path,
    http: u16,
) -> std::path::PathBuf {
    let keys = format!("primary_host = \"scada\"\n[metrics]\nlisten = \"127.0.0.1:{http}\"\n");
    config_with(plant, port, dir, &keys)
}

fn sparkplug_events(text: &str, event: &str) -> Option<f64> {
    let series =
        format!("pulsegate_output_protocol_events_total{{event=\"{event}\",output=\"sparkplug\"}}");
    crate::metrics::sample(text, &series)
}

/// Sparkplug 3.0: a STATE older than the last one taken, or one that is not
/// `{"online": bool, "timestamp": ms}`, is ignored: no NDEATH, no hold, the node keeps
/// publishing, and the ignored messages are counted; a current `offline` still takes it down.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stale_or_malformed_state_is_ignored_and_no_ndeath_follows() {
    const T: u64 = 2_000_000_000_000;
    let broker = Broker::start();
    let mut host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("sparkplug-stale-state");
    let http = free_port();
    let _gw = Gateway::start(&with_host_and_metrics(&plant, broker.port, &dir, http));
    host.send(json!({"state": "scada", "online": true, "timestamp": T}));
    host.wait(Duration::from_secs(15), "born, and data", |l| {
        of_type(l, "DBIRTH").count() == 2 && of_type(l, "DDATA").count() >= 3
    })
    .await;
    host.send(json!({"state": "scada", "online": false, "timestamp": T - 10_000}));
    host.send(json!({"state_raw": "scada", "payload": "{\"online\":false,\"timestamp\":\"x\"}"}));
    host.send(json!({"state": "scada", "online": true, "timestamp": T - 20_000}));
    let text = crate::metrics::scrape_until(http, Duration::from_secs(10), "3 ignored", |t| {
        sparkplug_events(t, "host_state_ignored") == Some(3.0)
    })
    .await;
    assert_eq!(sample_held(&text), Some(0.0), "not held");
    let data_before = of_type(&host.lines(), "DDATA").count();
    host.wait(Duration::from_secs(10), "still publishing", |l| {
        of_type(l, "DDATA").count() > data_before + 5
    })
    .await;
    let lines = host.lines();
    assert_eq!(
        of_type(&lines, "NDEATH").count(),
        0,
        "no NDEATH for a stale or forged STATE"
    );
    assert_eq!(
        of_type(&lines, "NBIRTH").count(),
        1,
        "no rebirth for an older online"
    );
    assert!(
        of_type(&lines, "DDATA").count() > data_before + 5,
        "still publishing"
    );
    let (code, body) =
        tokio::task::spawn_blocking(move || crate::metrics::http_get(http, "/healthz"))
            .await
            .unwrap();
    assert_eq!(code, 200, "{body}");
    host.send(json!({"state": "scada", "online": false, "timestamp": T + 1}));
    host.wait(
        Duration::from_secs(10),
        "the NDEATH of a current offline",
        |l| of_type(l, "NDEATH").count() == 1,
    )
    .await;
    no_errors(&host.lines());
}

fn sample_held(text: &str) -> Option<f64> {
    crate::metrics::sample(text, "pulsegate_mqtt_held{output=\"sparkplug\"}")
}

/// Three hundred `Node Control/Rebirth` in a burst: every one counted, a handful of births (one
/// at once, the rest coalesced into one at the end of the gap), not three hundred.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_hundred_rebirth_requests_are_a_handful_of_births() {
    let broker = Broker::start();
    let mut host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("sparkplug-rebirth-flood");
    let http = free_port();
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &DEVICES,
        &format!("[sparkplug]\ngroup_id = \"plant\"\n[metrics]\nlisten = \"127.0.0.1:{http}\"\n"),
    )
    .replacen(
        "[mqtt]\n",
        "[mqtt]\nformat = [\"json\", \"sparkplug\"]\n",
        1,
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    host.wait(Duration::from_secs(15), "born", |l| {
        of_type(l, "DBIRTH").count() == 2
    })
    .await;
    host.send(json!({"ncmd": "plant/test", "rebirth": true, "count": 300}));
    crate::metrics::scrape_until(http, Duration::from_secs(10), "300 requests", |t| {
        sparkplug_events(t, "rebirth_requested") == Some(300.0)
    })
    .await;
    // One rebirth at once, the rest coalesced into one at the end of the 5 s gap
    // (`REBIRTH_GAP_MS`): wait for that one and its device births.
    host.wait(Duration::from_secs(15), "the coalesced rebirth", |l| {
        let n = of_type(l, "NBIRTH").count();
        n >= 3 && of_type(l, "DBIRTH").count() >= 2 * n
    })
    .await;
    let lines = host.lines();
    let births = of_type(&lines, "NBIRTH").count() - 1;
    println!("300 rebirth requests: {births} rebirths");
    assert!(
        (1..=3).contains(&births),
        "{births} rebirths for 300 requests"
    );
    assert_eq!(of_type(&lines, "DBIRTH").count(), 2 * (births + 1));
    assert_seq_unbroken(&lines);
    no_errors(&lines);
}
